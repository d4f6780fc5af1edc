"""Settings of the occlusion pipeline (issue 6), with their defaults and units.

Every number the pipeline uses is here, named with its unit, and listed in docs/occlusion.md.
The camera's spectral constants ``A`` and ``w`` of the F-value (Kakuta Eq. 11) follow from its
channels' centre wavelengths (:func:`camera_constants`) unless given explicitly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np

from daylit.settingschema import first_problem


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


def _num(default, description, **bounds) -> dict:
    return {"type": "number", "default": default, "description": description, **bounds}


def _int(default, description, **bounds) -> dict:
    return {"type": "integer", "default": default, "description": description, **bounds}


def _numbers(default, n, description, **bounds) -> dict:
    return {"type": "array", "items": {"type": "number", **bounds}, "minItems": n,
            "maxItems": n, "default": default, "description": description}


# Every setting of the pipeline with its default, what is allowed and its meaning: the one
# source of OcclusionSettings' defaults, its checks (daylit.settingschema) and the table in
# docs/occlusion.md (tests/server/occlusion/test_occlusion_docs.py).
SCHEMA: dict = {
    "type": "object",
    "additionalProperties": False,
    "properties": {
        # Input
        "response": {"type": ["string", "array"], "default": "srgb",
                     "x-allowed": "srgb, linear, gamma:G or a table",
                     "description": "inverse response of the site camera (as server.measure"
                     ".inverse_response_table); the F-value and the daylight gain are "
                     "computed on linear values"},
        "learn_frames": _int(10, "frames of the empty site averaged (per-pixel median) "
                             "before segmenting", minimum=1),
        # Camera shake (register.py)
        "register": {"type": "boolean", "default": True,
                     "description": "register each frame to the background (one sub-pixel "
                     "translation) before comparing; off for a camera known to be still"},
        "register_scale": _int(2, "the registration works on grey frames shrunk by this "
                               "factor", minimum=1),
        "register_blur_px": _num(2.0, "standard deviation, frame pixels, of the Gaussian blur "
                                 "before registration", minimum=0),
        "register_iterations": _int(3, "Gauss-Newton steps per frame at most", minimum=1),
        "register_max_shift_px": _num(8.0, "a larger estimated shift is rejected (the last "
                                      "one is kept), frame pixels", exclusiveMinimum=0),
        "register_min_shift_px": _num(0.05, "below this shift, frame pixels, the frame is "
                                      "compared as it is (no resampling)", minimum=0),
        "register_tolerance_px": _num(0.1, "registration uncertainty, pixels: the background's "
                                      "variance gets (gradient x this)^2 added, so edges of "
                                      "fixed objects tolerate the residual shift", minimum=0),
        # Codec error (segment.py)
        "codec_error_fraction": _num(0.1, "variance of a block codec's error near a change, "
                                     "as a share of the mean squared change around the pixel "
                                     "(0: off)", minimum=0),
        "codec_block_px": _int(16, "side, pixels, of the square that share of the change is "
                               "averaged over (16: a 4:2:0 chroma block)", minimum=1),
        "outline_radius_px": _int(2, "on block-coded frames, people's outlines are moved "
                                  "onto the luminance edges by a guided filter of this window "
                                  "radius, pixels (outline.py; 0: off)", minimum=0),
        "outline_eps": _num(25.0, "the guided filter's regulariser, squared 8-bit codes",
                            exclusiveMinimum=0),
        "codec_blockiness_min": _num(1.1, "the codec's error is modelled only when the "
                                     "learned frames' block-boundary step ratio "
                                     "(background.blockiness) is at least this", minimum=0),
        "codec_chroma_px": _int(5, "side, pixels, of the square over which a block-coded "
                                "frame's colour is shared (4:2:0 and its interpolation): a "
                                "shadow's blue shift may be off by the spread of the "
                                "darkening there (1: off)", minimum=1),
        # Background model (background.py)
        "bg_rate": _num(0.02, "per-frame update rate of the per-pixel background mean and "
                        "variance where the final label is background (time constant 1 / "
                        "bg_rate frames)", exclusiveMinimum=0, exclusiveMaximum=1),
        "bg_update_bands": _int(8, "the slow update visits one of this many row bands per "
                                "frame (rate bg_rate * bands each; bg_rate * bands < 1)",
                                minimum=1),
        "bg_protect_px": _int(3, "no update this close to a person or shadow, pixels",
                              minimum=0),
        "bg_update_gate": _num(3.0, "no update of pixels further than this many standard "
                               "deviations (per channel, RMS) from their background: a person "
                               "the cut missed is not learned", exclusiveMinimum=0),
        "bg_sigma_floor": _num(2.0, "smallest per-channel standard deviation of the "
                               "background, codes (0-255)", exclusiveMinimum=0),
        "bg_global_components": _int(15, "Gaussians of the global background colour mixture "
                                     "(paper: 15)", minimum=1),
        "bg_global_weight": _num(0.0, "lambda, weight of the global mixture against the "
                                 "per-pixel Gaussian in the background term (small: a large "
                                 "one hides people in colours found elsewhere in the "
                                 "background)", minimum=0, exclusiveMaximum=1),
        "gain_sample_step_px": _int(2, "the daylight gain is a median over every this-many "
                                    "coarse pixels", minimum=1),
        "region_gain_min_share": _num(0.02, "smooth regions above the horizon (the sky) "
                                      "holding at least this share of the frame get a "
                                      "daylight gain of their own (regiongain.py; 0: off)",
                                      minimum=0, maximum=1),
        "region_gain_step_codes": _num(4.0, "such a region's neighbouring coarse pixels "
                                       "differ by at most this, codes, in every channel",
                                       minimum=0),
        # Region of interest (pipeline.py)
        "detect_scale": _int(4, "the background difference that finds candidate regions is "
                             "taken on frames shrunk by this factor", minimum=1),
        "detect_threshold": _num(7.0, "mean absolute difference, codes, above which a coarse "
                                 "pixel is a candidate", minimum=0),
        "roi_pad_px": _int(8, "full-resolution margin around each candidate region, pixels",
                           minimum=0),
        "min_region_px": _int(32, "candidate regions smaller than this (full-resolution "
                              "pixels) are noise", minimum=0),
        # Segmentation energy (segment.py, Kakuta Eq. 6-7)
        "fg_components": _int(5, "Gaussians of the person colour mixture (paper: 5)",
                              minimum=1),
        "fg_uniform_weight": _num(0.3, "uniform share of the person colour density, so a "
                                  "person in a colour not yet seen is still explained",
                                  exclusiveMinimum=0, maximum=1),
        "fg_refit_every": _int(10, "frames between refits of the person mixture (warm-started "
                               "EM)", minimum=1),
        "fg_samples": _int(300, "at most this many person pixels per refit", minimum=1),
        "temporal_weight": _num(1.0, "alpha, weight of the temporal prior V^T", minimum=0),
        "temporal_prior": _numbers([0.1, 0.3, 0.7, 0.9], 4, "P(person now | person at t-1, "
                                   "t-2) after (0,0), (0,1), (1,0), (1,1)",
                                   exclusiveMinimum=0, exclusiveMaximum=1),
        "spatial_weight": _num(6.0, "beta, weight of the contrast-sensitive spatial prior "
                               "V^S, nats per pair of neighbours with different labels (at no "
                               "contrast)", minimum=0),
        "band_px": _int(3, "graph nodes are the pixels within this distance of a possible "
                        "person pixel; the others are fixed background", minimum=0),
        "lut_bits": _int(5, "colour bits per channel of the mixture look-up tables",
                         minimum=3, maximum=6),
        "full_frame": {"type": "boolean", "default": False,
                       "description": "one graph node per pixel of the whole frame, no "
                       "regions, no band (the benchmark's unoptimised baseline; same energy)"},
        # Shadow (shadow.py, Kakuta Eq. 8-12)
        "wavelengths_nm": _numbers([610.0, 540.0, 465.0], 3, "centre wavelengths of the R, "
                                   "G, B channels, nm (R > G > B); A and w follow",
                                   exclusiveMinimum=0),
        "f_constants": {"type": ["array", "null"], "items": {"type": "number"},
                        "minItems": 2, "maxItems": 2, "default": None,
                        "x-allowed": "null or two numbers [A, w]",
                        "description": "(A, w) of Kakuta Eq. 11 given directly instead of "
                        "wavelengths_nm"},
        "t_f": _num(0.12, "a pixel is shadow only when |ln F - ln F_background| < t_f",
                    exclusiveMinimum=0),
        "shadow_ratio": _numbers([0.05, 0.92], 2, "(lo, hi) of a shadow's luminance over the "
                                 "background's (hi < 1: darker), lo < hi", minimum=0),
        "shadow_min_blue_shift": _num(0.0, "least drop of ln(G/B) below the background's "
                                      "in shadow (lit by the bluer sky alone); 0: the paper's "
                                      "two conditions alone", minimum=0),
        "shadow_signature": {"type": "boolean", "default": True,
                             "description": "also require the blue shift and darkening of "
                             "the frame's shadows (shadow.ShadowSignature), tracked from "
                             "frame to frame"},
        "daylight_temperatures_k": _numbers([5600.0, 11000.0], 2, "colour temperatures, K, "
                                            "of sun plus sky and of sky alone, from which "
                                            "the first expected blue shift follows (Wien)",
                                            exclusiveMinimum=0),
        "shadow_penumbra": {"type": "boolean", "default": False,
                            "description": "a pixel darkened less than the frame's shadows "
                            "may be their penumbra (blue shift scaled to its darkening); "
                            "false: its darkening must be the shadows' within "
                            "shadow_dark_tolerance"},
        "shadow_learn_spread": {"type": "boolean", "default": True,
                                "description": "widen the blue-shift tolerance to twice the "
                                "spread of the frame's shadows' blue shifts (learned with the "
                                "signature; at most shadow_search): a codec's chroma error"},
        "shadow_search": _num(0.25, "half width, ln units, of the blue shifts searched "
                              "around the last estimate", minimum=0),
        "shadow_shift_tolerance": _num(0.1, "a shadow's blue shift is within this of the "
                                       "frame's, ln units", exclusiveMinimum=0),
        "shadow_dark_tolerance": _num(0.3, "its log darkening is within this of the "
                                      "frame's", exclusiveMinimum=0),
        "shadow_signature_core_px": _int(2, "the signature is estimated from candidates at "
                                         "least this many pixels (per 1024 px of frame "
                                         "width, at least 1) inside the foreground: its "
                                         "rim (outer penumbra, noise specks) left out; "
                                         "0: all", minimum=0),
        "shadow_signature_rate": _num(0.3, "smoothing of the signature from frame to frame "
                                      "(1: no memory)", exclusiveMinimum=0, maximum=1),
        "shadow_sliver_share": _num(0.8, "a person region at least this share of which "
                                    "passes the shadow's hard gates, and thin (see "
                                    "shadow_sliver_px), is a shadow's rim the codec left "
                                    "(0: off)", minimum=0, maximum=1),
        "shadow_island_share": _num(0.5, "a person region whose one-pixel ring is at least "
                                    "this share shadow is a piece of that shadow and joins it "
                                    "(shadowpieces.py; 0: off)", minimum=0, maximum=1),
        "shadow_sliver_px": _int(2, "a region is thin when an erosion of this radius, pixels "
                                 "per 1024 px of frame width (at least 1), leaves at most a "
                                 "tenth of it", minimum=0),
        "shadow_cost": _num(6.0, "background cost, nats, of a pixel that is a perfect shadow",
                            minimum=0),
        "shadow_slope": _num(4.0, "added cost, nats, per squared tolerance of deviation from "
                             "a perfect shadow", minimum=0),
        "shadow_max_deviation": _num(3.0, "a candidate further than this many tolerances "
                                     "(root of the summed squared deviations) from a perfect "
                                     "shadow is never shadow (0: no limit)", minimum=0),
        "dark_floor": _num(0.004, "linear values below this (on any channel) make the "
                           "chromaticity meaningless; such pixels are never shadow", minimum=0),
        # People and depth (depth.py, Kakuta Eq. 13)
        "min_person_px": _int(25, "connected person regions smaller than this are dropped",
                              minimum=0),
        "foot_min_px": _int(2, "the foot line is the lowest row with at least this many "
                            "pixels of the region", minimum=1),
        "min_person_height_m": _num(0.1, "person regions lower than this, metres, if "
                                    "they stood on their foot line are dropped as pieces of "
                                    "shadow lying on the ground (0: off; pinhole cameras only)",
                                    minimum=0),
    },
}


def _default(key: str):
    value = SCHEMA["properties"][key]["default"]
    return tuple(value) if isinstance(value, list) else value


@dataclass(frozen=True)
class OcclusionSettings:
    """What the occlusion pipeline may be tuned with; defaults suit a 320-1024 px site camera.

    Each field's meaning, unit, default and allowed values are in :data:`SCHEMA` (and the
    table generated from it in docs/occlusion.md). A value it does not allow raises
    ``ValueError("occlusion settings: KEY must be ..., got ...")``.
    """

    response: object = _default("response")
    learn_frames: int = _default("learn_frames")

    register: bool = _default("register")
    register_scale: int = _default("register_scale")
    register_blur_px: float = _default("register_blur_px")
    register_iterations: int = _default("register_iterations")
    register_max_shift_px: float = _default("register_max_shift_px")
    register_min_shift_px: float = _default("register_min_shift_px")
    register_tolerance_px: float = _default("register_tolerance_px")

    codec_error_fraction: float = _default("codec_error_fraction")
    codec_block_px: int = _default("codec_block_px")
    outline_radius_px: int = _default("outline_radius_px")
    outline_eps: float = _default("outline_eps")
    codec_blockiness_min: float = _default("codec_blockiness_min")
    codec_chroma_px: int = _default("codec_chroma_px")

    bg_rate: float = _default("bg_rate")
    bg_update_bands: int = _default("bg_update_bands")
    bg_protect_px: int = _default("bg_protect_px")
    bg_update_gate: float = _default("bg_update_gate")
    bg_sigma_floor: float = _default("bg_sigma_floor")
    bg_global_components: int = _default("bg_global_components")
    bg_global_weight: float = _default("bg_global_weight")
    gain_sample_step_px: int = _default("gain_sample_step_px")
    region_gain_min_share: float = _default("region_gain_min_share")
    region_gain_step_codes: float = _default("region_gain_step_codes")

    detect_scale: int = _default("detect_scale")
    detect_threshold: float = _default("detect_threshold")
    roi_pad_px: int = _default("roi_pad_px")
    min_region_px: int = _default("min_region_px")

    fg_components: int = _default("fg_components")
    fg_uniform_weight: float = _default("fg_uniform_weight")
    fg_refit_every: int = _default("fg_refit_every")
    fg_samples: int = _default("fg_samples")
    temporal_weight: float = _default("temporal_weight")
    temporal_prior: tuple[float, float, float, float] = _default("temporal_prior")
    spatial_weight: float = _default("spatial_weight")
    band_px: int = _default("band_px")
    lut_bits: int = _default("lut_bits")
    full_frame: bool = _default("full_frame")

    wavelengths_nm: tuple[float, float, float] = _default("wavelengths_nm")
    f_constants: tuple[float, float] | None = _default("f_constants")
    t_f: float = _default("t_f")
    shadow_ratio: tuple[float, float] = _default("shadow_ratio")
    shadow_min_blue_shift: float = _default("shadow_min_blue_shift")
    shadow_signature: bool = _default("shadow_signature")
    daylight_temperatures_k: tuple[float, float] = _default("daylight_temperatures_k")
    shadow_penumbra: bool = _default("shadow_penumbra")
    shadow_learn_spread: bool = _default("shadow_learn_spread")
    shadow_search: float = _default("shadow_search")
    shadow_shift_tolerance: float = _default("shadow_shift_tolerance")
    shadow_dark_tolerance: float = _default("shadow_dark_tolerance")
    shadow_signature_core_px: int = _default("shadow_signature_core_px")
    shadow_signature_rate: float = _default("shadow_signature_rate")
    shadow_sliver_share: float = _default("shadow_sliver_share")
    shadow_sliver_px: int = _default("shadow_sliver_px")
    shadow_island_share: float = _default("shadow_island_share")
    shadow_cost: float = _default("shadow_cost")
    shadow_slope: float = _default("shadow_slope")
    shadow_max_deviation: float = _default("shadow_max_deviation")
    dark_floor: float = _default("dark_floor")

    min_person_px: int = _default("min_person_px")
    foot_min_px: int = _default("foot_min_px")
    min_person_height_m: float = _default("min_person_height_m")

    def __post_init__(self) -> None:
        values = {f.name: _plain(getattr(self, f.name)) for f in fields(self)}
        problem = first_problem(values, SCHEMA)
        if problem is not None:
            raise ValueError(f"occlusion settings: {problem.path[0]} {problem.words}")
        # What one key's schema cannot say: relations between keys.
        if self.bg_rate * self.bg_update_bands >= 1.0:
            raise ValueError("occlusion settings: bg_rate * bg_update_bands must be < 1")
        if not self.shadow_ratio[0] < self.shadow_ratio[1]:
            raise ValueError("occlusion settings: shadow_ratio must be (lo, hi) with lo < hi")
        if self.f_constants is None:
            camera_constants(self.wavelengths_nm)  # validates R > G > B

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


def _plain(value):
    """A setting as JSON Schema sees it: tuples and arrays as lists, numpy scalars as numbers."""
    if isinstance(value, tuple | list | np.ndarray):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value
