"""Gaussian mixtures of colour (Kakuta Sec. 3.1.1) and their look-up tables.

The mixtures are fitted with OpenCV's EM (``cv2.ml.EM``, full covariances), warm-started from
the previous fit when one exists. Per frame, a pixel's log-density is one table look-up on its
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


@functools.cache
def _centres(bits: int) -> np.ndarray:
    return bin_centres(bits).astype(np.float32)


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
        colours drift slowly); otherwise from k-means.
        """
        x = np.ascontiguousarray(samples_bgr, dtype=np.float64).reshape(-1, 3)
        k = min(self.components, max(1, len(x) // 20))
        if len(x) < 3 * k:
            return False
        # A little jitter: quantised codes would otherwise give singular covariances.
        x = x + np.random.default_rng(len(x)).uniform(-0.5, 0.5, x.shape)
        em = cv2.ml.EM_create()
        em.setClustersNumber(k)
        em.setCovarianceMatrixType(cv2.ml.EM_COV_MAT_GENERIC)
        em.setTermCriteria((cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, self.max_iter, 1e-3))
        try:
            if warm and self.fitted and len(self.means) == k:
                # Start from the previous fit: its posteriors feed the first M-step. (trainE
                # would take the parameters directly, but its Python binding cannot pass covs.)
                logs = self._component_logs(x)
                probs = np.exp(logs - logs.max(axis=0))
                probs = (probs / probs.sum(axis=0)).T
                ok = em.trainM(x, np.ascontiguousarray(probs))[0]
            else:
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

    def _component_logs(self, x: np.ndarray) -> np.ndarray:
        """(K, N) ``ln(w_k N(x; mu_k, Sigma_k))`` of (N, 3) points (dtype of ``x``)."""
        logs = np.empty((len(self.means), len(x)), dtype=x.dtype)
        for k, (mu, cov, w) in enumerate(zip(self.means, self.covs, self.weights, strict=True)):
            L_inv = np.linalg.inv(np.linalg.cholesky(cov))
            z = (x - mu.astype(x.dtype)) @ L_inv.T.astype(x.dtype)  # (N, 3) whitened
            logdet = -2.0 * np.log(np.diag(L_inv)).sum()
            const = np.log(w) - 0.5 * logdet - 1.5 * np.log(2 * np.pi)
            logs[k] = const - 0.5 * (z[:, 0] * z[:, 0] + z[:, 1] * z[:, 1] + z[:, 2] * z[:, 2])
        return logs

    def table(self, bits: int, uniform_weight: float = 0.0) -> np.ndarray:
        """(2^(3 bits),) float32 log-density at each bin centre, optionally mixed with uniform.

        ``ln((1 - u) p(x) + u / 256^3)``; an unfitted mixture gives the uniform density alone.
        """
        n = 1 << (3 * bits)
        if not self.fitted:
            return np.full(n, LOG_UNIFORM, dtype=np.float32)
        logs = self._component_logs(_centres(bits))
        top = logs.max(0)
        logp = top + np.log(np.exp(logs - top).sum(0))
        if uniform_weight > 0.0:
            logp = np.logaddexp(np.log1p(-uniform_weight) + logp, np.log(uniform_weight)
                                + LOG_UNIFORM) if uniform_weight < 1.0 else np.full(n, LOG_UNIFORM)
        return logp.astype(np.float32)
