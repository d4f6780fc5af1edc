"""The empty site as the camera sees it: a per-pixel Gaussian, a global colour mixture, and a
global daylight gain (Kakuta Sec. 3.1.1, background side).

The model is kept in a fixed *reference illumination*, that of the frames it was learned from.
Each new frame is first mapped into it by a per-channel gain on linear light (a diagonal,
von Kries change of illuminant), estimated as the median ratio of frame to background over
pixels labelled background in the previous frame. Daylight that brightens, dims or turns warmer
is thus followed at once and for the whole frame, while the per-pixel statistics change only
slowly (``bg_rate``) and only where the final label is background, so a person who stands still
is never learned into the background. The slow update visits one horizontal band per frame
(``bg_update_bands``), spreading its cost.

Arrays (H, W full resolution; h, w = H // s, W // s at the detection scale s):

- ``mean`` (H, W, 3) float32, BGR codes (0-255) in the reference illumination;
- ``var`` (H, W, 3) float32, codes^2; ``edge_var`` (H, W, 3) float32 codes^2, the variance a
  residual camera shake of ``register_tolerance_px`` gives at the mean's edges (None when not
  registering); ``total_var`` (H, W, 3) float32 their sum, ``inv_var`` its reciprocal;
  ``log_norm`` (H, W) float32, ``0.5 sum_c ln(2 pi total_var_c)``;
- ``mean_u8`` (H, W, 3) uint8, the mean rounded to codes; ``linear`` (H, W, 3) float32 its
  linear light (for the shadow test; rounding changes it by under 1 % above code 50);
  ``log_green`` (H, W) float32, ln of its green channel's linear light (the codec's local
  spread, segment.Segmenter._dark_spread);
- ``coarse_mean``, ``coarse_linear`` (h, w, 3) float32, block means of the above.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable

import cv2
import numpy as np

from server.occlusion.colour import Transfer
from server.occlusion.mixture import ColourMixture
from server.occlusion.settings import OcclusionSettings

log = logging.getLogger("daylit.occlusion")

_SUM3 = np.ones((1, 3), dtype=np.float32)  # cv2.transform: sum of the three channels


def shrink(image: np.ndarray, scale: int) -> np.ndarray:
    """Block mean by an integer ``scale`` (the remainder rows/columns are dropped)."""
    if scale == 1:
        return image
    h, w = image.shape[0] // scale, image.shape[1] // scale
    return cv2.resize(image[: h * scale, : w * scale], (w, h), interpolation=cv2.INTER_AREA)


_WORD = {2: np.uint16, 4: np.uint32, 8: np.uint64}  # a block's row of bytes as one word


def block_any(mask: np.ndarray, scale: int) -> np.ndarray:
    """(H, W) bool or uint8 -> (H // scale, W // scale) bool, True where any pixel of the
    block is non-zero (the remainder rows/columns are dropped, as :func:`shrink`'s).

    For a scale of 2, 4 or 8 each block row is read as one machine word: nine times as fast
    as ``shrink(mask) > 0`` (OpenCV's area resampling of a 1024x512 mask took 0.5 ms).
    """
    h, w = mask.shape[0] // scale, mask.shape[1] // scale
    m = np.ascontiguousarray(mask[: h * scale, : w * scale]).view(np.uint8)
    word = _WORD.get(scale)
    if word is None:  # block means in float: a single pixel of 1 in the block stays > 0
        return shrink(m.astype(np.float32), scale) > 0
    rows = m.view(word).reshape(h, scale, w)  # (h, scale, w): one word per block row
    out = rows[:, 0] != 0
    for k in range(1, scale):
        out |= rows[:, k] != 0
    return out


def blockiness(frames_bgr: np.ndarray, block_px: int = 8) -> float:
    """How block-coded the frames are: (N, H, W, 3) uint8 -> ratio >= 0.

    The mean absolute step between horizontal neighbours across the boundaries of
    ``block_px`` columns, over the mean step at the other column phases (a block-boundary
    measure in the manner of Wang, Sheikh and Bovik 2002). About 1 for frames never
    block-coded (0.92-1.0 measured on the project's sequences); JPEG 75 and MPEG-4 part 2 give
    1.2-1.4, JPEG 90 1.14 (docs/occlusion.md).
    """
    steps = np.zeros(block_px)
    for frame in frames_bgr:
        grey = cv2.cvtColor(np.asarray(frame), cv2.COLOR_BGR2GRAY).astype(np.float32)
        d = np.abs(np.diff(grey, axis=1)).mean(axis=0)  # (W - 1,): step from x to x + 1
        n = len(d) // block_px * block_px
        steps += d[:n].reshape(-1, block_px).mean(axis=0)
    inside = np.delete(steps, block_px - 1).mean()
    return float(steps[block_px - 1] / inside) if inside > 0 else 1.0


class BackgroundModel:
    """Per-pixel and global background statistics of one fixed camera; see the module notes."""

    def __init__(self, width: int, height: int, settings: OcclusionSettings, transfer: Transfer):
        self.width, self.height = int(width), int(height)
        self.settings = settings
        self.transfer = transfer
        self.scale = settings.detect_scale
        self.mean: np.ndarray | None = None
        self.edge_var: np.ndarray | None = None
        self.blockiness = 1.0  # of the learned frames (blockiness()): codec-coded above ~1.1
        self.var: np.ndarray | None = None
        self.inv_var: np.ndarray | None = None
        self.total_var: np.ndarray | None = None
        self.log_norm: np.ndarray | None = None
        self.linear: np.ndarray | None = None
        self.log_green: np.ndarray | None = None
        self.coarse_mean: np.ndarray | None = None
        self.coarse_linear: np.ndarray | None = None
        self.global_mixture = ColourMixture(settings.bg_global_components, max_iter=30)
        self.global_table: np.ndarray | None = None  # (bins,) float32 log-density
        self.mean_u8: np.ndarray | None = None
        self.gain_bgr = np.ones(3, dtype=np.float32)
        # Mean squared colour difference of 4-neighbours in the empty site: the contrast scale
        # of the spatial prior (GrabCut's <|I_m - I_n|^2>), fixed at learning time.
        self.mean_contrast = 100.0
        self._band = 0
        # Rows per band, a multiple of the detection scale so the coarse copy updates exactly.
        bands = settings.bg_update_bands
        step = -(-self.height // (bands * self.scale)) * self.scale
        self._bands = [(y, min(y + step, self.height)) for y in range(0, self.height, step)]

    @property
    def ready(self) -> bool:
        return self.mean is not None

    # ------------------------------------------------------------------------------ learning

    def learn(self, frames: Iterable[np.ndarray]) -> int:
        """Learn from frames of the empty site, (H, W, 3) uint8 BGR each; returns how many.

        The mean is the per-pixel median (robust to someone crossing during learning), the
        variance ``(1.4826 MAD)^2`` floored at ``bg_sigma_floor^2``.
        """
        stack = np.stack([np.asarray(f) for f in frames])
        if stack.ndim != 4 or stack.shape[1:] != (self.height, self.width, 3):
            raise ValueError(f"background frames must be {self.height}x{self.width}x3")
        n = len(stack)
        mean = np.median(stack, axis=0).astype(np.float32)
        floor = self.settings.bg_sigma_floor**2
        if n >= 3:
            mad = np.median(np.abs(stack.astype(np.float32) - mean[None]), axis=0)
            var = (1.4826 * mad) ** 2
            # A few frames' MAD is a rough estimate per pixel (+-40 % in sigma for 10 frames):
            # no pixel is taken to be quieter than the camera's typical noise per channel.
            typical = np.median(var.reshape(-1, 3), axis=0)
            var = np.maximum(var, np.maximum(typical, floor)[None, None, :]).astype(np.float32)
        else:
            var = np.full_like(mean, floor)
        self.mean, self.var = mean, var
        self.blockiness = blockiness(stack)
        # A residual registration error of register_tolerance_px moves each edge by that much:
        # its variance (per-channel gradient x tolerance)^2 is added where the pixel is
        # compared (inv_var), not learned into var.
        self.edge_var = None
        tol = self.settings.register_tolerance_px if self.settings.register else 0.0
        if tol > 0:
            gx = cv2.Scharr(mean, cv2.CV_32F, 1, 0, scale=1.0 / 32.0)
            gy = cv2.Scharr(mean, cv2.CV_32F, 0, 1, scale=1.0 / 32.0)
            self.edge_var = ((gx * gx + gy * gy) * np.float32(tol * tol)).astype(np.float32)
        self.gain_bgr = np.ones(3, dtype=np.float32)
        self._derive(0, self.height)
        dx, dy = np.diff(mean, axis=1), np.diff(mean, axis=0)
        self.mean_contrast = max(1.0, float(((dx * dx).sum() + (dy * dy).sum())
                                            / (dx[..., 0].size + dy[..., 0].size)))
        if self.settings.bg_global_weight > 0.0:
            self.refit_global()
        return n

    def refit_global(self, samples: int = 6000) -> None:
        """Refit the global colour mixture (paper: K = 15) to the current mean image."""
        rng = np.random.default_rng(0)
        flat = self.mean.reshape(-1, 3)
        pick = rng.choice(len(flat), size=min(samples, len(flat)), replace=False)
        fitted = self.global_mixture.fit(flat[pick], warm=False)
        if fitted or self.global_table is None:  # unfitted: a uniform table
            self.global_table = self.global_mixture.table(self.settings.lut_bits)

    def _derive(self, y0: int, y1: int) -> None:
        """Recompute the derived arrays for rows ``y0:y1`` (multiples of the scale)."""
        if self.inv_var is None:
            self.inv_var = np.empty_like(self.var)
            self.total_var = np.empty_like(self.var)
            self.log_norm = np.empty(self.var.shape[:2], dtype=np.float32)
            self.mean_u8 = np.empty(self.mean.shape, dtype=np.uint8)
            self.linear = np.empty_like(self.mean)
            self.log_green = np.empty(self.var.shape[:2], dtype=np.float32)
            h, w = self.height // self.scale, self.width // self.scale
            self.coarse_mean = np.empty((h, w, 3), dtype=np.float32)
            self.coarse_linear = np.empty((h, w, 3), dtype=np.float32)
        var = self.total_var[y0:y1]
        if self.edge_var is not None:
            np.add(self.var[y0:y1], self.edge_var[y0:y1], out=var)
        else:
            var[:] = self.var[y0:y1]
        np.divide(1.0, var, out=self.inv_var[y0:y1])
        prod = var[..., 0] * var[..., 1] * var[..., 2]
        self.log_norm[y0:y1] = 0.5 * np.log((2.0 * np.pi) ** 3 * prod)
        self.mean_u8[y0:y1] = cv2.convertScaleAbs(self.mean[y0:y1])  # round, saturate
        self.linear[y0:y1] = self.transfer.image_to_linear(self.mean_u8[y0:y1])
        self.log_green[y0:y1] = cv2.LUT(cv2.extractChannel(self.mean_u8[y0:y1], 1),
                                        self.transfer.log_table[:, :, 1].copy())
        s = self.scale
        c0, c1 = y0 // s, min(y1 // s, self.coarse_mean.shape[0])
        if c1 > c0:
            self.coarse_mean[c0:c1] = shrink(self.mean[c0 * s : c1 * s], s)
            self.coarse_linear[c0:c1] = shrink(self.linear[c0 * s : c1 * s], s)

    # ------------------------------------------------------------------------------ daylight

    def estimate_gain(self, coarse_bgr: np.ndarray, exclude: np.ndarray | None) -> np.ndarray:
        """Per-channel daylight gain (linear light, frame over background), (3,) float32.

        ``coarse_bgr`` (h, w, 3) uint8 is the frame at the detection scale; ``exclude`` (h, w)
        bool marks pixels not to use (people and shadows of the previous frame). Pixels too
        dark or clipped are left out; with fewer than 50 usable pixels the last gain is kept.
        """
        step = self.settings.gain_sample_step_px
        frame = coarse_bgr[::step, ::step].reshape(-1, 3)
        bg = self.coarse_linear[::step, ::step].reshape(-1, 3)
        ok = np.ones(len(frame), dtype=bool)
        for c in range(3):  # neither dark (noise) nor clipped
            ok &= (frame[:, c] > 8) & (frame[:, c] < 250) & (bg[:, c] > 0.01)
        if exclude is not None and np.count_nonzero(ok & ~exclude[::step, ::step].ravel()) >= 50:
            ok &= ~exclude[::step, ::step].ravel()  # else the median copes with the outliers
        if np.count_nonzero(ok) < 50:
            return self.gain_bgr
        ratio = self.transfer.to_linear(frame[ok]) / bg[ok]
        gain = np.median(ratio, axis=0).astype(np.float32)
        if np.all(np.isfinite(gain)) and np.all(gain > 0.05):
            self.gain_bgr = gain
        return self.gain_bgr

    # ------------------------------------------------------------------------------ updating

    def next_band(self) -> tuple[int, int]:
        """Rows ``(y0, y1)`` the next :meth:`update` will visit."""
        return self._bands[self._band]

    def update(self, corrected_bgr: np.ndarray, background: np.ndarray) -> tuple[int, int]:
        """Slowly blend the next band of rows toward the frame where ``background`` is True.

        ``corrected_bgr`` (H, W, 3) uint8 is the frame in the reference illumination;
        ``background`` (H, W) bool the pixels whose final label is background (no person, no
        shadow, not next to a person). Returns the band's rows ``(y0, y1)``.
        """
        y0, y1 = self._bands[self._band]
        self._band = (self._band + 1) % len(self._bands)
        rate = self.settings.bg_rate * len(self._bands)
        frame = corrected_bgr[y0:y1]
        mean, var = self.mean[y0:y1], self.var[y0:y1]
        diff = cv2.subtract(frame, mean, dtype=cv2.CV_32F)
        sq = cv2.multiply(diff, diff)
        # Only pixels the background still explains (within bg_update_gate sigma): a person the
        # cut missed is not learned, and cannot teach the cut to miss them again.
        d2 = cv2.transform(cv2.multiply(sq, self.inv_var[y0:y1]), _SUM3)
        near = d2 < 3.0 * self.settings.bg_update_gate**2
        mask = (background[y0:y1] & near).view(np.uint8)
        cv2.accumulateWeighted(sq, var, rate, mask=mask)  # before the mean moves
        cv2.accumulateWeighted(frame.astype(np.float32), mean, rate, mask=mask)
        np.maximum(var, self.settings.bg_sigma_floor**2, out=var)
        self._derive(y0, y1)
        return y0, y1
