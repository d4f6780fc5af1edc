"""Global sub-pixel registration of a shaking camera's frames to the background model.

A site camera on a pole in the wind moves by fractions of a pixel from frame to frame. Compared
pixel by pixel with a still background, every edge of a fixed object then differs by up to its
contrast per pixel of shift, and becomes a phantom person. Each frame is therefore registered
to the background first: one translation ``d = (dx, dy)`` pixels, such that
``frame(x + d) ~ background(x)`` (the scene moved by ``+d`` in the frame), and the frame is
resampled by ``-d`` into the background's pixel grid before it is compared.

The translation is found by Gauss-Newton (Lucas-Kanade with the inverse-compositional trick:
the background's gradients and their 2x2 normal matrix are computed once per background) on
grey images shrunk by ``register_scale`` and blurred by a Gaussian of ``register_blur_px``
(frame pixels), so that the linearisation holds over a few pixels and block artefacts of
codecs average out. Each iteration resamples the frame by the current estimate; pixels whose
residual is larger than ``3 x 1.4826 MAD`` of all residuals (people, their shadows, moving
leaves) are left out of the next step, as are the people of the previous frame
(``exclude``). The estimate starts from the previous frame's shift, so a camera that drifts
slowly is followed over many pixels (at most ``register_max_shift_px``, beyond which the
estimate is rejected and the last one kept).

Arrays: ``reference`` (h, w) float32 grey codes at the registration scale, ``gx``, ``gy`` its
gradients (codes per shrunk pixel); frames (H, W, 3) uint8 BGR at full resolution.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from server.occlusion.settings import OcclusionSettings


def subpixel(d_px: float) -> float:
    """A shift rounded to 1/256 pixel (OpenCV interpolates at 1/32): so exact in float32 that
    an integer offset plus it rounds as it alone does, and a resampling of part of an image
    (:meth:`Registration.align_rects`) gives the codes of the whole-image one."""
    return round(float(d_px) * 256.0) / 256.0


def shift_image(image: np.ndarray, dx_px: float, dy_px: float,
                interpolation: int = cv2.INTER_LINEAR) -> np.ndarray:
    """``out(x, y) = image(x + dx, y + dy)``: (H, W[, C]) in, same shape and dtype out.

    Samples outside the image repeat the border row/column (a shaking camera's border).
    """
    h, w = image.shape[:2]
    m = np.float32([[1, 0, subpixel(dx_px)], [0, 1, subpixel(dy_px)]])
    return cv2.warpAffine(image, m, (w, h), flags=interpolation | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_REPLICATE)


class Registration:
    """The camera's shift against its background, frame by frame; see the module notes.

    Attributes
    ----------
    shift_px : (2,) float64, the last frame's ``(dx, dy)``, full-resolution pixels
    residual_px : the last Gauss-Newton step's size, pixels (how far from converged)
    """

    def __init__(self, settings: OcclusionSettings):
        self.settings = settings
        self.scale = max(1, int(settings.register_scale))
        self.reference: np.ndarray | None = None
        self.gx: np.ndarray | None = None
        self.gy: np.ndarray | None = None
        self.shift_px = np.zeros(2)
        self.residual_px = 0.0

    def shrink(self, bgr: np.ndarray) -> np.ndarray:
        """(H, W, 3) -> (H // s, W // s, 3) block means at the registration scale ``s``."""
        s = self.scale
        if s == 1:
            return bgr
        h, w = bgr.shape[0] // s, bgr.shape[1] // s
        return cv2.resize(bgr[: h * s, : w * s], (w, h), interpolation=cv2.INTER_AREA)

    def _grey(self, bgr: np.ndarray, shrunk: bool = False) -> np.ndarray:
        """(H, W, 3) BGR (uint8 or float32 codes) -> (h, w) float32, shrunk and blurred.

        ``shrunk``: ``bgr`` is already at the registration scale (:meth:`shrink`)."""
        s = self.scale
        if not shrunk:  # shrink first (block mean), then grey: the same numbers, less work
            bgr = self.shrink(bgr)
        grey = cv2.cvtColor(bgr.astype(np.float32, copy=False), cv2.COLOR_BGR2GRAY)
        sigma = self.settings.register_blur_px / s
        if sigma > 0:
            grey = cv2.GaussianBlur(grey, (0, 0), sigma)
        return grey

    def set_reference(self, mean_bgr: np.ndarray) -> None:
        """Take (H, W, 3) float32 BGR codes (the background mean) as the reference."""
        ref = self._grey(mean_bgr)
        self.reference = ref
        # Central differences, codes per shrunk pixel (Scharr/32 is as exact and smoother).
        self.gx = cv2.Scharr(ref, cv2.CV_32F, 1, 0, scale=1.0 / 32.0)
        self.gy = cv2.Scharr(ref, cv2.CV_32F, 0, 1, scale=1.0 / 32.0)
        b = 2 + int(np.ceil(self.settings.register_max_shift_px / self.scale))
        self._inside = np.zeros(ref.shape, dtype=bool)  # away from the border
        self._inside[b:-b, b:-b] = True
        self._sample = np.flatnonzero(self._inside)[::7]  # the pixels the MAD is taken over

    def estimate(self, frame_bgr: np.ndarray, exclude: np.ndarray | None = None,
                 shrunk: bool = False) -> np.ndarray:
        """``(dx, dy)`` full-resolution pixels of ``frame_bgr`` (H, W, 3) against the reference.

        ``exclude`` (h', w') bool, any resolution: pixels not to use (resized to the
        registration scale). ``shrunk``: ``frame_bgr`` is already at the registration scale
        (:meth:`shrink`; the pipeline shrinks before its daylight table, a quarter of the
        look-ups). Returns the shift, also kept in ``shift_px``.
        """
        s = self.settings
        grey = self._grey(frame_bgr, shrunk)
        use = self._inside.copy()
        if exclude is not None and exclude.any():
            ex = cv2.resize(exclude.view(np.uint8), use.shape[::-1],
                            interpolation=cv2.INTER_NEAREST) > 0
            if np.count_nonzero(use & ~ex) > 0.2 * use.size:
                use &= ~ex
        d = self.shift_px / self.scale  # shrunk pixels
        step = np.zeros(2)
        limit = None
        gx, gy = self.gx.ravel(), self.gy.ravel()
        use_f = use.view(np.uint8).astype(np.float32).ravel()
        for _ in range(s.register_iterations):
            moved = shift_image(grey, d[0], d[1])
            r = cv2.subtract(moved, self.reference)
            abs_r = np.abs(r)
            if limit is None:  # outliers by the residuals at the starting shift
                sample = abs_r.ravel()[self._sample][use.ravel()[self._sample]]
                mad = float(np.median(sample)) if sample.size else 0.0
                limit = 3.0 * 1.4826 * mad + 1e-3
            # Weights 1 on the pixels used, 0 elsewhere: sums by BLAS dot products rather
            # than gathers of the used pixels (the same sums, a third of the time).
            _, w = cv2.threshold(abs_r, limit, 1.0, cv2.THRESH_BINARY_INV)
            w = w.ravel()
            w *= use_f
            gxw, gyw, rr = gx * w, gy * w, r.ravel()
            # The 2x2 normal equations in closed form (numpy's cond and solve cost more in
            # call overhead than the sums themselves).
            axx, axy, ayy = float(gxw @ gx), float(gxw @ gy), float(gyw @ gy)
            half_trace, det = 0.5 * (axx + ayy), axx * ayy - axy * axy
            root = math.sqrt(max(half_trace * half_trace - det, 0.0))
            if not half_trace - root > 1e-6 * (half_trace + root):  # condition number > 1e6
                break
            bx, by = float(gxw @ rr), float(gyw @ rr)
            # moved(x) ~ reference(x - (d_true - d)): r = -grad . (d_true - d)
            step = -np.array([ayy * bx - axy * by, axx * by - axy * bx]) / det
            d = d + step
            if np.hypot(*step) * self.scale < 0.01:
                break
        d_px = d * self.scale
        self.residual_px = float(np.hypot(*step) * self.scale)
        if np.all(np.isfinite(d_px)) and np.hypot(*d_px) <= s.register_max_shift_px:
            self.shift_px = d_px
        return self.shift_px

    @property
    def moved(self) -> bool:
        """Whether the last shift is large enough to resample for (``register_min_shift_px``)."""
        return bool(np.hypot(*self.shift_px) >= self.settings.register_min_shift_px)

    def margin_px(self) -> int:
        """Pixels a resampling by the last shift reaches beyond its output's rectangle."""
        return int(np.ceil(np.abs(self.shift_px).max())) + 2

    def align_rects(self, frame_bgr: np.ndarray, rects: list[tuple[int, int, int, int]],
                    table: np.ndarray | None = None, out: np.ndarray | None = None
                    ) -> np.ndarray:
        """:meth:`align` of ``cv2.LUT(frame_bgr, table)``, computed inside ``rects`` only.

        ``frame_bgr`` (H, W, 3) uint8; ``rects`` ``(y0, y1, x0, x1)`` pixels of the output
        wanted; ``table`` (256, 1, 3) uint8 or None. Returns ``out`` (H, W, 3) uint8 (zeros
        where no rect is, unless ``out`` is given), equal inside the rects to the whole-frame
        computation: each rect's source window reaches :meth:`margin_px` beyond it, or to the
        frame's border, which is repeated as in :func:`shift_image`.
        """
        height, width = frame_bgr.shape[:2]
        if out is None:
            out = np.zeros_like(frame_bgr)
        dx, dy = self.shift_px
        moved = self.moved
        m = self.margin_px() if moved else 0
        for y0, y1, x0, x1 in rects:
            if y1 <= y0 or x1 <= x0:
                continue
            sy0, sy1 = max(0, y0 - m), min(height, y1 + m)
            sx0, sx1 = max(0, x0 - m), min(width, x1 + m)
            src = frame_bgr[sy0:sy1, sx0:sx1]
            if table is not None:
                src = cv2.LUT(src, table)
            if not moved:
                out[y0:y1, x0:x1] = src
                continue
            # out(x, y) = src(x + x0 - sx0 + dx, y + y0 - sy0 + dy) for the rect's pixels
            mat = np.float32([[1, 0, x0 - sx0 + subpixel(dx)], [0, 1, y0 - sy0 + subpixel(dy)]])
            out[y0:y1, x0:x1] = cv2.warpAffine(
                src, mat, (x1 - x0, y1 - y0), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                borderMode=cv2.BORDER_REPLICATE)
        return out

    def align(self, frame_bgr: np.ndarray) -> np.ndarray:
        """The frame resampled into the background's grid by the last shift (a copy when the
        shift is under ``register_min_shift_px``, an interpolation otherwise)."""
        dx, dy = self.shift_px
        if np.hypot(dx, dy) < self.settings.register_min_shift_px:
            return frame_bgr
        return shift_image(frame_bgr, dx, dy)

    def to_frame(self, *masks: np.ndarray) -> list[np.ndarray]:
        """(H, W) uint8 masks (0/255) in the background's grid back to the frame's (moved by
        ``+d``; bilinear, then 255 where above 127), all in one resampling."""
        dx, dy = self.shift_px
        if np.hypot(dx, dy) < self.settings.register_min_shift_px:
            return list(masks)
        stack = cv2.merge(masks) if len(masks) > 1 else masks[0]
        moved = shift_image(stack, -dx, -dy)
        _, moved = cv2.threshold(moved, 127, 255, cv2.THRESH_BINARY)
        return list(cv2.split(moved)) if len(masks) > 1 else [moved]

    def to_frame_in(self, rects: list[tuple[int, int, int, int]], *masks: np.ndarray
                    ) -> list[np.ndarray]:
        """:meth:`to_frame` of masks that are zero outside ``rects`` ``(y0, y1, x0, x1)``: the
        same result, resampled only in each rect grown by :meth:`margin_px`."""
        if not self.moved:
            return list(masks)
        dx, dy = self.shift_px
        height, width = masks[0].shape
        m = self.margin_px()
        out = [np.zeros_like(k) for k in masks]
        for y0, y1, x0, x1 in rects:
            y0, y1 = max(0, y0 - m), min(height, y1 + m)
            x0, x1 = max(0, x0 - m), min(width, x1 + m)
            # The source window reaches m further, or to the frame's border, repeated there
            # exactly as in shift_image: out(x, y) = stack(x - dx, y - dy).
            sy0, sy1 = max(0, y0 - m), min(height, y1 + m)
            sx0, sx1 = max(0, x0 - m), min(width, x1 + m)
            crops = [k[sy0:sy1, sx0:sx1] for k in masks]
            stack = cv2.merge(crops) if len(masks) > 1 else crops[0]
            mat = np.float32([[1, 0, x0 - sx0 + subpixel(-dx)],
                              [0, 1, y0 - sy0 + subpixel(-dy)]])
            part = cv2.warpAffine(stack, mat, (x1 - x0, y1 - y0),
                                  flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                  borderMode=cv2.BORDER_REPLICATE)
            _, part = cv2.threshold(part, 127, 255, cv2.THRESH_BINARY)
            parts = cv2.split(part) if len(masks) > 1 else [part]
            for o, p in zip(out, parts, strict=True):
                np.maximum(o[y0:y1, x0:x1], p, out=o[y0:y1, x0:x1])
        return out
