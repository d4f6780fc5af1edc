"""Smoothing the indirect bounce within each flat surface.

The bounce is estimated per texel with a few dozen cosine-weighted rays. Where it is the only
light (in full shadow next to a sunlit wall) single texels spike: 24 rays of which two happen
to hit the sunlit wall. Indirect light varies slowly across a surface, so the bounce part (never
the exact direct part) is filtered with a Gaussian, normalized within each flat region — a
plane receiver, a flat face of a model part, or the flat surface a view's pixels see — so
light never bleeds from one surface onto another. Lightmappers do the same.
"""

from __future__ import annotations

import cv2
import numpy as np

MAX_CHANNELS = 128  # OpenCV 5 rejects images of more channels (measured: 256 fails)


def smooth_within_labels(image: np.ndarray, labels: np.ndarray, sigma_px: float) -> np.ndarray:
    """Gaussian-smooth ``image`` (H, W, ...) separately inside each label of ``labels`` (H, W).

    Texels with label < 0 are left as they are (zero in practice) and never contribute.
    Returns a new float32 array of the same shape.
    """
    h, w = labels.shape
    flat = np.ascontiguousarray(image, dtype=np.float32).reshape(h, w, -1)
    out = flat.copy()
    radius = int(np.ceil(3.0 * sigma_px))
    kernel = (2 * radius + 1, 2 * radius + 1)
    for label in np.unique(labels[labels >= 0]):
        ys, xs = np.nonzero(labels == label)
        y0, y1 = max(ys.min() - radius, 0), min(ys.max() + radius + 1, h)
        x0, x1 = max(xs.min() - radius, 0), min(xs.max() + radius + 1, w)
        mask = (labels[y0:y1, x0:x1] == label).astype(np.float32)
        weight = cv2.GaussianBlur(mask, kernel, sigma_px, borderType=cv2.BORDER_CONSTANT)
        inside = mask > 0
        for c0 in range(0, flat.shape[2], MAX_CHANNELS):
            c1 = min(c0 + MAX_CHANNELS, flat.shape[2])
            region = flat[y0:y1, x0:x1, c0:c1] * mask[:, :, None]
            blurred = cv2.GaussianBlur(region, kernel, sigma_px, borderType=cv2.BORDER_CONSTANT)
            blurred = blurred.reshape(region.shape)  # OpenCV drops a single channel axis
            out[y0:y1, x0:x1, c0:c1][inside] = blurred[inside] / weight[inside][:, None]
    return out.reshape(image.shape)


def surface_labels(part: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """One label per distinct (part, face normal) pair: the flat surfaces. (m,) int."""
    key = np.concatenate([part[:, None].astype(np.float64), np.round(normals, 2)], axis=1)
    _, labels = np.unique(key, axis=0, return_inverse=True)
    return labels.ravel()
