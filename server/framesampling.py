"""Which of the pool's pixels a frame of the scene estimate reads, and how (server.sceneestimate):
the pick of samples in sun and in shadow, each sample's patch of pixels, and whether it is
usable (finite, not clipped, not marked by the occlusion mask).

:class:`FrameSampling` is a mixin of :class:`server.sceneestimate.SceneEstimator` (its
``samples``, ``patch_px`` and random generator).
"""

from __future__ import annotations

import numpy as np


class FrameSampling:
    """How :class:`server.sceneestimate.SceneEstimator` samples a frame (a mixin)."""

    def _pick(self, lit: np.ndarray, count: int | None = None) -> np.ndarray:
        """``count`` (default ``samples``) pool indices, half mostly in sun and half mostly in
        shadow (``lit``, the share in sun, from 0.5 or below it) where the pool has them (the
        shadowed ones are what tells the sky from the sun)."""
        count = self.samples if count is None else count
        groups = [np.flatnonzero(lit >= 0.5), np.flatnonzero(lit < 0.5)]
        want = count // 2
        small = min(groups, key=len)
        large = max(groups, key=len)
        take_small = min(len(small), want)
        take_large = min(len(large), count - take_small)
        return np.concatenate([self._rng.choice(small, take_small, replace=False),
                               self._rng.choice(large, take_large, replace=False)])

    def read_pixels(self, image: np.ndarray, pixels_xy: np.ndarray,
                    to_linear=None, patch_px: int | None = None) -> np.ndarray:
        """The ``(2 patch_px + 1)^2`` pixels about each pixel, (k, m, 3) linear RGB:
        ``image`` (H, W, >=3) as it is, or through ``to_linear`` (codes (..., 3) -> linear),
        which then runs on these pixels only, never on the whole frame. ``patch_px``: the
        estimator's unless given (0: the pixel alone)."""
        r = self.patch_px if patch_px is None else patch_px
        dy, dx = np.mgrid[-r:r + 1, -r:r + 1]
        ys = pixels_xy[None, :, 1] + dy.ravel()[:, None]
        xs = pixels_xy[None, :, 0] + dx.ravel()[:, None]
        raw = image[ys, xs, :3]
        return (to_linear(raw) if to_linear is not None else raw).astype(np.float64)

    def read_usable(self, image: np.ndarray, pixels_xy: np.ndarray, to_linear=None,
                    clip_level: float | None = None, ignore_mask: np.ndarray | None = None,
                    patch_px: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Each sample's patch mean (m, 3) linear (:meth:`read_pixels`) and (m,) bool whether
        it is usable: finite, not negative, no pixel of its patch at ``clip_level``, not
        marked by ``ignore_mask`` (H, W bool)."""
        patches = self.read_pixels(image, pixels_xy, to_linear, patch_px)
        values = patches.mean(axis=0)
        usable = np.all(np.isfinite(values), axis=1) & (values.min(axis=1) >= 0.0)
        if clip_level is not None:
            usable &= patches.max(axis=(0, 2)) < clip_level
        if ignore_mask is not None:
            usable &= ~np.asarray(ignore_mask, bool)[pixels_xy[:, 1], pixels_xy[:, 0]]
        return values, usable

