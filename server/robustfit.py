"""Robust fits of a few non-negative unknowns to many samples, for the scene estimate.

:func:`ransac_fit` finds the inliers of a two-unknown linear model from pairs of samples;
:func:`robust_linear_fit` refines any number of non-negative unknowns by iteratively
reweighted least squares with Tukey's biweight on residuals relative to the fitted value (the
samples' noise grows with their brightness); :func:`weighted_nonneg` is one weighted
non-negative least-squares solve (scipy's NNLS). Shapes: n samples, p unknowns.
"""

from __future__ import annotations

import numpy as np


def robust_linear_fit(A: np.ndarray, y: np.ndarray, weights0: np.ndarray | None = None,
                      iterations: int = 12, tukey: float = 4.685,
                      groups: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Fit ``y ~ A x`` (A (n, p), y (n,)) with ``x >= 0`` by IRLS with Tukey's biweight on
    residuals relative to the fitted value; returns x (p,) and the final weights (n,).
    ``groups`` (n,) int: samples of another noise level (single pixels among patches' means,
    dark among bright) each get their own residual scale (the median absolute deviation of
    their group's), so one group's noise does not make the other's samples outliers."""
    w = np.ones_like(y) if weights0 is None else weights0.astype(float).copy()
    x = np.zeros(A.shape[1])
    floor = 1e-9 + 0.02 * float(np.median(np.abs(y)))
    groups = np.zeros(len(y), int) if groups is None else np.asarray(groups, int)
    for _ in range(iterations):
        x = weighted_nonneg(A, y, w)
        fit = A @ x
        rel = (y - fit) / np.maximum(np.abs(fit), floor)
        good = w > 0
        scale = np.ones(len(y))
        for g in np.unique(groups):
            mine = groups == g
            ok = good & mine
            scale[mine] = 1.4826 * np.median(np.abs(rel[ok])) if ok.any() else 1.0
        scale = np.maximum(scale, 0.01)
        u = rel / (tukey * scale)
        w = np.where(np.abs(u) < 1.0, (1.0 - u * u) ** 2, 0.0)
    return x, w


def weighted_nonneg(A: np.ndarray, y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted non-negative least squares of ``y ~ A x`` (scipy's NNLS); x (p,)."""
    from scipy.optimize import nnls

    sw = np.sqrt(np.maximum(w, 0.0))
    if not np.any(sw > 0):
        return np.zeros(A.shape[1])
    x, _ = nnls(A * sw[:, None], y * sw)
    return x


def ransac_fit(a: np.ndarray, c: np.ndarray, y: np.ndarray, rng: np.random.Generator,
               hypotheses: int = 150, tolerance: float = 0.08) -> np.ndarray:
    """The inlier mask (n,) of the best of ``hypotheses`` two-sample fits of ``y ~ x1 a + x2
    c`` (x1, x2 >= 0): most samples within ``tolerance`` relative error. One of each pair is a
    sample with the sun's term, the other one without when there are such."""
    n = len(y)
    sunny = np.flatnonzero(a > 0.25 * np.max(a)) if np.max(a) > 0 else np.arange(n)
    shade = np.flatnonzero(a <= 0.25 * np.max(a)) if np.max(a) > 0 else np.arange(n)
    if len(sunny) == 0 or len(shade) == 0:
        sunny = shade = np.arange(n)
    i = rng.choice(sunny, hypotheses)
    j = rng.choice(shade, hypotheses)
    det = a[i] * c[j] - a[j] * c[i]
    ok = np.abs(det) > 1e-12
    det = np.where(ok, det, 1.0)
    x1 = (y[i] * c[j] - y[j] * c[i]) / det
    x2 = (a[i] * y[j] - a[j] * y[i]) / det
    # the overcast hypothesis: no sun at all, the sky from each shaded sample
    x1 = np.concatenate([np.where(ok, np.maximum(x1, 0.0), 0.0), np.zeros(hypotheses)])
    x2 = np.concatenate([np.where(ok, np.maximum(x2, 0.0), 0.0),
                         y[j] / np.maximum(c[j], 1e-12)])
    fit = x1[:, None] * a[None] + x2[:, None] * c[None]
    inside = np.abs(y[None] - fit) <= tolerance * np.maximum(fit, 1e-9)
    return inside[int(np.argmax(inside.sum(axis=1)))]
