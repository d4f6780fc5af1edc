"""People versus everything else, by a graph cut of Kakuta's energy (Eq. 6-7).

For the labels ``X^t`` of frame ``I^t`` (1: person, 0: background or shadow)::

    E^t = alpha V^T(X^t, X^{t-1}, X^{t-2}) + beta V^S(X^t, I^t) + U^C(X^t, I^t)     (Eq. 6)

- ``U^C``, colour: ``-ln p(I_n | person)`` from a Gaussian mixture of people's colours (paper:
  K = 5) mixed with a uniform density, refitted every few frames to the pixels labelled person;
  ``-ln p(I_n | background)`` from the mixture ``lambda p_global(I_n) + (1 - lambda)
  N(I_n; mu_n, Sigma_n)`` of a global background mixture (K = 15) and the pixel's own Gaussian
  (the combined model of Sun et al., which the paper follows; ``lambda = bg_global_weight``,
  0 by default: for a fixed camera the global term mostly hides people dressed in colours found
  elsewhere on the site, see docs/occlusion.md). Mixture densities are table look-ups on
  5-bit-per-channel colour.
- Shadow (shadow.py): a pixel that looks like its background in shadow (the F-value test and
  the frame's shadow signature) costs ``shadow_cost`` plus a penalty that grows with its
  distance from a perfect shadow as background, so cast shadows join the background inside the
  same cut, where the spatial prior smooths the per-pixel test, instead of being carved out of
  the person mask afterwards.
- ``V^T``, temporal: ``-ln P(x_n^t | x_n^{t-1}, x_n^{t-2})``, a second-order Markov chain per
  pixel with four probabilities (settings ``temporal_prior``).
- ``V^S``, spatial: for each 4-neighbour pair with different labels,
  ``exp(-|I_m - I_n|^2 / (2 <|I_m - I_n|^2>))`` (contrast-sensitive, Boykov-Jolly / GrabCut).

Eq. 7 takes the previous labels as fixed, so the energy is submodular in ``X^t`` and one s-t
min cut (PyMaxflow, Boykov-Kolmogorov) gives the exact minimum (graphcut.py: over the nodes
their own costs leave undecided). The cut runs at full
resolution, but only inside regions of interest: boxes around the coarse background difference
and last frame's people, and inside those only for the pixels within ``band_px`` of a pixel
that may be a person (its unary term, shadow and temporal prior included, or last frame's
label). Everything else is background; the
frame-wide cut gives the same labels there (those pixels match their background Gaussian by
many nats) at many times the cost (benchmarks/bench_occlusion.py measures both).
"""

from __future__ import annotations

import math
import time

import cv2
import numpy as np

from server.occlusion.background import BackgroundModel
from server.occlusion.colour import Transfer, colour_index, table_costs
from server.occlusion.graphcut import graph_cut
from server.occlusion.mixture import ColourMixture
from server.occlusion.settings import OcclusionSettings, log_prior_table
from server.occlusion.shadow import (
    ShadowFeatures,
    ShadowSignature,
    luminance,
    shadow_features,
)
from server.occlusion.shadowpieces import give_back_pieces

Box = tuple[int, int, int, int]  # y0, y1, x0, x1 (end exclusive), full resolution


def regions_of_interest(
    candidates: np.ndarray,
    scale: int,
    pad_px: int,
    min_px: int,
    shape: tuple[int, int],
) -> list[Box]:
    """Boxes around candidate regions: (h, w) bool at detection scale -> full-resolution boxes.

    Regions smaller than ``min_px`` full-resolution pixels are dropped; boxes are padded by
    ``pad_px`` and overlapping boxes merged, so they are disjoint.
    """
    height, width = shape
    mask = candidates.astype(np.uint8)
    count, _, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    boxes = []
    for label in range(1, count):
        x, y, w, h, area = (int(v) for v in stats[label])
        if area * scale * scale < min_px:
            continue
        boxes.append([
            max(0, y * scale - pad_px), min(height, (y + h) * scale + pad_px),
            max(0, x * scale - pad_px), min(width, (x + w) * scale + pad_px),
        ])
    merged = True
    while merged and len(boxes) > 1:
        merged = False
        for i in range(len(boxes)):
            for j in range(i + 1, len(boxes)):
                a, b = boxes[i], boxes[j]
                if a[0] < b[1] and b[0] < a[1] and a[2] < b[3] and b[2] < a[3]:
                    boxes[i] = [min(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), max(a[3], b[3])]
                    del boxes[j]
                    merged = True
                    break
            if merged:
                break
    return [tuple(b) for b in boxes]


_SUM3 = np.ones((1, 3), dtype=np.float32)  # cv2.transform: sum of the three channels


def squared_distance(a: np.ndarray, b: np.ndarray, inv_var: np.ndarray | None = None) -> np.ndarray:
    """``sum_c (a_c - b_c)^2 [/ var_c]`` of two (h, w, 3) images -> (h, w) float32 (OpenCV)."""
    d = cv2.subtract(a, b, dtype=cv2.CV_32F)
    sq = cv2.multiply(d, d)
    if inv_var is not None:
        sq = cv2.multiply(sq, inv_var)
    return cv2.transform(sq, _SUM3)


def contrast_weights(
    codes: np.ndarray, weight: float, mean_contrast: float
) -> tuple[np.ndarray, np.ndarray]:
    """``V^S`` edge costs of an (h, w, 3) colour patch: (w_right, w_down), (h, w) float32 each.

    ``weight * exp(-|I_m - I_n|^2 / (2 mean_contrast))`` for the edge from each pixel to its
    right / lower neighbour (0 in the last column / row).
    """
    h, w = codes.shape[:2]
    k = -1.0 / (2.0 * mean_contrast)
    w_right = np.zeros((h, w), dtype=np.float32)
    w_down = np.zeros((h, w), dtype=np.float32)
    if w > 1:
        e = squared_distance(codes[:, 1:], codes[:, :-1]).reshape(h, w - 1)
        w_right[:, :-1] = cv2.exp(e * np.float32(k)).reshape(h, w - 1) * np.float32(weight)
    if h > 1:
        e = squared_distance(codes[1:], codes[:-1]).reshape(h - 1, w)
        w_down[:-1] = cv2.exp(e * np.float32(k)).reshape(h - 1, w) * np.float32(weight)
    return w_right, w_down


class Segmenter:
    """The labelling of one camera's frames, with its memory (previous labels, person colours).

    Attributes
    ----------
    history : (H, W) uint8, ``2 x^{t-1} + x^{t-2}`` per pixel (index into the temporal prior)
    person_mixture : the people's colour mixture; ``person_table`` its log-density table
    """

    def __init__(self, settings: OcclusionSettings, background: BackgroundModel,
                 transfer: Transfer):
        self.settings = settings
        self.background = background
        self.transfer = transfer
        h, w = background.height, background.width
        self.history = np.zeros((h, w), dtype=np.uint8)
        cost_fg, cost_bg = log_prior_table(settings.temporal_prior)
        # As cv2.LUT tables over the history index (0-3): a quarter of numpy's fancy index.
        self.temporal_fg = np.zeros((256, 1), dtype=np.float32)
        self.temporal_bg = np.zeros((256, 1), dtype=np.float32)
        self.temporal_fg[:4, 0] = settings.temporal_weight * np.asarray(cost_fg)
        self.temporal_bg[:4, 0] = settings.temporal_weight * np.asarray(cost_bg)
        self.person_mixture = ColourMixture(settings.fg_components, max_iter=5)
        self.person_table = self.person_mixture.table(settings.lut_bits)
        self._frames_since_refit = 0
        self._table_pending = False
        lam = settings.bg_global_weight
        self._log_global_w = math.log(lam) if lam > 0 else None
        self._log_pixel_w = math.log1p(-lam)
        self.signature = ShadowSignature(settings)
        # ln(linear green) of each code, for the codec's local spread (_dark_spread)
        self._log_green = np.ascontiguousarray(transfer.log_table[:, 0, 1]).reshape(256, 1)
        self.timings_ms: dict[str, float] = {}
        # The compiled code is loaded (or compiled, the first time after a change of
        # graphcut.py or colour.py) now, not in a frame, for the types and memory layouts
        # the frames bring (each has its own compiled code): cut() passes the costs and the
        # free mask as views of one part of the box, strided or (a part as wide as the box)
        # contiguous, the edge weights contiguous; colour_terms() a box of the frame or the
        # whole frame.
        weights = np.ones((2, 2), dtype=np.float32)
        for box_width in (3, 2):  # a part narrower than its box (strided), or as wide
            costs = np.ones((3, box_width), dtype=np.float32)[:2, :2]
            free = np.ones((3, box_width), dtype=bool)[:2, :2]
            graph_cut(costs, costs, weights, weights, free)
        for codes in (np.zeros((3, 3, 3), dtype=np.uint8)[:2, :2],
                      np.zeros((2, 2, 3), dtype=np.uint8)):
            table_costs(codes, self.person_table, settings.lut_bits)

    def reset(self) -> None:
        self.history[:] = 0

    def _codec_aware(self, codes: np.ndarray, box: Box) -> tuple[np.ndarray, np.ndarray]:
        """Squared Mahalanobis distance (h, w) and ``0.5 sum_c ln(2 pi var_c)`` (h, w) of a
        box whose variance includes the codec's error.

        A block codec (JPEG, MPEG: 8x8 luma, 16x16 chroma blocks at 4:2:0) spreads the error of
        coding a change over the whole block it falls in, as ringing around a person's rim.
        Its variance, per pixel and equal in the three channels, is taken as
        ``codec_error_fraction`` times the mean squared change (frame minus background,
        averaged over the channels) in the ``codec_block_px`` square around the pixel: next
        to a person it is large, on the quiet site it is the sensor noise's small share. Used
        only when the learned frames were block-coded (``blockiness`` at least
        ``codec_blockiness_min``): on frames that never were, it would only hide people's
        low-contrast pixels next to their high-contrast ones.
        """
        s = self.settings
        bg = self.background
        y0, y1, x0, x1 = box
        diff = cv2.subtract(codes, bg.mean[y0:y1, x0:x1], dtype=cv2.CV_32F)
        sq = cv2.multiply(diff, diff)
        k = s.codec_block_px
        spread = cv2.blur(cv2.transform(sq, _SUM3 / 3.0), (k, k),
                          borderType=cv2.BORDER_REPLICATE) * np.float32(s.codec_error_fraction)
        # The spread added to each channel by OpenCV (grey to 3 channels, then add): the same
        # sums as numpy's broadcast, which took 10 times as long here.
        var = cv2.add(bg.total_var[y0:y1, x0:x1], cv2.cvtColor(spread, cv2.COLOR_GRAY2BGR))
        d2 = cv2.transform(cv2.divide(sq, var), _SUM3)
        # 0.5 sum_c ln(2 pi var_c), the logarithms by OpenCV (a product over numpy's
        # strided channels took three times as long).
        log_norm = cv2.transform(cv2.log(var), _SUM3 * np.float32(0.5))
        log_norm += np.float32(1.5 * math.log(2.0 * math.pi))
        return d2, log_norm

    def _dark_spread(self, codes: np.ndarray, box: Box, ys: np.ndarray,
                     xs: np.ndarray) -> np.ndarray:
        """(n,) float32: at the box pixels ``(ys, xs)``, the standard deviation of the
        frame's log change in green (the channel luminance mostly is) over the background's,
        in the ``codec_chroma_px`` square around each.

        At 4:2:0 a codec keeps one colour for each 2x2 pixels and its decoder interpolates
        between them (and quantises it per 16x16 block): a pixel's chromaticity is partly its
        neighbours'. Luminance is kept at full resolution, so how much the neighbours'
        change differs from the pixel's own says how far its colour change can be off: at a
        shadow's edge, where the sunlit ground's colour bleeds in, a lot; inside, little.
        Computed over the pixels' bounding rectangle only (and a margin of half the square).
        """
        y0, _, x0, _ = box
        k = self.settings.codec_chroma_px
        h, w = codes.shape[:2]
        m = k // 2 + 1
        r0, r1 = max(0, int(ys.min()) - m), min(h, int(ys.max()) + m + 1)
        c0, c1 = max(0, int(xs.min()) - m), min(w, int(xs.max()) + m + 1)
        change = cv2.subtract(
            cv2.LUT(cv2.extractChannel(codes[r0:r1, c0:c1], 1), self._log_green),
            self.background.log_green[y0 + r0:y0 + r1, x0 + c0:x0 + c1])
        mean = cv2.blur(change, (k, k), borderType=cv2.BORDER_REPLICATE)
        mean_sq = cv2.blur(cv2.multiply(change, change), (k, k),
                           borderType=cv2.BORDER_REPLICATE)
        var = cv2.max(mean_sq - cv2.multiply(mean, mean), 0.0)
        return np.sqrt(var[ys - r0, xs - c0])

    def colour_terms(self, corrected: np.ndarray, box: Box) -> dict:
        """The colour costs ``U^C`` of one region and its shadow features (before the cut).

        Returns arrays over the box (h, w): ``cost_fg``, ``cost_bg`` (nats), ``different``
        (the person model explains the pixel better than its background, i.e. the
        foreground before shadow removal, as the paper's Fig. 16 b), ``candidates`` (those of
        them darker than their background within ``shadow_ratio``) and, for the candidates
        only, the shadow features of :func:`~server.occlusion.shadow.shadow_features` and
        ``core`` (n,) bool, those at least ``shadow_signature_core_px`` inside ``different``
        (the pixels the shadow signature is estimated from).
        """
        s = self.settings
        bg = self.background
        y0, y1, x0, x1 = box
        codes = corrected[y0:y1, x0:x1]
        h, w = codes.shape[:2]
        coded = self.coded()
        if coded:
            d2, log_norm = self._codec_aware(codes, box)
        else:
            d2 = squared_distance(codes, bg.mean[y0:y1, x0:x1], bg.inv_var[y0:y1, x0:x1])
            log_norm = bg.log_norm[y0:y1, x0:x1]
        d2 = d2.reshape(h, w)
        log_pixel = -0.5 * d2 - log_norm
        if self._log_global_w is not None:
            idx = colour_index(codes.reshape(-1, 3), s.lut_bits).reshape(h, w)
            log_bg = np.logaddexp(self._log_global_w + bg.global_table[idx],
                                  self._log_pixel_w + log_pixel)
        else:
            log_bg = log_pixel
        cost_bg = -log_bg
        cost_fg = table_costs(codes, self.person_table, s.lut_bits)  # -ln p(I | person)
        different = cost_bg > cost_fg
        # Shadow candidates: the pixels that differ and are darker than their background within
        # shadow_ratio (a cheap luminance test first; the chromaticity only for those).
        tr = self.transfer
        # Gathers by flat index into the whole-frame arrays (faster than masking box views),
        # as take(axis=0): numpy's fancy index of (N, 3) rows took 5-7 times as long.
        ys, xs = np.nonzero(different)
        flat = (ys + y0) * bg.width + (xs + x0)
        # Table reads as np.take at 3 code + channel (Transfer.channel_index): same values.
        at = tr.channel_index(corrected.reshape(-1, 3).take(flat, axis=0))  # (n, 3)
        lin = tr.decode_flat.take(at)
        lin_bg = bg.linear.reshape(-1, 3).take(flat, axis=0)
        ratio = luminance(lin) / np.maximum(luminance(lin_bg), 1e-9)
        lo, hi = s.shadow_ratio
        dark = np.flatnonzero((ratio > lo) & (ratio < hi))  # indices into ys, xs
        ys, xs = ys.take(dark), xs.take(dark)
        candidates = np.zeros((h, w), dtype=bool)
        candidates[ys, xs] = True
        flat = flat.take(dark)
        at, lin, lin_bg = (a.take(dark, axis=0) for a in (at, lin, lin_bg))
        at_bg = tr.channel_index(bg.mean_u8.reshape(-1, 3).take(flat, axis=0))
        # Sensor noise of each channel's ln value: the background's spread (codes) times the
        # slope of ln(linear) at the frame's code.
        noise = np.sqrt(bg.var.reshape(-1, 3).take(flat, axis=0)) * tr.log_slope_flat.take(at)
        features = shadow_features(
            lin, lin_bg, s, tr.log_flat.take(at), tr.log_flat.take(at_bg), noise,
        )
        if coded and s.codec_chroma_px > 1 and len(dark):
            local = self._dark_spread(codes, box, ys, xs)
            features = features._replace(dark_local=local)
        # The candidates the signature is estimated from: the core of the foreground, away
        # from its rim on lit ground. Under heavy sensor noise the outer penumbra (ground lit
        # 70-90 %) and noise specks at that rim outnumbered the umbra in the signature's fine
        # darkening bins, and the signature locked onto them (issue 18, noise 3 codes).
        # The foreground, not the candidates, is eroded: a small shadow under the feet
        # borders its person and keeps its core (eroding the candidates lost it).
        # The rim's width in pixels grows with the frame: the setting is per 1024 px of width
        # (2 there; 1 at 480-512 px, where 2 lost a high sun's small shadows under the feet).
        k = max(1, round(s.shadow_signature_core_px * bg.width / 1024)) if (
            s.shadow_signature_core_px > 0) else 0
        core = candidates
        if k > 0:
            core = cv2.erode(different.view(np.uint8), np.ones((2 * k + 1, 2 * k + 1), np.uint8))
        core = core.view(bool)[ys, xs]
        return {"box": box, "codes": codes, "cost_fg": cost_fg, "cost_bg": cost_bg,
                "different": different, "candidates": candidates, "features": features,
                "core": core}

    def cut(self, terms: dict) -> tuple[np.ndarray, np.ndarray]:
        """Graph cut of one region's energy; returns ``(person, shadow)``, (h, w) bool:
        ``shadow`` is the foreground the cut gave to the background as cast shadow."""
        s = self.settings
        y0, y1, x0, x1 = terms["box"]
        cost_fg, cost_bg, different = terms["cost_fg"], terms["cost_bg"], terms["different"]
        # Shadow is one more way to be background: the cheaper explanation counts.
        cand = terms["candidates"]
        as_shadow = self.signature.cost(terms["features"])
        shadow = np.zeros(different.shape, dtype=bool)
        shadow[cand] = as_shadow < cost_fg[cand]
        cost_bg[cand] = np.minimum(cost_bg[cand], as_shadow)
        hist = self.history[y0:y1, x0:x1]
        cost_fg += cv2.LUT(hist, self.temporal_fg)
        cost_bg += cv2.LUT(hist, self.temporal_bg)
        # Nodes only near pixels that may be people (now or last frame); the rest of the region
        # is background whatever its neighbours do (it matches its background Gaussian).
        if s.full_frame:
            free = None  # the unoptimised baseline: every pixel is a node
            part = (slice(None), slice(None))
        else:
            maybe = ((cost_bg > cost_fg) | (hist >= 2)).view(np.uint8)
            k = 2 * s.band_px + 1
            free = cv2.dilate(maybe, np.ones((k, k), np.uint8))
            # The graph only over the free pixels' bounding rectangle and a 1-pixel rim (the
            # fixed neighbours whose edges become unary costs): the same cut, less to build.
            x, y, w, h = cv2.boundingRect(free)
            if w == 0:
                return np.zeros(different.shape, dtype=bool), shadow
            part = (slice(max(0, y - 1), y + h + 1), slice(max(0, x - 1), x + w + 1))
            free = free[part].view(bool)
        w_right, w_down = contrast_weights(terms["codes"][part], s.spatial_weight,
                                           self.background.mean_contrast)
        person = np.zeros(different.shape, dtype=bool)
        person[part] = graph_cut(cost_fg[part], cost_bg[part], w_right, w_down, free)
        # Pieces of the shadow the codec kept as person: thin slivers and islands (module
        # shadowpieces). The sliver's radius is per 1024 px of frame width (1 at 480, 2 at 1024).
        gated = np.zeros(person.shape, dtype=bool)
        gated[cand] = np.isfinite(as_shadow)
        person, shadow = give_back_pieces(
            person, shadow, gated, s.shadow_sliver_share,
            round(s.shadow_sliver_px * self.background.width / 1024), s.shadow_island_share)
        return person, shadow & ~person

    def coded(self) -> bool:
        """Whether the learned frames were block-coded (the codec's terms apply)."""
        s = self.settings
        return (s.codec_error_fraction > 0.0
                and self.background.blockiness >= s.codec_blockiness_min)

    def segment(self, corrected: np.ndarray, boxes: list[Box]) -> tuple[np.ndarray, np.ndarray,
                                                                      np.ndarray]:
        """Label a frame (H, W, 3) uint8 in the reference illumination, inside ``boxes``.

        Returns full-frame ``(person, shadow, foreground)`` (H, W) bool: people, cast shadows
        removed from the foreground, and the foreground before shadow removal. The frame's
        shadow signature is re-estimated from all regions (their cores) before any is cut.
        """
        t0 = time.perf_counter()
        terms = [self.colour_terms(corrected, box) for box in boxes]
        if terms:
            merged = tuple(np.concatenate([np.broadcast_to(t["features"][k], t["core"].shape)
                                           [t["core"]] for t in terms])
                           for k in range(len(ShadowFeatures._fields)))
            self.signature.update(merged)
        t1 = time.perf_counter()
        shape = corrected.shape[:2]
        person = np.zeros(shape, dtype=bool)
        shadow = np.zeros(shape, dtype=bool)
        foreground = np.zeros(shape, dtype=bool)
        for t in terms:
            y0, y1, x0, x1 = t["box"]
            p, sh = self.cut(t)
            person[y0:y1, x0:x1] = p
            shadow[y0:y1, x0:x1] = sh
            foreground[y0:y1, x0:x1] = p | sh
        self.timings_ms = {"terms": 1e3 * (t1 - t0), "cut": 1e3 * (time.perf_counter() - t1)}
        return person, shadow, foreground

    def remember(self, person: np.ndarray, corrected: np.ndarray) -> None:
        """Shift the label history and, every ``fg_refit_every`` frames, refit person colours.

        The refit is spread over two frames (EM on one, the look-up table on the next) so no
        frame pays for both.
        """
        # history = 2 x^t + x^{t-1}: the new (t-1) bit is this frame, the old (t-1) becomes t-2.
        np.right_shift(self.history, 1, out=self.history)
        self.history |= person.view(np.uint8) << 1
        self._frames_since_refit += 1
        if self._table_pending:
            self.person_table = self.person_mixture.table(
                self.settings.lut_bits, self.settings.fg_uniform_weight
            )
            self._table_pending = False
            return
        if self._frames_since_refit < self.settings.fg_refit_every and self.person_mixture.fitted:
            return
        n = int(np.count_nonzero(person))
        if n < 200:
            return
        self._frames_since_refit = 0
        rng = np.random.default_rng(n)
        # Person pixels lie in the regions only: nonzero over the rows that have any (the
        # same pixels in the same order, without a pass over the whole frame).
        rows = np.flatnonzero(person.any(axis=1))
        ys, xs = np.nonzero(person[rows[0]:rows[-1] + 1])
        ys += rows[0]
        pick = rng.choice(n, size=min(n, self.settings.fg_samples), replace=False)
        samples = corrected[ys[pick], xs[pick]]
        self._table_pending = self.person_mixture.fit(samples, warm=True)
