"""Cast shadows by the F-value, an illumination-invariant chromaticity (Kakuta Eq. 8-12).

With chromaticities ``i_r = R / B`` and ``i_g = G / B`` of linear light (Eq. 8), and a daylight
illuminant that follows Planck's law under Wien's approximation (Eq. 11,
``e_r = w e_g^A``), the quantity::

    F = i_r / (w * i_g^A) = s_r / s_g^A                                    (Eq. 12)

depends on the surface alone: the ground has the same F in sunlight and in shadow. (The paper
writes ``F = i_r / i_g^A``, which is ``w s_r / s_g^A``; ``w`` is a constant and cancels from the
comparison below, so both read the same.) A pixel that differs from the background is a shadow
when

1. ``|ln F - ln F_background| < t_F`` (the paper's condition 1, on the log so that ``t_F`` is a
   relative tolerance whatever the surface's colour),
2. its luminance is below the background's, within ``shadow_ratio`` (condition 2, with a lower
   bound: a shadow darkens by the share of direct sun in the light, not to black), and
3. its ``ln(G/B)`` is at least ``shadow_min_blue_shift`` below the background's: shadowed
   ground is lit by the sky alone, a higher colour temperature than sun plus sky;
4. (:class:`ShadowSignature`) its blue shift and darkening are close to those all of the
   frame's shadows share. The shift is along the Planckian direction that F deliberately
   ignores; it separates a shadow from a dark neutral garment over warm paving, which passes
   conditions 1 and 2.

``shadow_min_blue_shift = 0`` and ``shadow_signature = False`` give the paper's test alone.

Inputs are linear BGR (the order OpenCV frames come in).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from server.occlusion.settings import OcclusionSettings

# Luminance weights (Rec. 709) in BGR order.
_LUMA_BGR = np.array([0.0722, 0.7152, 0.2126], dtype=np.float32)


def log_f_value(linear_bgr: np.ndarray, A: float, w: float = 1.0) -> np.ndarray:
    """``ln F = ln(R/B) - A ln(G/B) - ln w`` of (..., 3) linear BGR values (Eq. 8, 12)."""
    lb = np.log(linear_bgr[..., 0])
    lg = np.log(linear_bgr[..., 1])
    lr = np.log(linear_bgr[..., 2])
    return (lr - lb) - A * (lg - lb) - np.log(w)


def luminance(linear_bgr: np.ndarray) -> np.ndarray:
    """(..., 3) linear BGR -> (...) float32 relative luminance."""
    return linear_bgr @ _LUMA_BGR


class ShadowFeatures(NamedTuple):
    """How a candidate pixel differs from its background, (N,) arrays each.

    ``usable``: no channel below ``dark_floor`` in either; ``f_change = ln F - ln
    F_background`` (``w`` cancels); ``blue = ln(G/B)_background - ln(G/B)`` (positive when
    bluer); ``dark``: log luminance ratio. ``*_noise``: standard deviation of each that the
    camera's noise alone gives (0 when unknown), added in quadrature to the tolerances.
    ``dark_local``: on block-coded frames, the standard deviation of the log change in
    green (about ``dark``) around the pixel, over the codec's chroma reach
    (``codec_chroma_px``; segment.Segmenter._dark_spread), 0 otherwise: at 4:2:0 a
    pixel's colour is shared with its neighbours, so its blue shift is off by as much as
    theirs differs (:meth:`ShadowSignature.cost` scales it by the signature's blue per
    darkening).
    """

    usable: np.ndarray
    f_change: np.ndarray
    blue: np.ndarray
    dark: np.ndarray
    f_noise: np.ndarray | float = 0.0
    blue_noise: np.ndarray | float = 0.0
    dark_noise: np.ndarray | float = 0.0
    dark_local: np.ndarray | float = 0.0


def shadow_features(
    frame_linear_bgr: np.ndarray, background_linear_bgr: np.ndarray, settings: OcclusionSettings,
    frame_log_bgr: np.ndarray | None = None, background_log_bgr: np.ndarray | None = None,
    log_noise_bgr: np.ndarray | None = None,
) -> ShadowFeatures:
    """:class:`ShadowFeatures` of (N, 3) linear BGR pixels against their background (N, 3).

    The logarithms of the inputs may be passed in (from tables) to save computing them;
    ``log_noise_bgr`` (N, 3) is the standard deviation of each channel's ``ln`` value from
    sensor noise (see :meth:`server.occlusion.colour.Transfer.log_slope`).
    """
    floor = settings.dark_floor
    # The smallest channel by np.minimum: numpy's min over a last axis of 3 took 10 times as long.
    lowest = np.minimum(np.minimum(frame_linear_bgr[..., 0], frame_linear_bgr[..., 1]),
                        np.minimum(frame_linear_bgr[..., 2], background_linear_bgr[..., 0]))
    lowest = np.minimum(lowest, np.minimum(background_linear_bgr[..., 1],
                                           background_linear_bgr[..., 2]))
    usable = lowest > floor
    lf = np.log(np.maximum(frame_linear_bgr, floor)) if frame_log_bgr is None else frame_log_bgr
    lb = (np.log(np.maximum(background_linear_bgr, floor)) if background_log_bgr is None
          else background_log_bgr)
    d_gb = (lf[..., 1] - lf[..., 0]) - (lb[..., 1] - lb[..., 0])
    d_rb = (lf[..., 2] - lf[..., 0]) - (lb[..., 2] - lb[..., 0])
    with np.errstate(divide="ignore"):
        dark = np.log(luminance(frame_linear_bgr) / np.maximum(luminance(background_linear_bgr),
                                                               1e-9))
    A = settings.A
    if log_noise_bgr is None:
        return ShadowFeatures(usable, d_rb - A * d_gb, -d_gb, dark)
    v = np.square(log_noise_bgr)  # ln F = ln R - A ln G + (A - 1) ln B
    f_noise = np.sqrt(v[..., 2] + A * A * v[..., 1] + (A - 1.0) ** 2 * v[..., 0])
    blue_noise = np.sqrt(v[..., 1] + v[..., 0])
    return ShadowFeatures(usable, d_rb - A * d_gb, -d_gb, dark, f_noise, blue_noise,
                          log_noise_bgr[..., 1])


def _tolerance(tol: float, noise) -> np.ndarray | float:
    return np.sqrt(tol * tol + np.square(noise))


def paper_test(features, settings: OcclusionSettings) -> np.ndarray:
    """Kakuta's conditions 1 and 2 (with ``shadow_ratio`` bounds and the minimum blue shift)."""
    f = ShadowFeatures(*features)
    lo, hi = settings.shadow_ratio
    ok = f.usable & (np.abs(f.f_change) < _tolerance(settings.t_f, f.f_noise))
    ok &= (f.dark > np.log(max(lo, 1e-6))) & (f.dark < np.log(hi))
    if settings.shadow_min_blue_shift > 0.0:
        ok &= f.blue >= settings.shadow_min_blue_shift
    return ok


def expected_blue_shift(settings: OcclusionSettings) -> float:
    """``ln(G/B)`` change from sunlit to shadowed ground for Planckian illuminants at
    ``daylight_temperatures_k`` (sun plus sky, sky alone), under Wien's approximation."""
    c2 = 1.4388e-2  # m K
    _, lg, lb = (x * 1e-9 for x in settings.wavelengths_nm)
    t_lit, t_sky = settings.daylight_temperatures_k
    return float(c2 * (1.0 / t_lit - 1.0 / t_sky) * (1.0 / lb - 1.0 / lg))


def _spread(deviation: np.ndarray, start: float, most: float) -> float:
    """Standard deviation of the population around 0 in ``deviation`` (N,), ln units.

    1.4826 MAD of the values within a window that starts at ``start`` and widens to 2.5
    spreads (at most ``most``): a window as wide as the search from the start would take in
    a second population nearby (a neutral coat 0.2 less blue than the shadows) and widen
    the tolerance enough to let it pass; a fixed narrow one would truncate a wide peak.
    Underestimates a little where the window is still under 2.5 spreads wide.
    """
    window, sigma = start, 0.0
    for _ in range(3):
        inside = np.abs(deviation) < window
        if np.count_nonzero(inside) < 20:
            return sigma
        sigma = 1.4826 * float(np.median(np.abs(deviation[inside])))
        wider = min(most, 2.5 * sigma)
        if wider <= window:
            break
        window = wider
    return sigma


class ShadowSignature:
    """The change of illuminant that every cast shadow of a frame shares, tracked over frames.

    All of a frame's shadows trade the same sun-plus-sky illuminant for the same skylight, so
    against their backgrounds they are darker by one factor and bluer by one shift along the
    Planckian direction (the direction F ignores). The pixels that pass the paper's test are
    histogrammed over (blue shift, log darkening); the peak that is large and near the last
    estimate (at first, the shift :func:`expected_blue_shift` predicts) becomes the new
    estimate, smoothed over frames. A pixel is then shadow when it passes the paper's test *and*
    lies within ``shadow_shift_tolerance`` / ``shadow_dark_tolerance`` of the signature (as a
    soft cost, :meth:`cost`): a neutral grey coat over warm paving passes the first but is far
    less blue than a real shadow.
    """

    def __init__(self, settings: OcclusionSettings):
        self.settings = settings
        self.blue = expected_blue_shift(settings)
        self.dark: float | None = None  # unknown until the first shadows are seen
        # Spread (ln units, a standard deviation) of the blue shift among the frame's shadow
        # pixels, learned with the signature: what the camera's noise and a codec's chroma
        # error make of one illuminant change (0 until measured). The darkening's is not
        # learned: the candidates' darkening mixes garments of every shade with the shadows,
        # and learning it changed nothing through the codecs (issue 18).
        self.blue_spread = 0.0
        self.updates = 0

    def update(self, features) -> None:
        """Re-estimate from a frame's candidate pixels (the tuple of :func:`shadow_features`)."""
        s = self.settings
        blue, dark = features[2], features[3]
        # Blue shifts from slightly negative (a neutral shadow, with noise) to beyond the last
        # estimate and the Planckian prediction: neutral and bluish skies alike.
        lo_b = -0.1
        hi_b = max(self.blue, expected_blue_shift(s)) + s.shadow_search
        ok = paper_test(features, s) & (blue > lo_b) & (blue < hi_b)
        # The umbra sets the signature; the penumbra (less dark) is matched to it in cost().
        if self.dark is not None:
            ok &= dark < 0.5 * self.dark
        if np.count_nonzero(ok) < 30:
            return
        b, d = blue[ok], dark[ok]
        # Fine bins in darkening, unsmoothed: a shadow darkens all the ground it falls on by
        # one factor (a sharp peak), a garment over textured ground by as many factors as the
        # ground has shades (a spread one), even when the two share their chromaticity.
        step_b, step_d = s.shadow_shift_tolerance / 2, s.shadow_dark_tolerance / 6
        lo_d = float(d.min())
        nb = int((hi_b - lo_b) / step_b) + 1
        nd = int((float(d.max()) - lo_d) / step_d) + 1
        hist = np.zeros((nb + 2, nd + 2))
        ib = np.clip(((b - lo_b) / step_b).astype(int), 0, nb - 1) + 1
        id_ = np.clip(((d - lo_d) / step_d).astype(int), 0, nd - 1) + 1
        np.add.at(hist, (ib, id_), 1.0)
        smooth = sum(np.roll(hist, i, 0) for i in (-1, 0, 1))
        # The peak most consistent with the last estimate, not merely the largest:
        # a dark grey coat can outnumber its owner's shadow in one frame.
        centres = lo_b + (np.arange(nb + 2) - 0.5) * step_b
        prior = (np.exp(-0.5 * ((centres - self.blue) / (0.5 * s.shadow_search)) ** 2)
                 if self.updates else np.ones(nb + 2))
        prior = prior[:, None]
        if self.dark is not None:
            # Darkening changes slowly (a cloud fades the shadows over seconds): a peak far
            # darker than the last estimate is a dark garment, not the shadows. Under heavy
            # noise and a cloud, the fading shadows' cores vanished and the signature jumped
            # to a neutral grey garment (ln -0.3 -> -1.4; issue 18).
            centres_d = lo_d + (np.arange(nd + 2) - 0.5) * step_d
            prior = prior * np.exp(-0.5 * ((centres_d - self.dark)
                                           / s.shadow_dark_tolerance) ** 2)[None, :]
        pb, pd = np.unravel_index(int(np.argmax(smooth * prior)), smooth.shape)
        cb, cd = lo_b + (pb - 0.5) * step_b, lo_d + (pd - 0.5) * step_d
        if self.dark is not None and abs(cd - self.dark) > 2.0 * s.shadow_dark_tolerance:
            return
        near = np.abs(b - cb) < s.shadow_shift_tolerance
        near &= np.abs(d - cd) < s.shadow_dark_tolerance
        if np.count_nonzero(near) < 20:
            return
        nb_, nd_ = float(np.median(b[near])), float(np.median(d[near]))
        # The spread about the peak. Through a block codec a shadow's blue shift spreads over
        # +-0.15 (4:2:0 chroma bleeding from the sunlit side, coarse chroma quantisation; raw
        # +-0.07), more than shadow_shift_tolerance allows.
        sb = _spread(b - nb_, s.shadow_shift_tolerance, s.shadow_search)
        rate = 1.0 if self.updates == 0 else s.shadow_signature_rate
        self.blue += rate * (nb_ - self.blue)
        self.dark = nd_ if self.dark is None else self.dark + rate * (nd_ - self.dark)
        self.blue_spread += rate * (sb - self.blue_spread)
        self.updates += 1

    @property
    def shift_tolerance(self) -> float:
        """Tolerance of a shadow's blue shift, ln units: ``shadow_shift_tolerance``, or two
        learned spreads where the frames are noisier (a codec), at most ``shadow_search``."""
        s = self.settings
        if not s.shadow_learn_spread:
            return s.shadow_shift_tolerance
        return min(max(s.shadow_shift_tolerance, 2.0 * self.blue_spread),
                   max(s.shadow_search, s.shadow_shift_tolerance))

    def cost(self, features) -> np.ndarray:
        """(N,) float32 background cost, nats, of explaining each candidate as shadow.

        ``shadow_cost + shadow_slope * m^2``, with ``m^2`` the squared deviations from a perfect
        shadow in units of their tolerances: of ln F (``t_f``, the paper's condition 1) and,
        with ``shadow_signature``, of the blue shift and the darkening from the frame's
        signature; each tolerance is widened by the noise of its feature (in quadrature). A
        soft cost rather than a yes/no test, so that a shadow pixel just outside a tolerance is
        still cheaper as background than as a person. +inf where the hard
        conditions fail (not darker within ``shadow_ratio``, not bluer by
        ``shadow_min_blue_shift``, ``|ln F|`` change beyond ``2 t_f``, unusably dark) and
        where ``m`` exceeds ``shadow_max_deviation``.
        """
        s = self.settings
        f = ShadowFeatures(*features)
        lo, hi = s.shadow_ratio
        gate = f.usable & (f.dark > np.log(max(lo, 1e-6))) & (f.dark < np.log(hi))
        tol_f = _tolerance(s.t_f, f.f_noise)
        gate &= np.abs(f.f_change) < 2.0 * tol_f
        if s.shadow_min_blue_shift > 0.0:
            gate &= f.blue >= s.shadow_min_blue_shift
        m2 = (f.f_change / tol_f) ** 2
        if s.shadow_signature:
            tol_b = self.shift_tolerance if self.updates else s.shadow_search
            blue = self.blue
            if self.dark is not None and not s.shadow_penumbra:
                # dark_local: at a shadow's edge a codec blurs the luminance step too (JPEG's
                # and H.264's quantised blocks, the deblocking filter), so the darkening
                # there is uncertain by as much as it varies around the pixel.
                tol_d = _tolerance(s.shadow_dark_tolerance, np.sqrt(
                    np.square(f.dark_noise) + np.square(np.asarray(f.dark_local))))
                m2 += ((f.dark - self.dark) / tol_d) ** 2
            elif self.dark is not None:
                # Penumbra: covered a share c of the way, the ground is lit by
                # 1 - c (1 - r) per channel (r the umbra's ratio), so a pixel darker by
                # less than the umbra is also less blue. c from the darkening, then the blue
                # shift it implies; darker than the umbra counts as deviation.
                r_g = math.exp(self.dark)
                r_b = r_g * math.exp(self.blue)
                c = np.clip((1.0 - np.exp(f.dark)) / max(1.0 - r_g, 1e-3), 0.0, 1.0)
                blue = (np.log(np.maximum(1.0 - c * (1.0 - r_b), 1e-3))
                        - np.log(np.maximum(1.0 - c * (1.0 - r_g), 1e-3)))
                tol_d = _tolerance(s.shadow_dark_tolerance, f.dark_noise)
                m2 += (np.minimum(f.dark - self.dark, 0.0) / tol_d) ** 2
            blue_noise = f.blue_noise
            if self.dark is not None and np.any(f.dark_local):
                # The codec's chroma bleeding: neighbours darkened differently by dark_local
                # (ln) are bluer by that times the shadows' blue per darkening.
                per_dark = abs(self.blue / min(self.dark, -1e-3))
                blue_noise = np.sqrt(np.square(blue_noise)
                                     + np.square(per_dark * np.asarray(f.dark_local)))
            m2 += ((f.blue - blue) / _tolerance(tol_b, blue_noise)) ** 2
        if s.shadow_max_deviation > 0:
            # Beyond a few tolerances from a perfect shadow a pixel is something else (dark
            # shoes on their own shadow, dark hair: not bluer by the shadows' shift); as a
            # merely expensive shadow the cut's smoothing still joined it to the shadow.
            gate &= m2 <= s.shadow_max_deviation ** 2
        cost = s.shadow_cost + s.shadow_slope * m2
        return np.where(gate, cost, np.inf).astype(np.float32)

    def test(self, features) -> np.ndarray:
        """(N,) bool: within every tolerance (``m <= 1``): a shadow for certain."""
        return self.cost(features) <= self.settings.shadow_cost + self.settings.shadow_slope


def shadow_test(
    frame_linear_bgr: np.ndarray, background_linear_bgr: np.ndarray, settings: OcclusionSettings
) -> np.ndarray:
    """The paper's per-pixel test alone: (N, 3), (N, 3) linear -> (N,) bool."""
    return paper_test(shadow_features(frame_linear_bgr, background_linear_bgr, settings), settings)
