"""Smoothing the indirect bounce within each flat surface.

The bounce is estimated per texel with a few dozen cosine-weighted rays. Where it is the only
light (in full shadow next to a sunlit wall) single texels spike: 24 rays of which two happen
to hit the sunlit wall. Indirect light varies slowly across a surface, so the bounce part (never
the exact direct part) is filtered with a Gaussian, normalized within each flat region — a
plane receiver, a flat face of a model part, or the flat surface a view's pixels see — so
light never bleeds from one surface onto another. Lightmappers do the same.

Two things keep the filter honest at a surface's edges, where the bounce changes fastest (at
the foot of a sunlit wall the ground's bounce halves within a metre):

- **Buried texels** (inside another solid: the ground under a building, a podium's top under
  the hall) see nothing; their bounce is not light anyone sees and must not be averaged into
  their open neighbours'. They are left out of the filter and take the bounce of the nearest
  open texel of their surface (:func:`fill_from_nearest`), so that bilinear filtering at the
  edge reads open values.
- **Local linear fit** (``order=1``): a normalised Gaussian at an edge reaches only inward and
  returns the mean of the inward values, biased toward them wherever the bounce has a slope.
  A Gaussian-weighted least-squares plane ``a + b dx + c dy`` has no first-order bias; its
  slopes are ridge-regularised (``RIDGE`` times the kernel's own second moment), so a strip
  one texel wide falls back to the weighted mean across it.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.ndimage import find_objects

MAX_CHANNELS = 128  # OpenCV 5 rejects images of more channels (measured: 256 fails)
# Bytes of one float64 working array of a fit (a surface's bounding box x the channels done at
# once): a surface whose charts are spread over a whole atlas has a bounding box of the atlas,
# and a fit holds several such arrays (docs/benchmarks.md, "A large site").
FIT_BYTES = 64 << 20
# Ridge on the local fit's slopes, as a fraction of the kernel's second moment (sigma^2 times
# its weight): enough to keep a one-texel strip's fit finite (no spread across it: its slope
# across is then 0), small enough not to shrink the slope that an edge's value needs.
RIDGE = 1e-6


def smooth_within_labels(
    image: np.ndarray, labels: np.ndarray, sigma_px: float, order: int = 0,
    plan: dict | None = None,
) -> np.ndarray:
    """Gaussian-smooth ``image`` (H, W, ...) separately inside each label of ``labels`` (H, W).

    ``order=0``: the normalised Gaussian mean; ``order=1``: the value at each texel of the
    Gaussian-weighted least-squares plane through its label's texels (no first-order bias at
    a label's edges; see the module's docstring), never below zero. Texels with label < 0 are
    left as they are and never contribute. Returns a new float32 array of the same shape.

    ``plan``: a dict kept by a caller that smooths several images with the same ``labels``
    (a stack's blocks of lights): each label's box and fit weights (which depend on the
    labels only: (K,) per weight, K the label's texels) are computed on the first call and
    reused (the same values); its mask and the coordinate images are made again per call
    (kept, they were box-sized float64 images for every label at once: 9 GB for the
    palace's lightmap).
    """
    if order not in (0, 1):
        raise ValueError(f"order must be 0 or 1, got {order}")
    h, w = labels.shape
    flat = np.ascontiguousarray(image, dtype=np.float32).reshape(h, w, -1)
    out = flat.copy()
    radius, blur = gaussian(sigma_px)
    key = (sigma_px, order)
    regions = None if plan is None else plan.get(key)
    if regions is None:
        regions = _fit_regions(labels, radius, blur, sigma_px, order)
        if plan is not None:
            regions = plan[key] = list(regions)
    for (y0, y1, x0, x1), label, kept in regions:
        mask = (labels[y0:y1, x0:x1] == label).astype(np.float32)
        inside = mask > 0
        weights = list(zip(kept, _coordinates(mask.shape, order), strict=True))
        for c0, c1 in channel_blocks(flat.shape[2], mask.size):
            region = flat[y0:y1, x0:x1, c0:c1] * mask[:, :, None]
            if order == 1:  # G(m x v) - x0 G(m v) cancels: float32 loses 1e-4 of v at x ~ 400
                region = region.astype(np.float64)
            value = fitted_values(region, weights, blur, inside)
            if order == 1:
                value = np.maximum(value, 0.0)
            out[y0:y1, x0:x1, c0:c1][inside] = value
    return out.reshape(image.shape)


def _coordinates(shape: tuple, order: int) -> list:
    """The coordinate image each fit weight multiplies (:func:`plane_weights`' order): None
    for the mean (order 0); None, x, y (float64, ``shape``) for the plane (order 1)."""
    if order == 0:
        return [None]
    yy, xx = np.mgrid[0 : shape[0], 0 : shape[1]].astype(np.float64)
    return [None, xx, yy]


def _fit_regions(labels: np.ndarray, radius: int, blur, sigma_px: float, order: int):
    """Per label of ``labels`` (>= 0): its box (y0, y1, x0, x1) grown by ``radius``, the
    label, and its fit weights' (K,) arrays (:func:`plane_weights` or the mean's, without
    their coordinate images: :func:`_coordinates`)."""
    h, w = labels.shape
    # Each label's bounding box in one pass over the image (a search of the whole image per
    # label was 42 s of CPU per call on the palace's lightmap of 10,146 surfaces).
    boxes = find_objects(np.where(labels >= 0, labels + 1, 0))
    for label in np.unique(labels[labels >= 0]):
        rows, columns = boxes[label]
        y0, y1 = max(rows.start - radius, 0), min(rows.stop + radius, h)
        x0, x1 = max(columns.start - radius, 0), min(columns.stop + radius, w)
        mask = (labels[y0:y1, x0:x1] == label).astype(np.float32)
        inside = mask > 0
        if order == 0:
            weights = [(blur(mask)[inside] ** -1, None)]
        else:
            weights = plane_weights(mask.astype(np.float64), inside, blur, sigma_px)
        yield (y0, y1, x0, x1), label, [w for w, _ in weights]


def channel_blocks(channels: int, texels: int) -> list[tuple[int, int]]:
    """``(first, stop)`` blocks of ``channels`` fitted at a time over a region of ``texels``:
    at most :data:`MAX_CHANNELS`, and few enough that a float64 working array stays within
    :data:`FIT_BYTES` (at least one channel). Each channel is fitted on its own, so the
    blocks give the same values whatever their size."""
    step = max(1, min(MAX_CHANNELS, FIT_BYTES // (8 * max(texels, 1))))
    return [(c, min(c + step, channels)) for c in range(0, channels, step)]


def gaussian(sigma_px: float):
    """(radius, blur): a Gaussian of ``sigma_px`` texels cut at 3 sigma (``radius`` texels),
    and ``blur(a)`` applying it to an (h, w) or (h, w, C) array, zero outside the array."""
    radius = int(np.ceil(3.0 * sigma_px))
    kernel = (2 * radius + 1, 2 * radius + 1)

    def blur(a):
        b = cv2.GaussianBlur(a, kernel, sigma_px, borderType=cv2.BORDER_CONSTANT)
        return b.reshape(a.shape)  # OpenCV drops a single channel axis

    return radius, blur


def fitted_values(region: np.ndarray, weights: list, blur, at: np.ndarray) -> np.ndarray:
    """The local fit's value at the ``at`` texels, (K, C) float64: the sum over ``weights``
    (:func:`plane_weights`, or one ``(w, None)``) of ``w G(region x coordinate)[at]``;
    ``region`` (h, w, C) holds the masked values."""
    value = np.zeros((int(at.sum()), region.shape[2]), dtype=np.float64)
    for weight, coordinate in weights:
        moment = region if coordinate is None else region * coordinate[:, :, None]
        value += blur(moment)[at] * weight[:, None]
    return value


def plane_weights(mask: np.ndarray, inside: np.ndarray, blur, sigma_px: float) -> list:
    """For a Gaussian-weighted plane fit ``a + b (x - x0) + c (y - y0)`` at every texel
    ``(x0, y0)`` of ``mask``: ``a = w_0 G(m v) + w_x G(m x v) + w_y G(m y v)`` (``G`` the blur,
    ``m`` the mask, ``v`` the values). Returns ``[(w_0, None), (w_x, x), (w_y, y)]``, the
    weights (K,) at the ``inside`` texels and the coordinate images (texels, float64).
    ``inside`` need not lie in the mask: the plane is then continued to those texels
    (bake.contact)."""
    hh, ww = mask.shape
    yy, xx = np.mgrid[0:hh, 0:ww].astype(np.float64)
    S = {k: blur(mask * f) for k, f in (("1", 1.0), ("x", xx), ("y", yy), ("xx", xx * xx),
                                         ("xy", xx * yy), ("yy", yy * yy))}
    S = {k: v[inside] for k, v in S.items()}
    x0, y0 = xx[inside], yy[inside]
    # Moments about each texel.
    s00 = S["1"]
    s10 = S["x"] - x0 * s00
    s01 = S["y"] - y0 * s00
    ridge = RIDGE * sigma_px**2 * s00
    s20 = S["xx"] - 2 * x0 * S["x"] + x0 * x0 * s00 + ridge
    s02 = S["yy"] - 2 * y0 * S["y"] + y0 * y0 * s00 + ridge
    s11 = S["xy"] - x0 * S["y"] - y0 * S["x"] + x0 * y0 * s00
    M = np.stack([np.stack([s00, s10, s01], -1), np.stack([s10, s20, s11], -1),
                  np.stack([s01, s11, s02], -1)], -2)  # (K, 3, 3), symmetric
    first = np.linalg.solve(M, np.broadcast_to(np.eye(3)[0], (len(s00), 3))[..., None])[..., 0]
    w0, wx, wy = first[:, 0], first[:, 1], first[:, 2]
    return [(w0 - wx * x0 - wy * y0, None), (wx, xx), (wy, yy)]


def fill_from_nearest(image: np.ndarray, labels: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Texels of a label not in ``keep`` (H, W) bool take the value of the nearest ``keep``
    texel of the same label (where it has one); ``image`` (H, W, ...) is changed in place and
    returned."""
    from scipy.ndimage import distance_transform_edt

    fill = (labels >= 0) & ~keep
    for label in np.unique(labels[fill]):
        ys, xs = np.nonzero(labels == label)
        y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
        own = labels[y0:y1, x0:x1] == label
        source = own & keep[y0:y1, x0:x1]
        if not source.any():
            continue
        _, (iy, ix) = distance_transform_edt(~source, return_indices=True)
        todo = own & ~source
        ty, tx = np.nonzero(todo)
        image[y0 + ty, x0 + tx] = image[y0 + iy[ty, tx], x0 + ix[ty, tx]]
    return image


def surface_labels(part: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """One label per distinct (part, face normal) pair: the flat surfaces. (m,) int."""
    key = np.concatenate([part[:, None].astype(np.float64), np.round(normals, 2)], axis=1)
    _, labels = np.unique(key, axis=0, return_inverse=True)
    return labels.ravel()
