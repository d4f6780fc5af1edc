"""Gaussian mixtures of colour (Kakuta Sec. 3.1.1) and their look-up tables.

A first fit is OpenCV's EM (``cv2.ml.EM``, full covariances, k-means start); a refit is
warm-started from the previous fit and runs the same EM iterations in numpy
(:func:`em_from_posteriors`, the steps of OpenCV's ``trainM``, checked against it in
tests/server/occlusion/test_occlusion_mixture.py): on 300 samples and 5 components that is
0.5 ms of a core where ``cv2.ml.EM.trainM`` took 5.2 ms in the same run (its per-sample loops
and an SVD per component and step; ``benchmarks/bench_occlusion.py --refit``), the frames
that set the pipeline's p95 (issue 18). Per frame, a pixel's log-density is one table look-up on its
quantised colour (:func:`server.occlusion.colour.colour_index`): the table is evaluated once per
refit at the bin centres, 32768 entries at 5 bits per channel, instead of K Gaussians per pixel.
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

from server.occlusion.colour import bin_centres

# Log of the uniform density over the code cube (codes 0-255 per channel).
LOG_UNIFORM = -3.0 * np.log(256.0)


def em_from_posteriors(x: np.ndarray, probs: np.ndarray, max_iter: int, eps: float
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """EM for a full-covariance Gaussian mixture started with an M-step from posteriors.

    The iteration of OpenCV's ``EM::trainM`` (ml/src/em.cpp ``doTrain``): an M-step from
    ``probs``, then up to ``max_iter`` E-steps with an M-step between them, stopping early when
    the log-likelihood falls or rises by less than ``eps`` times its magnitude. The returned
    parameters are those of the last M-step (as OpenCV's getters give them).

    x : (N, 3) float64 samples; probs : (N, K) float64 posteriors, rows summing to 1.
    Returns (means (K, 3), covs (K, 3, 3), weights (K,)) or None when a covariance is not
    positive definite (the caller keeps its model, as when OpenCV's EM fails).
    """
    n = len(x)
    min_pos_weight = n * np.finfo(np.float64).eps  # OpenCV's threshold for an empty component
    prev_ll = 0.0
    means = covs = weights = None
    for it in range(max_iter + 1):
        if it > 0:  # E-step from the last M-step's parameters
            try:
                chol = np.linalg.cholesky(covs)  # (K, 3, 3)
            except np.linalg.LinAlgError:
                return None
            inv = np.linalg.inv(chol)
            d = x[None, :, :] - means[:, None, :]  # (K, N, 3)
            z = d @ inv.transpose(0, 2, 1)  # (K, N, 3) whitened (batched matmul: einsum is slower)
            logdet = 2.0 * np.log(np.diagonal(chol, axis1=1, axis2=2)).sum(1)
            with np.errstate(divide="ignore"):  # an empty component: weight 0, as in OpenCV
                log_w = np.log(weights)
            logs = (log_w - 0.5 * logdet)[:, None] - 0.5 * (z * z).sum(2)  # (K, N)
            top = logs.max(0)
            e = np.exp(logs - top)
            total = e.sum(0)
            ll = float((top + np.log(total)).sum()) - 1.5 * n * np.log(2 * np.pi)
            probs = (e / total).T
            if it >= max_iter:
                break
            delta = ll - prev_ll
            if it > 1 and (delta < -np.finfo(np.float64).eps or delta < eps * abs(ll)):
                break
            prev_ll = ll
        # M-step (components whose posteriors sum to ~0 copy the lightest non-empty one)
        nk = probs.sum(0)  # (K,)
        live = nk > min_pos_weight
        if not live.any():
            return None
        safe = np.where(live, nk, 1.0)
        means = (probs.T @ x) / safe[:, None]
        d = x[None, :, :] - means[:, None, :]
        covs = ((probs.T[:, :, None] * d).transpose(0, 2, 1) @ d) / safe[:, None, None]
        if not live.all():
            donor = np.flatnonzero(live)[np.argmin(nk[live])]
            means[~live], covs[~live] = means[donor], covs[donor]
        weights = nk / n
    return means, covs, weights


@functools.cache
def _centres_t(bits: int) -> np.ndarray:
    """(3, 2^(3 bits)) float32 bin centres, channels first (for ``_component_logs``)."""
    return np.ascontiguousarray(bin_centres(bits).T, dtype=np.float32)


class ColourMixture:
    """A Gaussian mixture over BGR codes.

    Attributes
    ----------
    means : (K, 3) float64, codes
    covs : (K, 3, 3) float64, codes^2
    weights : (K,) float64, summing to 1
    """

    def __init__(self, components: int, var_floor: float = 16.0, max_iter: int = 10):
        self.components = int(components)
        self.var_floor = float(var_floor)  # codes^2: no narrower than a look-up bin
        self.max_iter = int(max_iter)
        self.means: np.ndarray | None = None
        self.covs: np.ndarray | None = None
        self.weights: np.ndarray | None = None

    @property
    def fitted(self) -> bool:
        return self.means is not None

    def fit(self, samples_bgr: np.ndarray, warm: bool = True) -> bool:
        """Fit to (N, 3) colour samples; returns False (model unchanged) if EM fails.

        With ``warm`` and an existing fit, EM starts from it (a few iterations suffice when the
        colours drift slowly; numpy, :func:`em_from_posteriors`); otherwise OpenCV's EM from
        k-means.
        """
        x = np.ascontiguousarray(samples_bgr, dtype=np.float64).reshape(-1, 3)
        k = min(self.components, max(1, len(x) // 20))
        if len(x) < 3 * k:
            return False
        # A little jitter: quantised codes would otherwise give singular covariances.
        x = x + np.random.default_rng(len(x)).uniform(-0.5, 0.5, x.shape)
        if warm and self.fitted and len(self.means) == k:
            # Start from the previous fit: its posteriors feed the first M-step.
            logs = self._component_logs(np.ascontiguousarray(x.T))
            probs = np.exp(logs - logs.max(axis=0))
            fit = em_from_posteriors(x, (probs / probs.sum(axis=0)).T, self.max_iter, 1e-3)
            if fit is None:
                return False
            means, covs, weights = fit
        else:
            em = cv2.ml.EM_create()
            em.setClustersNumber(k)
            em.setCovarianceMatrixType(cv2.ml.EM_COV_MAT_GENERIC)
            em.setTermCriteria((cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, self.max_iter,
                                1e-3))
            # k-means draws its first centres from OpenCV's global generator: seeded here,
            # so a processor's masks do not depend on what ran before it in the process
            # (the same frames gave person IoU 0.887 first in a process, 0.885 after another).
            cv2.setRNGSeed(len(x))
            try:
                ok = em.trainEM(x)[0]
            except cv2.error:
                return False
            if not ok:
                return False
            means = np.asarray(em.getMeans(), dtype=np.float64).reshape(k, 3)
            covs = np.asarray(em.getCovs(), dtype=np.float64).reshape(k, 3, 3)
            weights = np.asarray(em.getWeights(), dtype=np.float64).reshape(k)
        if not (np.all(np.isfinite(means)) and np.all(np.isfinite(covs))):
            return False
        covs = covs + self.var_floor * np.eye(3)[None]
        weights = np.clip(weights, 1e-6, None)
        self.means, self.covs, self.weights = means, covs, weights / weights.sum()
        return True

    def _component_logs(self, x_t: np.ndarray) -> np.ndarray:
        """(K, N) ``ln(w_k N(x; mu_k, Sigma_k))`` of points given channels first, (3, N)
        (dtype of ``x_t``).

        Channels first: the whitening is one (3, 3) @ (3, N) product per component and the
        squares are summed over contiguous rows (a third of the time of (N, 3) points).
        """
        logs = np.empty((len(self.means), x_t.shape[1]), dtype=x_t.dtype)
        for k, (mu, cov, w) in enumerate(zip(self.means, self.covs, self.weights, strict=True)):
            L_inv = np.linalg.inv(np.linalg.cholesky(cov))
            z = L_inv.astype(x_t.dtype) @ (x_t - mu.astype(x_t.dtype)[:, None])  # (3, N) whitened
            logdet = -2.0 * np.log(np.diag(L_inv)).sum()
            const = np.log(w) - 0.5 * logdet - 1.5 * np.log(2 * np.pi)
            logs[k] = const - 0.5 * (z[0] * z[0] + z[1] * z[1] + z[2] * z[2])
        return logs

    def table(self, bits: int, uniform_weight: float = 0.0) -> np.ndarray:
        """(2^(3 bits),) float32 log-density at each bin centre, optionally mixed with uniform.

        ``ln((1 - u) p(x) + u / 256^3)``; an unfitted mixture gives the uniform density alone.
        """
        n = 1 << (3 * bits)
        if not self.fitted:
            return np.full(n, LOG_UNIFORM, dtype=np.float32)
        logs = self._component_logs(_centres_t(bits))
        top = logs.max(0)
        logp = top + np.log(np.exp(logs - top).sum(0))
        if uniform_weight > 0.0:
            logp = np.logaddexp(np.log1p(-uniform_weight) + logp, np.log(uniform_weight)
                                + LOG_UNIFORM) if uniform_weight < 1.0 else np.full(n, LOG_UNIFORM)
        return logp.astype(np.float32)
