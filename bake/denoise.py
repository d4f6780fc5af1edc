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

from bake.labelgroups import label_boxes, label_groups

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
    plan: dict | None = None, only: np.ndarray | None = None,
) -> np.ndarray:
    """Gaussian-smooth ``image`` (H, W, ...) separately inside each label of ``labels`` (H, W).

    ``order=0``: the normalised Gaussian mean; ``order=1``: the value at each texel of the
    Gaussian-weighted least-squares plane through its label's texels (no first-order bias at
    a label's edges; see the module's docstring), never below zero. Texels with label < 0 are
    left as they are and never contribute. Returns a new float32 array of the same shape.

    The labels are smoothed a group at a time (:func:`bake.labelgroups.label_groups`: pieces
    of labels more than the kernel's radius apart share one blur), with the values of a fit
    of each label in its own bounding box (:func:`smooth_label_by_label`): the same bits but
    within the kernel's radius of the image's right edge, where the last bit can differ.

    ``only`` (H, W) bool or None: the values are needed at these texels only; labels' pieces
    without one are left as they are (same values where they are needed).

    ``plan``: a dict kept by a caller that smooths several images with the same ``labels``
    (and ``only``: a stack's blocks of lights): each group's texels and fit weights (which
    depend on the labels only: (K,) float64 per weight, K the group's texels) are computed on
    the first call and reused (the same values); its mask and the coordinate images are made
    again per call.
    """
    if order not in (0, 1):
        raise ValueError(f"order must be 0 or 1, got {order}")
    h, w = labels.shape
    flat = np.ascontiguousarray(image, dtype=np.float32).reshape(h, w, -1)
    out = flat.copy()
    radius, blur = gaussian(sigma_px)
    key = (sigma_px, order, None if only is None else "only")
    groups = None if plan is None else plan.get(key)
    if groups is None:
        groups = _fit_groups(labels, radius, blur, sigma_px, order, only)
        if plan is not None:
            groups = plan[key] = list(groups)
    for (y0, y1, x0, x1), texels, local, kept in groups:
        mask, coordinates = _group_images((y1 - y0, x1 - x0), texels, local, order)
        weights = list(zip(kept, coordinates, strict=True))
        _fit_box(flat, out, (y0, y1, x0, x1), mask, weights, blur, order)
    return out.reshape(image.shape)


def _fit_box(flat: np.ndarray, out: np.ndarray, box: tuple, mask: np.ndarray, weights: list,
             blur, order: int) -> None:
    """Fit the texels of ``mask`` (float32, 1 inside) in ``box`` (y0, y1, x0, x1) of ``flat``
    (H, W, C) into ``out`` (same shape), by blocks of channels (:func:`fitted_values`; order
    1 in float64, clipped at 0)."""
    y0, y1, x0, x1 = box
    inside = mask > 0
    for c0, c1 in channel_blocks(flat.shape[2], mask.size):
        region = flat[y0:y1, x0:x1, c0:c1] * mask[:, :, None]
        if order == 1:  # G(m x v) - x0 G(m v) cancels: float32 loses 1e-4 of v at x ~ 400
            region = region.astype(np.float64)
        value = fitted_values(region, weights, blur, inside)
        if order == 1:
            value = np.maximum(value, 0.0)
        out[y0:y1, x0:x1, c0:c1][inside] = value


def _group_images(shape: tuple, texels: np.ndarray, local: np.ndarray, order: int):
    """A group's mask (``shape``, float32: 1 at its ``texels``, flat indices) and the
    coordinate images each fit weight multiplies (:func:`plane_weights`' order): None for
    the mean (order 0); None, x, y (float64, ``shape``; ``local`` (2, K) at the texels, the
    coordinates in each texel's own label's box) for the plane (order 1)."""
    mask = np.zeros(shape, np.float32)
    mask.flat[texels] = 1.0
    if order == 0:
        return mask, [None]
    xx, yy = np.zeros(shape), np.zeros(shape)
    xx.flat[texels], yy.flat[texels] = local[0], local[1]
    return mask, [None, xx, yy]


def _fit_groups(labels, radius: int, blur, sigma_px: float, order: int, only=None):
    """Per group of ``labels`` (:func:`bake.labelgroups.label_groups`): its box, texels,
    local coordinates and its fit weights' (K,) arrays (:func:`plane_weights` or the
    mean's, without their coordinate images: :func:`_group_images`)."""
    for box, texels, local in label_groups(labels, radius, only):
        mask, coordinates = _group_images((box[1] - box[0], box[3] - box[2]), texels, local,
                                          order)
        inside = mask > 0
        if order == 0:
            weights = [(blur(mask)[inside] ** -1, None)]
        else:
            weights = plane_weights(mask.astype(np.float64), inside, blur, sigma_px,
                                    coordinates[1:])
        yield box, texels, local, [w for w, _ in weights]


def smooth_label_by_label(image: np.ndarray, labels: np.ndarray, sigma_px: float,
                          order: int = 0) -> np.ndarray:
    """:func:`smooth_within_labels` one label at a time in its bounding box grown by the
    kernel's radius (the code before issue 20's groups, kept as the tests' reference: the
    same bits, far slower where a label's pieces are scattered over an atlas)."""
    h, w = labels.shape
    flat = np.ascontiguousarray(image, dtype=np.float32).reshape(h, w, -1)
    out = flat.copy()
    radius, blur = gaussian(sigma_px)
    boxes = label_boxes(labels)
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
        _fit_box(flat, out, (y0, y1, x0, x1), mask, weights, blur, order)
    return out.reshape(image.shape)


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


def plane_weights(mask: np.ndarray, inside: np.ndarray, blur, sigma_px: float,
                  coordinates: list | None = None) -> list:
    """For a Gaussian-weighted plane fit ``a + b (x - x0) + c (y - y0)`` at every texel
    ``(x0, y0)`` of ``mask``: ``a = w_0 G(m v) + w_x G(m x v) + w_y G(m y v)`` (``G`` the blur,
    ``m`` the mask, ``v`` the values). Returns ``[(w_0, None), (w_x, x), (w_y, y)]``, the
    weights (K,) at the ``inside`` texels and the coordinate images (texels, float64).
    ``inside`` need not lie in the mask: the plane is then continued to those texels
    (bake.contact). ``coordinates``: the images ``[x, y]`` (float64, as ``mask``) to use
    instead of each texel's column and row in ``mask`` (a group of labels: each texel's
    coordinates in its own label's box, :func:`smooth_within_labels`)."""
    if coordinates is None:
        hh, ww = mask.shape
        yy, xx = np.mgrid[0:hh, 0:ww].astype(np.float64)
    else:
        xx, yy = coordinates
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
    boxes = label_boxes(labels)  # one pass, not one per label
    for label in np.unique(labels[fill]):
        rows, columns = boxes[label]
        y0, y1, x0, x1 = rows.start, rows.stop, columns.start, columns.stop
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
