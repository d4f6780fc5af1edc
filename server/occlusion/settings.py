"""Settings of the occlusion pipeline (issue 6), with their defaults and units.

Every number the pipeline uses is here, named with its unit, and listed in docs/occlusion.md.
The camera's spectral constants ``A`` and ``w`` of the F-value (Kakuta Eq. 11) follow from its
channels' centre wavelengths (:func:`camera_constants`) unless given explicitly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace


def camera_constants(wavelengths_nm: tuple[float, float, float]) -> tuple[float, float]:
    """``(A, w)`` of Kakuta Eq. 11 for narrow-band channels centred at ``(lambda_R, G, B)`` nm.

    With Wien's approximation a Planckian illuminant of temperature ``T`` gives the channel
    response ``e_c ~ lambda_c^-5 exp(-c2 / (lambda_c T))``, so in the chromaticities
    ``e_r = e_R / e_B``, ``e_g = e_G / e_B`` the temperature cancels from
    ``e_r = w * e_g^A`` with::

        A = (1/lambda_R - 1/lambda_B) / (1/lambda_G - 1/lambda_B)
        w = (lambda_G / lambda_B)^(5 A) / (lambda_R / lambda_B)^5

    (The paper prints the denominator of ``w`` with the exponent ``5A``; the derivation gives
    ``5``. ``w`` cancels when two F-values are compared as a ratio, which is what the shadow test
    does, so only ``A`` affects the result. ``tests/server/occlusion`` checks Eq. 11 against
    exact Wien spectra.)
    """
    lr, lg, lb = (float(x) for x in wavelengths_nm)
    if not (lr > lg > lb > 0):
        raise ValueError(f"wavelengths must satisfy R > G > B > 0 nm, got {wavelengths_nm}")
    A = (1.0 / lr - 1.0 / lb) / (1.0 / lg - 1.0 / lb)
    w = (lg / lb) ** (5.0 * A) / (lr / lb) ** 5.0
    return A, w


@dataclass(frozen=True)
class OcclusionSettings:
    """What the occlusion pipeline may be tuned with; defaults suit a 320-1024 px site camera.

    Input
    -----
    response : inverse response of the site camera (``"srgb"``, ``"linear"``, ``"gamma:G"`` or a
        table, as :func:`server.measure.inverse_response_table`); the F-value and the daylight
        gain are computed on linear values.
    learn_frames : frames of the empty site averaged (per-pixel median) before segmenting.

    Background model (background.py)
    --------------------------------
    bg_rate : per-frame update rate of the per-pixel background mean and variance where the
        final label is background (time constant ``1 / bg_rate`` frames).
    bg_update_bands : the slow update visits this many horizontal bands in turn, one per frame
        (rate ``bg_rate * bands`` each), so its cost is spread over frames.
    bg_protect_px : a band this wide around every person is not updated either (their edges).
    bg_update_gate : and only pixels within this many standard deviations (per channel, RMS) of
        their background are: a person the cut missed is not learned into the background.
    bg_sigma_floor : smallest per-channel standard deviation of the background, codes (0-255).
    bg_global_components : Gaussians in the global background colour mixture (paper: 15).
    bg_global_weight : weight of the global mixture against the per-pixel Gaussian in the
        background likelihood (Sun et al.'s combined model); small, because a fixed site camera's
        per-pixel model is far sharper and a large weight hides people dressed in colours that
        occur elsewhere in the background.
    gain_sample_step_px : the daylight gain is a median over every this-many coarse pixels.

    Region of interest (pipeline.py)
    --------------------------------
    detect_scale : the background difference that finds candidate regions is taken on frames
        shrunk by this factor (the graph cut then runs at full resolution inside the regions).
    detect_threshold : mean absolute difference, codes, above which a coarse pixel is a
        candidate.
    roi_pad_px : full-resolution margin added around each candidate region.
    min_region_px : candidate regions smaller than this (full-resolution pixels) are noise.

    Segmentation energy (segment.py, Kakuta Eq. 6-7)
    ------------------------------------------------
    fg_components : Gaussians in the foreground colour mixture (paper: 5).
    fg_uniform_weight : weight of a uniform colour density in the foreground model, so a person
        in a colour not yet seen is still explained.
    fg_refit_every : refit the foreground mixture every this many frames (warm-started EM).
    fg_samples : at most this many person pixels are used for a refit.
    temporal_weight : ``alpha``, weight of the temporal prior ``V^T``.
    temporal_prior : ``P(person now | person at t-1, person at t-2)`` for the four histories
        ``((0, 0), (0, 1), (1, 0), (1, 1))`` as ``(t-1, t-2)`` pairs.
    spatial_weight : ``beta``, weight of the contrast-sensitive spatial prior ``V^S``, nats per
        neighbour pair.
    band_px : graph nodes are the pixels within this distance of a possible person pixel
        (foreground by colour, or person in the last frame); the others are fixed background.
    lut_bits : colour bits per channel of the mixture look-up tables.
    full_frame : one graph node per pixel of the whole frame, no regions, no band (the
        unoptimised baseline of the benchmark; same energy).

    Shadow (shadow.py, Kakuta Eq. 8-12)
    -----------------------------------
    wavelengths_nm : centre wavelengths of the R, G, B channels; ``A`` and ``w`` follow.
    f_constants : ``(A, w)`` given directly instead of ``wavelengths_nm``.
    t_f : a pixel is shadow only when ``|ln F - ln F_background| < t_f``.
    shadow_ratio : ``(min, max)`` of its luminance over the background's (``max < 1``: darker).
    shadow_min_blue_shift : and its ``ln(G/B)`` lies at least this far below the background's:
        the shadowed ground is lit by the sky alone, which is bluer (a higher colour
        temperature) than sun plus sky. 0 gives the paper's two conditions alone.
    shadow_signature : also require the blue shift and darkening of the frame's shadows
        (shadow.ShadowSignature), tracked from frame to frame.
    daylight_temperatures_k : (sun plus sky, sky alone) colour temperatures, K, from which the
        first expected blue shift of shadows follows (Wien's approximation).
    shadow_search : half width, ln units, of the blue shifts searched around the last estimate.
    shadow_shift_tolerance : a shadow's blue shift is within this of the frame's, ln units.
    shadow_dark_tolerance : its log darkening is within this of the frame's.
    shadow_signature_rate : smoothing of the signature from frame to frame (1: no memory).
    shadow_cost : background cost, nats, of a pixel that is a perfect shadow.
    shadow_slope : added cost, nats, per squared tolerance of deviation from a perfect shadow.
    dark_floor : linear values below this (on any channel) make the chromaticity meaningless;
        such pixels are never called shadow.

    People and depth (depth.py, Kakuta Eq. 13)
    -------------------------------------------
    min_person_px : connected person regions smaller than this are dropped.
    foot_min_px : the foot line is the lowest row with at least this many pixels of the region.
    """

    response: object = "srgb"
    learn_frames: int = 10

    bg_rate: float = 0.02
    bg_update_bands: int = 4
    bg_protect_px: int = 3
    bg_update_gate: float = 3.0
    bg_sigma_floor: float = 2.0
    bg_global_components: int = 15
    bg_global_weight: float = 0.0
    gain_sample_step_px: int = 2

    detect_scale: int = 4
    detect_threshold: float = 7.0
    roi_pad_px: int = 8
    min_region_px: int = 32

    fg_components: int = 5
    fg_uniform_weight: float = 0.3
    fg_refit_every: int = 10
    fg_samples: int = 300
    temporal_weight: float = 1.0
    temporal_prior: tuple[float, float, float, float] = (0.1, 0.3, 0.7, 0.9)
    spatial_weight: float = 6.0
    band_px: int = 3
    lut_bits: int = 5
    full_frame: bool = False

    wavelengths_nm: tuple[float, float, float] = (610.0, 540.0, 465.0)
    f_constants: tuple[float, float] | None = None
    t_f: float = 0.12
    shadow_ratio: tuple[float, float] = (0.15, 0.92)
    shadow_min_blue_shift: float = 0.08
    shadow_signature: bool = True
    daylight_temperatures_k: tuple[float, float] = (5600.0, 11000.0)
    shadow_search: float = 0.25
    shadow_shift_tolerance: float = 0.1
    shadow_dark_tolerance: float = 0.3
    shadow_signature_rate: float = 0.3
    shadow_cost: float = 6.0
    shadow_slope: float = 4.0
    dark_floor: float = 0.004

    min_person_px: int = 25
    foot_min_px: int = 2

    def __post_init__(self) -> None:
        checks = [
            (self.learn_frames >= 1, "learn_frames must be >= 1"),
            (0.0 < self.bg_rate < 1.0, "bg_rate must be in (0, 1)"),
            (self.bg_update_bands >= 1, "bg_update_bands must be >= 1"),
            (self.bg_rate * self.bg_update_bands < 1.0, "bg_rate * bg_update_bands must be < 1"),
            (self.bg_sigma_floor > 0, "bg_sigma_floor must be > 0"),
            (0.0 <= self.bg_global_weight < 1.0, "bg_global_weight must be in [0, 1)"),
            (self.detect_scale >= 1, "detect_scale must be >= 1"),
            (0.0 < self.fg_uniform_weight <= 1.0, "fg_uniform_weight must be in (0, 1]"),
            (len(self.temporal_prior) == 4, "temporal_prior needs four probabilities"),
            (all(0.0 < p < 1.0 for p in self.temporal_prior), "temporal_prior must be in (0, 1)"),
            (3 <= self.lut_bits <= 6, "lut_bits must be 3..6"),
            (self.t_f > 0, "t_f must be > 0"),
            (0.0 <= self.shadow_ratio[0] < self.shadow_ratio[1], "shadow_ratio must be (lo, hi)"),
        ]
        for ok, message in checks:
            if not ok:
                raise ValueError(f"occlusion settings: {message}")
        if self.f_constants is None:
            camera_constants(self.wavelengths_nm)  # validates

    @property
    def A(self) -> float:  # noqa: N802 (the paper's name)
        return (self.f_constants or camera_constants(self.wavelengths_nm))[0]

    @property
    def w(self) -> float:
        return (self.f_constants or camera_constants(self.wavelengths_nm))[1]

    def with_(self, **changes) -> OcclusionSettings:
        """A copy with some settings changed."""
        return replace(self, **changes)


def log_prior_table(prior: tuple[float, float, float, float]) -> tuple[list, list]:
    """``-ln P`` of person / background for each ``(t-1, t-2)`` history index ``2*a + b``."""
    cost_fg = [-math.log(p) for p in prior]
    cost_bg = [-math.log(1.0 - p) for p in prior]
    return cost_fg, cost_bg
