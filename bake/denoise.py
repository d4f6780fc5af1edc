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

The fit's sums are taken about each texel with the Gaussian's moment kernels (``d g(d)``,
``d^2 g(d)``: :class:`MomentBlurs`), not as blurs of coordinate images less the texel's own
coordinate times the plain blur: nothing cancels, so the values are blurred in float32, and
a texel's fit depends only on the offsets within its window, never on where its label lies.
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
# Elements (columns x channels) past a row's end that OpenCV's vector loops may leave to its
# scalar code: they step by one to a few vectors (8 floats each with AVX2, 16 with AVX-512).
ROW_TAIL_ELEMENTS = 128


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
    of each label in its own bounding box (:func:`smooth_label_by_label`): the same bits
    (:class:`MomentBlurs` pads each row past OpenCV's scalar tail).

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
    blurs = MomentBlurs(sigma_px)
    key = (sigma_px, order, None if only is None else "only")
    groups = None if plan is None else plan.get(key)
    if groups is None:
        groups = _fit_groups(labels, blurs, sigma_px, order, only)
        if plan is not None:
            groups = plan[key] = list(groups)
    for (y0, y1, x0, x1), texels, weights in groups:
        mask = np.zeros((y1 - y0, x1 - x0), np.float32)
        mask.flat[texels] = 1.0
        _fit_box(flat, out, (y0, y1, x0, x1), mask, weights, blurs, order)
    return out.reshape(image.shape)


def _fit_box(flat: np.ndarray, out: np.ndarray, box: tuple, mask: np.ndarray, weights: list,
             blurs: MomentBlurs, order: int) -> None:
    """Fit the texels of ``mask`` (float32, 1 inside) in ``box`` (y0, y1, x0, x1) of ``flat``
    (H, W, C) into ``out`` (same shape), by blocks of channels (:func:`fitted_values`; order
    1 clipped at 0)."""
    y0, y1, x0, x1 = box
    inside = mask > 0
    for c0, c1 in channel_blocks(flat.shape[2], mask.size):
        region = flat[y0:y1, x0:x1, c0:c1] * mask[:, :, None]
        value = fitted_values(region, weights, blurs, inside)
        if order == 1:
            value = np.maximum(value, 0.0)
        out[y0:y1, x0:x1, c0:c1][inside] = value


def _weights(mask: np.ndarray, inside: np.ndarray, blurs: MomentBlurs, sigma_px: float,
             order: int) -> list:
    """The fit weights of :func:`fitted_values` at the ``inside`` texels of ``mask`` ((h, w)
    float64, 1 at the texels fitted from): the normalised mean's (order 0) or the plane's
    (order 1, :func:`plane_weights`)."""
    if order == 0:
        return [(blurs.blur("1", mask)[inside] ** -1, "1")]
    return plane_weights(mask, inside, blurs, sigma_px)


def _fit_groups(labels, blurs: MomentBlurs, sigma_px: float, order: int, only=None):
    """Per group of ``labels`` (:func:`bake.labelgroups.label_groups`): its box, texels (flat
    indices into the box) and fit weights (:func:`_weights`)."""
    for box, texels in label_groups(labels, blurs.radius, only):
        mask = np.zeros((box[1] - box[0], box[3] - box[2]))
        mask.flat[texels] = 1.0
        yield box, texels, _weights(mask, mask > 0, blurs, sigma_px, order)


def smooth_label_by_label(image: np.ndarray, labels: np.ndarray, sigma_px: float,
                          order: int = 0) -> np.ndarray:
    """:func:`smooth_within_labels` one label at a time in its bounding box grown by the
    kernel's radius (the code before issue 20's groups, kept as the tests' reference: the
    same bits, far slower where a label's pieces are scattered over an atlas)."""
    h, w = labels.shape
    flat = np.ascontiguousarray(image, dtype=np.float32).reshape(h, w, -1)
    out = flat.copy()
    blurs = MomentBlurs(sigma_px)
    radius = blurs.radius
    boxes = label_boxes(labels)
    for label in np.unique(labels[labels >= 0]):
        rows, columns = boxes[label]
        y0, y1 = max(rows.start - radius, 0), min(rows.stop + radius, h)
        x0, x1 = max(columns.start - radius, 0), min(columns.stop + radius, w)
        mask = (labels[y0:y1, x0:x1] == label).astype(np.float32)
        weights = _weights(mask.astype(np.float64), mask > 0, blurs, sigma_px, order)
        _fit_box(flat, out, (y0, y1, x0, x1), mask, weights, blurs, order)
    return out.reshape(image.shape)


def channel_blocks(channels: int, texels: int) -> list[tuple[int, int]]:
    """``(first, stop)`` blocks of ``channels`` fitted at a time over a region of ``texels``:
    at most :data:`MAX_CHANNELS`, and few enough that a float64 working array stays within
    :data:`FIT_BYTES` (at least one channel). Each channel is fitted on its own, so the
    blocks give the same values whatever their size."""
    step = max(1, min(MAX_CHANNELS, FIT_BYTES // (8 * max(texels, 1))))
    return [(c, min(c + step, channels)) for c in range(0, channels, step)]


class MomentBlurs:
    """A Gaussian ``g`` of ``sigma_px`` texels cut at 3 sigma (:attr:`radius` texels) and its
    moment blurs by name, each of an (h, w) or (h, w, C) array (float32 or float64), zero
    outside it: ``"1"`` the Gaussian, ``sum_d g(d) a(p + d)``; ``"x"``, ``"y"`` its first
    moments, ``sum_d g(d) d_x a(p + d)`` (``d_x`` the offset in columns, ``d_y`` in rows);
    ``"xx"``, ``"yy"``, ``"xy"`` the second, ``d_x^2``, ``d_y^2``, ``d_x d_y``. All separable
    (OpenCV's ``sepFilter2D``).

    The blurs read arrays with zero columns added on the right (:meth:`padded`; what the
    border gives anyway) so that no texel is left to OpenCV's scalar row tail, which rounds
    otherwise than its vector loop: a texel's bits then depend neither on the channels
    blurred with it nor on where the image ends."""

    def __init__(self, sigma_px: float):
        self.radius = int(np.ceil(3.0 * sigma_px))
        g = cv2.getGaussianKernel(2 * self.radius + 1, sigma_px, cv2.CV_64F)[:, 0]
        d = np.arange(-self.radius, self.radius + 1, dtype=np.float64)
        self.kernels = {"1": (g, g), "x": (d * g, g), "y": (g, d * g), "xx": (d * d * g, g),
                        "yy": (g, d * d * g), "xy": (d * g, d * g)}

    @staticmethod
    def padded(a: np.ndarray) -> np.ndarray:
        """``a`` (h, w[, C]) with zero columns past :data:`ROW_TAIL_ELEMENTS` on the right."""
        channels = a.shape[2] if a.ndim == 3 else 1
        pad = -(-ROW_TAIL_ELEMENTS // channels)
        return cv2.copyMakeBorder(a, 0, 0, 0, pad, cv2.BORDER_CONSTANT, value=0).reshape(
            a.shape[0], a.shape[1] + pad, *a.shape[2:])  # OpenCV drops a single channel axis

    def blur(self, name: str, a: np.ndarray) -> np.ndarray:
        """Blur ``name`` of ``a`` (h, w[, C]), padded for it (:meth:`padded`); a caller that
        blurs one array several ways pads it once and calls :meth:`of_padded`."""
        return self.of_padded(name, self.padded(a), a.shape[1])

    def of_padded(self, name: str, padded: np.ndarray, width: int) -> np.ndarray:
        """Blur ``name`` of an array :meth:`padded` made from one ``width`` columns wide:
        (h, width[, C]), a view."""
        kernel_x, kernel_y = self.kernels[name]
        out = cv2.sepFilter2D(padded, -1, kernel_x, kernel_y, borderType=cv2.BORDER_CONSTANT)
        return out.reshape(padded.shape)[:, :width]


def fitted_values(region: np.ndarray, weights: list, blurs: MomentBlurs,
                  at: np.ndarray) -> np.ndarray:
    """The local fit's value at the ``at`` texels, (K, C) float64: the sum over ``weights``
    (:func:`plane_weights`, or one ``(w, "1")``) of ``w`` times blur ``name`` of ``region``
    at ``at``; ``region`` (h, w, C) holds the masked values (float32: the moment blurs
    cancel nothing)."""
    value = np.zeros((int(at.sum()), region.shape[2]), dtype=np.float64)
    padded = blurs.padded(region)
    for weight, name in weights:
        value += blurs.of_padded(name, padded, region.shape[1])[at] * weight[:, None]
    return value


def plane_weights(mask: np.ndarray, inside: np.ndarray, blurs: MomentBlurs,
                  sigma_px: float) -> list:
    """For a Gaussian-weighted plane fit ``a + b d_x + c d_y`` about every ``inside`` texel
    ``p`` of ``mask`` ((h, w) float64, 1 at the texels fitted from; ``d`` the offset from
    ``p``): ``a = w_1 G(m v) + w_x G_x(m v) + w_y G_y(m v)`` (``G`` the Gaussian, ``G_x``,
    ``G_y`` its first moments: :class:`MomentBlurs`; ``m`` the mask, ``v`` the values).
    Returns ``[(w_1, "1"), (w_x, "x"), (w_y, "y")]``, the weights (K,) float64 at the
    ``inside`` texels by the blur each multiplies. ``inside`` need not lie in the mask: the
    plane is then continued to those texels (bake.contact)."""
    padded = blurs.padded(mask)
    s = {name: blurs.of_padded(name, padded, mask.shape[1])[inside] for name in blurs.kernels}
    ridge = RIDGE * sigma_px**2 * s["1"]
    # The normal equations' moments about each texel: sum g m (1, d_x, d_y) (1, d_x, d_y)^T.
    M = np.stack([np.stack([s["1"], s["x"], s["y"]], -1),
                  np.stack([s["x"], s["xx"] + ridge, s["xy"]], -1),
                  np.stack([s["y"], s["xy"], s["yy"] + ridge], -1)], -2)  # (K, 3, 3)
    first = np.linalg.solve(M, np.broadcast_to(np.eye(3)[0], (len(s["1"]), 3))[..., None])[..., 0]
    return [(first[:, 0], "1"), (first[:, 1], "x"), (first[:, 2], "y")]


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
