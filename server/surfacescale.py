"""Per-surface albedo scales learned from the frames, for the scene estimate (issue 16).

A surface's stated albedo can be wrong (a survey's guess, stone darkened by rain, a repainted
wall). The scene estimate (server.sceneestimate) fits the sun and the sky to every sample, so a
surface whose albedo is off by a factor pulls the fit by that factor wherever its samples
dominate: a building's shaded face is often most of the shadowed pixels a view has, and then
its albedo sets the sky's estimate.

The model of sample ``i`` on surface ``p`` becomes ``y_i = s_p (A_i x)`` with ``x`` the light
(non-negative) and ``s_p`` the surface's albedo scale. With ``t_p = 1 / s_p`` it is linear:
``A_i x - t_p y_i = 0``. One weighted least-squares solve (scipy's ``lsq_linear``, bounded)
over the inlier samples, relative residuals, gives ``x`` and every ``t_p`` at once; a prior
row per surface pulls ``t_p`` toward its last value, so a surface seen in only a few samples, or
only in shade, keeps its scale, and the scales are followed across frames (an albedo does not
change within minutes). The overall level is not observable (every albedo x 2 looks like a
sky / 2), so the scales are divided by their median over the view's area: the surfaces that
agree set the level and one wrong surface among several is found. An error shared by all surfaces
stays in the estimate; a sky camera (fusion) is what can tell that.
"""

from __future__ import annotations

import numpy as np

from server.robustfit import robust_linear_fit

SCALE_LIMITS = (0.5, 2.0)  # a stated albedo is trusted within a factor of two
MIN_SURFACE_SAMPLES = 12  # fewer inlier samples of a surface in a frame: its scale is kept
# A surface seen only in shade has its scale confounded with the sky model's angular error
# (10-15 % on a north face against Radiance's Perez skies): within this a stated albedo is kept.
ALBEDO_TRUST = 0.15
MEMORY = 0.98  # per frame: the past frames' samples weigh this much less each frame


def surfaces_by_albedo(face_albedo: np.ndarray) -> np.ndarray:
    """(F,) int surface of each face: faces of one stated albedo (F, 3) are one surface."""
    _, inverse = np.unique(np.asarray(face_albedo, float), axis=0, return_inverse=True)
    return inverse.reshape(-1)


class SurfaceScales:
    """The albedo scale of each surface, followed across frames.

    Parameters
    ----------
    pool_surface : (m,) int, the surface of each of the view's candidate pixels (random pixels
        of the view, so each surface's count is its share of what the camera sees)
    """

    def __init__(self, pool_surface: np.ndarray):
        self.area = np.bincount(np.asarray(pool_surface, int)).astype(float)
        self.scale = np.ones(len(self.area))  # this frame's (after refit), read by of()
        self.kept = np.ones(len(self.area))  # from the frames before this one
        # past samples behind ``kept`` (decayed by MEMORY each frame)
        self.evidence = np.zeros(len(self.area))
        self.rescaled = np.zeros(len(self.area), bool)  # (S,) found wrong: scale used
        self._frame_evidence = np.zeros(len(self.area))

    def of(self, surface: np.ndarray) -> np.ndarray:
        """(n,) the scale to use for each sample's surface ``surface`` (n,) int: 1 while the
        learned scale is within ``ALBEDO_TRUST`` of it, else the learned scale (a surface
        once found wrong stays rescaled until its scale is back within half of that)."""
        return np.where(self.rescaled, self.scale, 1.0)[surface]

    def refit(self, surface: np.ndarray, A: np.ndarray, y: np.ndarray) -> None:
        """Solve the light and every surface's scale from this frame's samples and the frames
        before (read the scales with :meth:`of`; :meth:`end_frame` keeps them). Called again
        in the same frame (another sky model), it replaces this frame's part.

        surface : (n,) int; A : (n, q) each sample's radiance per unit of the q light terms,
        with the stated albedo; y : (n,) measured radiance.

        Outliers (people, unknown shadows) are found within each surface by its own robust fit
        (its light free): a fit over all surfaces at once would take the wrong surface's
        samples for the truth where they are many and set aside the right ones.
        """
        from scipy.optimize import lsq_linear

        good = np.isfinite(y) & (y > 0.0)
        weights = np.zeros(len(y))
        ids, counts = np.unique(surface[good], return_counts=True)
        free = ids[counts >= MIN_SURFACE_SAMPLES]
        for p in free:
            sel = good & (surface == p)
            weights[sel] = robust_linear_fit(A[sel], y[sel])[1]
        good &= weights > 0.5
        surface, A, y, w = surface[good], A[good], y[good], np.sqrt(weights[good])
        ids = np.unique(surface)
        free = free[np.isin(free, ids)]
        if len(free) < 2:  # one surface: its scale is the overall level, not observable
            return
        q = A.shape[1]
        column = {p: q + k for k, p in enumerate(free)}
        rows = []
        rhs = []
        # data rows, relative: (A_i x - t_p y_i) / y_i, or (A_i x) / y_i = 1 / s_p when the
        # surface's scale is held
        for p in ids:
            sel = surface == p
            block = np.zeros((int(sel.sum()), q + len(free)))
            block[:, :q] = A[sel] / y[sel, None] * w[sel, None]
            if p in column:
                block[:, column[p]] = -w[sel]
                rhs.append(np.zeros(int(sel.sum())))
            else:
                rhs.append(w[sel] / self.kept[p])
            rows.append(block)
        # prior rows: t_p close to its last value, weighted as the past samples behind it (a
        # recursive least-squares mean of the frames; at first each frame's own)
        for p in free:
            prior = np.zeros((1, q + len(free)))
            prior[0, column[p]] = np.sqrt(self.evidence[p])
            rows.append(prior)
            rhs.append(np.array([np.sqrt(self.evidence[p]) / self.kept[p]]))
        lo = np.concatenate([np.zeros(q), np.full(len(free), 1.0 / SCALE_LIMITS[1])])
        hi = np.concatenate([np.full(q, np.inf), np.full(len(free), 1.0 / SCALE_LIMITS[0])])
        fit = lsq_linear(np.vstack(rows), np.concatenate(rhs), bounds=(lo, hi))
        # the level, in the solve's own units: the median of the free surfaces' scales over
        # what the view sees of them is held at 1 (the held ones keep theirs)
        solved = 1.0 / fit.x[q:]
        order = np.argsort(solved)
        cumulative = np.cumsum(self.area[free][order])
        level = float(solved[order][np.searchsorted(cumulative, 0.5 * cumulative[-1])])
        self.scale = self.kept.copy()
        self.scale[free] = np.clip(solved / level, *SCALE_LIMITS)
        off = np.abs(np.log(self.scale))
        self.rescaled = np.where(self.rescaled, off > 0.5 * np.log1p(ALBEDO_TRUST),
                                 off > np.log1p(ALBEDO_TRUST))
        self._frame_evidence[:] = 0.0
        self._frame_evidence[free] = [float(np.sum(w[surface == p] ** 2)) for p in free]

    def end_frame(self) -> None:
        """Keep this frame's scales and count its samples as evidence behind them."""
        self.kept = self.scale.copy()
        self.evidence = MEMORY * self.evidence + self._frame_evidence
        self._frame_evidence[:] = 0.0
