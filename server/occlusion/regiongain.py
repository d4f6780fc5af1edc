"""A daylight gain of their own for the large smooth regions above the horizon: the sky.

The daylight gain (background.py) is one per channel for the whole frame, the median over
the site, so it follows the ground. The sky is not lit by the sun but is a light source of
its own: when a thin cloud veils the sun, the direct light on the ground falls while the sky
brightens (the cloud scatters the beam), so against the ground the sky grows brighter by a
factor of 1.9 and more (the synthetic hazy-to-thin-cloud change), and became person regions
of 13 000 px at 480x270 within 3 s.

At learning, the coarse background (detection scale) is split into *regions*: 4-connected
areas where neighbouring coarse pixels differ by at most ``region_gain_step_codes`` in every
channel (smooth: the sky, a plain wall), whose rays do not meet the ground plane (above the
horizon: no person's cast shadow falls there, and people cover little of it; a camera that
cannot say gets no region); pieces whose colour ranges overlap are one region (the sky
between buildings), which must hold at least ``region_gain_min_share`` of the frame. The
full-resolution pixels above the horizon whose background colour is in the region's range
and that are connected to it join it (the skyline's coarse pixels are not smooth, and a
strip of sky over a roof is narrower than one). Each frame, after the global gain,
each region gets a residual gain per channel: the median ratio, in linear light, of the
frame to the background over the region's coarse pixels, accepted when at least half of
them agree with it within 10 % (a person in front of a region does not set its gain; the
last accepted gain is kept then). Where the frame clipped a channel (the sky at code 255)
the ratio is only known from below: the median counts those pixels as above every other
(censored data), and a clipped pixel whose background, brightened by the region's gain
(within 10 %), would be clipped too is given its background's code (explained, not
measured). A channel clipped over more than half of the region keeps its last gain, and
all its clipped pixels are explained.

The region's pixels are mapped into the reference illumination by one look-up table of the
global and the region's gain together (``Transfer.gain_table``; the global table alone
clips a bright sky that it dims by less than the sky brightens), from the frame's own codes
(its grid: a smooth region's codes do not change with a shift of a pixel), only where the
pipeline reads them: the coarse copy and the regions of interest and update band
(``apply``). The mixed pixels along the skyline (part roof, part sky) are in no region and
keep the global gain; the registration's edge variance (gradient x
``register_tolerance_px``) covers them.
"""

from __future__ import annotations

import cv2
import numpy as np

from server.occlusion.colour import Transfer

_CLIP_CODE = 250  # frame codes at or above this are taken as clipped
_AGREE_LOG = np.log(1.1)  # a pixel agrees with the region's gain within 10 %
_UNIT_LOG = 0.02  # residual gains within 2 % of 1 are not applied
_SAMPLES = 600  # coarse pixels per region the median is taken over, at most


class RegionGain:
    """Residual daylight gains of the large smooth regions above the horizon.

    Attributes
    ----------
    coarse_labels : (h, w) int32, region of each coarse pixel, 0 = none (global gain only)
    labels : (H, W) uint8, the same at full resolution (each coarse pixel's block)
    gains : (n, 3) float32, each region's residual gain (BGR, linear, over the global gain)
    clip_mode : (n, 3) bool, channels the frame has clipped over most of the region (their
        gain is only known from below)
    """

    def __init__(self, transfer: Transfer, scale: int, min_share: float, step_codes: float):
        self.transfer = transfer
        self.scale = int(scale)
        self.min_share = float(min_share)
        self.step_codes = float(step_codes)
        self.coarse_labels: np.ndarray | None = None
        self.labels: np.ndarray | None = None
        self.gains = np.ones((0, 3), dtype=np.float32)
        self.clip_mode = np.zeros((0, 3), dtype=bool)  # channels known only from below
        self._samples: list[np.ndarray] = []  # flat coarse indices of each region
        self._applied: list[bool] = []  # per region: its gain differs from 1 (is applied)
        self._boxes: dict = {}  # bounding boxes of the regions in each label map

    @property
    def count(self) -> int:
        return len(self._samples)

    def learn(self, coarse_mean: np.ndarray, above: np.ndarray | None,
              mean_u8: np.ndarray, above_full: np.ndarray | None = None) -> int:
        """Find the regions in the coarse background mean (h, w, 3) float32 codes; ``above``
        (h, w) bool, the coarse pixels whose rays miss the ground (None: the camera cannot
        say, and no region is found); ``mean_u8`` (H, W, 3) uint8, the full-resolution
        background (the regions' rims), ``above_full`` (H, W) bool its pixels above the
        horizon (None: ``above``'s blocks).
        Returns how many regions there are."""
        h, w = coarse_mean.shape[:2]
        self.gains = np.ones((0, 3), dtype=np.float32)
        self._samples, self._applied, self._boxes = [], [], {}
        self.coarse_labels = np.zeros((h, w), dtype=np.int32)
        self.labels = np.zeros(mean_u8.shape[:2], dtype=np.uint8)
        if self.min_share <= 0 or h < 2 or w < 2:
            return 0
        # Smooth: within step_codes of each 4-neighbour in every channel.
        smooth = np.ones((h, w), dtype=bool)
        dx = np.abs(np.diff(coarse_mean, axis=1)).max(axis=2) <= self.step_codes
        dy = np.abs(np.diff(coarse_mean, axis=0)).max(axis=2) <= self.step_codes
        smooth[:, :-1] &= dx
        smooth[:, 1:] &= dx
        smooth[:-1] &= dy
        smooth[1:] &= dy
        if above is None:  # a camera that cannot tell the sky from the ground: no regions
            return 0
        smooth &= above
        count, comp, stats, _ = cv2.connectedComponentsWithStats(
            smooth.view(np.uint8), connectivity=4)
        # Pieces of one surface (the sky between buildings) are one region: pieces whose
        # colour ranges overlap (widened by 2 steps) join, largest first.
        groups: list[list] = []  # [pieces' label list, low (3,), high (3,)]
        flat_mean = coarse_mean.reshape(-1, 3)
        for k in np.argsort(-stats[1:, cv2.CC_STAT_AREA]) + 1:
            if stats[k, cv2.CC_STAT_AREA] < 4:
                break
            colours = flat_mean[(comp == k).ravel()]
            low, high = colours.min(axis=0), colours.max(axis=0)
            for g in groups:
                if np.all(low <= g[2] + 2 * self.step_codes) and np.all(
                        high >= g[1] - 2 * self.step_codes):
                    g[0].append(k)
                    g[1], g[2] = np.minimum(g[1], low), np.maximum(g[2], high)
                    break
            else:
                groups.append([[k], low, high])
        rng = np.random.default_rng(0)
        s = self.scale
        boxes = []
        for pieces, low, high in groups:
            member = np.isin(comp, pieces)
            if np.count_nonzero(member) < self.min_share * h * w or self.count >= 255:
                continue
            flat = np.flatnonzero(member)
            if len(flat) > _SAMPLES:
                flat = np.sort(rng.choice(flat, _SAMPLES, replace=False))
            self._samples.append(flat)
            self._applied.append(False)
            self.coarse_labels[member] = self.count
            boxes.append((low - self.step_codes, high + self.step_codes))
        self.gains = np.ones((self.count, 3), dtype=np.float32)
        self.clip_mode = np.zeros((self.count, 3), dtype=bool)
        full = np.repeat(np.repeat(self.coarse_labels.astype(np.uint8), s, 0), s, 1)
        self.labels[: h * s, : w * s] = full
        # The rims and slivers the coarse pixels miss (the skyline's coarse pixels are not
        # smooth; a strip of sky above a roof is narrower than one): the full-resolution
        # pixels above the horizon whose background colour is in the region's range,
        # connected to the region through such pixels.
        if above_full is None:
            above_full = np.repeat(np.repeat(above, s, 0), s, 1)
            above_full = np.pad(above_full, ((0, self.labels.shape[0] - above_full.shape[0]),
                                             (0, self.labels.shape[1] - above_full.shape[1])))
        for k, (low, high) in enumerate(boxes, start=1):
            inside = np.all((mean_u8 >= low) & (mean_u8 <= high), axis=2) & above_full
            inside |= self.labels == k
            n, comp = cv2.connectedComponents(inside.view(np.uint8), connectivity=8)
            touching = np.unique(comp[self.labels == k])
            grown = np.isin(comp, touching[touching > 0]) & (self.labels == 0)
            self.labels[grown] = k
        return self.count

    def estimate(self, coarse_frame: np.ndarray, coarse_corrected: np.ndarray,
                 coarse_linear: np.ndarray, coarse_mean: np.ndarray,
                 global_gain: np.ndarray) -> None:
        """Each region's residual gain from this frame.

        ``coarse_frame`` (h, w, 3) uint8, the frame's coarse copy as it came (for clipping);
        ``coarse_corrected`` the same in the reference illumination (global gain) and the
        background's grid; ``coarse_linear``, ``coarse_mean`` (h, w, 3) float32, the
        background's (linear light, codes); ``global_gain`` (3,) linear.
        """
        tr = self.transfer
        clip_linear = tr.decode_bgr[_CLIP_CODE] / np.asarray(global_gain, dtype=np.float32)
        for k, flat in enumerate(self._samples):
            raw = coarse_frame.reshape(-1, 3).take(flat, axis=0)
            at = tr.channel_index(coarse_corrected.reshape(-1, 3).take(flat, axis=0))
            lin = tr.decode_flat.take(at)
            lin_bg = coarse_linear.reshape(-1, 3).take(flat, axis=0)
            bg_codes = coarse_mean.reshape(-1, 3).take(flat, axis=0)
            # Per channel (columns): pixels whose background is measured; where the frame
            # clipped, the ratio is only known to be above the clip's (censored, +inf here):
            # the median stands as long as fewer than half are. NaN: not measured.
            valid = (bg_codes < _CLIP_CODE) & (lin_bg > 0.01) & (raw > 8)
            clipped = raw >= _CLIP_CODE
            with np.errstate(divide="ignore", invalid="ignore"):
                ratio = np.where(valid, np.where(clipped, np.inf, lin / lin_bg), np.nan)
                bound = clip_linear / lin_bg
            count = np.count_nonzero(valid, axis=0)
            ordered = np.sort(ratio, axis=0)  # NaN last, +inf before it
            cols = np.arange(3)
            median = np.where(count % 2 == 1, ordered[np.maximum(count - 1, 0) // 2, cols],
                              0.5 * (ordered[np.maximum(count // 2 - 1, 0), cols]
                                     + ordered[count // 2, cols]))
            with np.errstate(divide="ignore", invalid="ignore"):
                near = np.abs(np.log(ratio / median)) < _AGREE_LOG
            near |= valid & clipped & (bound <= median * np.exp(_AGREE_LOG))  # consistent
            measured = np.isfinite(median) & (count >= 0.3 * len(flat))
            agreed = bool(np.all(np.count_nonzero(near, axis=0)[measured]
                                 >= 0.5 * count[measured]))
            # Background clipped over most of the region: nothing to follow (gain 1);
            # frame clipped over most of it: NaN, only known from below.
            gain = np.where(count < 0.3 * len(flat), 1.0, np.where(measured, median, np.nan))
            if not agreed or np.all(np.isnan(gain)):
                continue  # a person in front, or nothing measured: keep the last gain
            # A channel clipped over most of the region keeps its last measured gain for
            # its pixels not clipped (the sky's channels brighten unequally: a cloud
            # whitens it, so another channel's gain is no guess; nor is the clip's bound,
            # which the pixels near the clip, in and out of it with the noise, do not
            # follow); its clipped pixels are explained by any gain.
            mode = np.isnan(gain)
            gain = np.where(mode, self.gains[k], gain)
            self.gains[k] = gain
            self.clip_mode[k] = mode
            unit = np.all(np.abs(np.log(gain)) < _UNIT_LOG)
            self._applied[k] = not unit

    def apply(self, corrected: np.ndarray, frame: np.ndarray, rects, mean_u8: np.ndarray,
              linear: np.ndarray, global_gain: np.ndarray, labels: np.ndarray | None = None
              ) -> None:
        """Apply the residual gains in place inside ``rects`` ((y0, y1, x0, x1) of
        ``corrected``).

        ``corrected`` (H, W, 3) uint8, the frame in the reference illumination (global gain)
        and the background's grid; ``frame`` the frame as it came (the codes corrected
        here, and which are clipped);
        ``mean_u8``, ``linear`` the background's codes and linear light; ``labels`` the
        region map of this resolution (default: the full-resolution one).
        """
        if not any(self._applied):
            return
        labels = self.labels if labels is None else labels
        clip_linear = (self.transfer.decode_bgr[_CLIP_CODE]
                       / np.asarray(global_gain, dtype=np.float32))
        for k, applied in enumerate(self._applied):
            if not applied:
                continue
            # The region's pixels inside the union of the rects (which may overlap: each
            # pixel is corrected once), searched in the region's bounding box only.
            by0, by1, bx0, bx1 = self._bbox(labels, k + 1)
            inside = np.zeros((by1 - by0, bx1 - bx0), dtype=bool)
            for y0, y1, x0, x1 in rects:
                inside[max(y0, by0) - by0:max(min(y1, by1) - by0, 0),
                       max(x0, bx0) - bx0:max(min(x1, bx1) - bx0, 0)] = True
            ys, xs = np.nonzero(inside & (labels[by0:by1, bx0:bx1] == k + 1))
            if len(ys) == 0:
                continue
            ys += by0
            xs += bx0
            # From the frame's own codes, by the global and the region's gain together (the
            # global table alone clips a bright sky it dims by less than the sky brightens).
            table = self.transfer.gain_table(np.asarray(global_gain) * self.gains[k])
            codes = cv2.LUT(frame[ys, xs].reshape(-1, 1, 3), table).reshape(-1, 3)
            # Clipped in the frame, and clipped too if the background brightened by the
            # region's gain: explained, the background's own code.
            explained = (frame[ys, xs] >= _CLIP_CODE) & (
                self.clip_mode[k] | (linear[ys, xs] * self.gains[k] * np.exp(_AGREE_LOG)
                                     >= clip_linear))
            corrected[ys, xs] = np.where(explained, mean_u8[ys, xs], codes)

    def _bbox(self, labels: np.ndarray, label: int) -> tuple[int, int, int, int]:
        """(y0, y1, x0, x1) of ``label`` in ``labels`` (cached per map and label)."""
        key = (labels.shape, label)
        box = self._boxes.get(key)
        if box is None:
            x, y, w, h = cv2.boundingRect((labels == label).view(np.uint8))
            box = self._boxes[key] = (y, y + h, x, x + w)
        return box
