"""The server's rule for splitting a measured sky into the aureole drawn apart and the rest.

The client would draw the sun's aureole apart (docs/sun.md, "The aureole": its own irradiance
per normal times its own wide visibility) and relight only the rest of the sky through basis
stacks fitted on skies without the CIE circumsolar term. Those bases cannot draw an aureole
at all (a clear sky sent with its aureole in is 2.5-4.2 % RMS off through them), so the
server must take *some* aureole out of every sky with a sun, also where the model does not
describe the sky (clouds near the sun). Whatever it takes out is drawn back by the client at
the directions it came from, so the split need not be a true aureole: it has to be light the
sky really has there (the model nowhere above the sky: the rest stays non-negative, no light
lost to clipping) and it has to leave a rest the reduced bases can draw (no peak left at the
sun), with a shape the client's soft shadow was measured for (the clear skies' range).

The rule (:func:`split_samples`, :func:`split`):

1. Fit the model over the whole shape grid (:func:`daylit.aureole.fit_samples`). **Accept**
   it when its RMS residual is at most ``ACCEPT_RMS_REL`` of the ring's mean radiance (clear
   skies: under 1 %) and it overshoots the sky by at most ``ACCEPT_OVERSHOOT`` of the sky's
   horizontal irradiance (read over the samples above ``min_elevation_deg``).
2. Else (**refused**: clouds near the sun, a shape at the grid's edge, a model above the
   sky): the *held* fit. Over the clear skies' shapes only (:func:`held_grid`), per channel
   the least-squares amplitude clipped to ``[0, A_env]``, ``A_env`` the largest amplitude whose
   model stays under every sample the fit may read beyond the disc (:func:`envelope`); the
   background refitted with that amplitude; the shape with the least residual kept. The
   rest is non-negative at every sample read, by construction.

Directions and maps as in :mod:`daylit.aureole`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from daylit import aureole
from daylit.aureole import AureoleFit, AureoleShape, kernel
from daylit.envmap import pixel_directions
from daylit.spherical import normalize

ACCEPT_RMS_REL = 0.03  # the free fit's residual, of the ring's mean radiance
ACCEPT_OVERSHOOT = 0.002  # the free model above the sky, of the sky's horizontal irradiance
# The clear skies' shapes: CIE types 7 and 10-15 (d -2.5 to -3, b -0.15 to -0.55) and the
# Perez skies the grid was measured on (d -3.1 to -4.0, b -0.23 to -0.54).
HELD_FALLOFFS = tuple(np.round(np.arange(-4.5, -2.45, 0.1), 2))  # d, 1/rad
# b every 0.05 from -0.6 to -0.15, and the CIE clear sky's -0.32 (as aureole.GRID_GRADATION_B).
HELD_GRADATION_B = tuple(sorted(set(np.round(np.arange(-0.6, -0.14, 0.05), 2)) | {-0.32}))


def held_grid(falloffs=HELD_FALLOFFS, gradation_b=HELD_GRADATION_B) -> list[AureoleShape]:
    """The clear skies' shapes (``a = -1`` with ``b`` in ``gradation_b``, or no gradation),
    to which a refused fit is held."""
    return aureole.shape_grid(falloffs, gradation_b)


@dataclass
class Split:
    """What the server would send: ``fit`` the aureole drawn apart (amplitude 0: none),
    whether the free fit was ``accepted``, the free fit's residual and overshoot (fractions,
    as in the rule), and ``reason`` in words."""

    fit: AureoleFit
    accepted: bool
    free_rms_rel: float
    free_overshoot_rel: float
    reason: str


def _select(dirs, sun_dir, chi_deg, min_elevation_deg):
    s = normalize(np.asarray(sun_dir, dtype=np.float64))
    chi = np.degrees(np.arccos(np.clip(dirs @ s, -1.0, 1.0)))
    keep = (chi >= chi_deg[0]) & (chi < 90.0)
    keep &= dirs[:, 1] > max(np.sin(np.radians(min_elevation_deg)), 0.0)
    return s, keep


def envelope(dirs, radiance_rgb, sun_dir, shape: AureoleShape,
             chi_min_deg: float = aureole.FIT_CHI_DEG[0],
             min_elevation_deg: float = aureole.FIT_MIN_ELEVATION_DEG) -> np.ndarray:
    """``A_env`` (3,) W/(m^2 sr): per channel the largest amplitude whose model ``A k`` is
    at most the sky's radiance at every sample from ``chi_min_deg`` (the disc and its fill
    left out) to 90 degrees from the sun and above ``min_elevation_deg``; ``min(radiance /
    k)`` over the samples where ``k > 0``. Samples (m, 3) as in
    :func:`daylit.aureole.fit_samples`; inf for a channel no sample bounds."""
    dirs = np.asarray(dirs, dtype=np.float64)
    values = np.asarray(radiance_rgb, dtype=np.float64)
    s, keep = _select(dirs, sun_dir, (chi_min_deg, 90.0), min_elevation_deg)
    k = kernel(dirs[keep], s, shape)
    strong = k > 0.0
    if not strong.any():
        return np.full(3, np.inf)
    return np.min(np.maximum(values[keep][strong], 0.0) / k[strong, None], axis=0)


def overshoot_rel(dirs, radiance_rgb, solid_angle_sr, sun_dir, fit: AureoleFit,
                  min_elevation_deg: float = aureole.FIT_MIN_ELEVATION_DEG) -> float:
    """Where the model exceeds the sky, its horizontal irradiance over the sky's (green),
    over the samples above ``min_elevation_deg`` and at least 2 degrees from the sun."""
    dirs = np.asarray(dirs, dtype=np.float64)
    y = np.asarray(radiance_rgb, dtype=np.float64)[:, 1]
    sr = np.asarray(solid_angle_sr, dtype=np.float64)
    s, keep = _select(dirs, sun_dir, (aureole.FIT_CHI_DEG[0], 90.0), min_elevation_deg)
    up = dirs[:, 1] > max(np.sin(np.radians(min_elevation_deg)), 0.0)
    weight = np.clip(dirs[:, 1], 0.0, None) * sr
    model = kernel(dirs[keep], s, fit.shape) * fit.amplitude[1]
    over = float(np.sum(np.maximum(model - y[keep], 0.0) * weight[keep]))
    return over / max(float(np.sum(np.maximum(y[up], 0.0) * weight[up])), 1e-12)


def held_fit(dirs, radiance_rgb, solid_angle_sr, sun_dir, shapes=None,
             chi_deg=aureole.FIT_CHI_DEG,
             min_elevation_deg: float = aureole.FIT_MIN_ELEVATION_DEG) -> AureoleFit:
    """The refused sky's fit: over ``shapes`` (default :func:`held_grid`), per channel the
    model of :func:`daylit.aureole.fit_samples` with its amplitude clipped to ``[0, A_env]``
    (:func:`envelope`) and the background refitted with it; the least residual (green) kept.
    Its model is nowhere above the samples :func:`envelope` reads."""
    dirs = np.asarray(dirs, dtype=np.float64)
    values = np.asarray(radiance_rgb, dtype=np.float64)
    shapes = held_grid() if shapes is None else shapes
    ring = aureole.Ring.of(dirs, values, solid_angle_sr, sun_dir, chi_deg, min_elevation_deg)
    d, w, y, s = ring.dirs, ring.weight, ring.values, ring.sun
    best = None
    for shape in shapes:
        basis = aureole.fit_basis(d, s, shape)
        k, background = basis[:, 0], basis[:, 1:]
        coef = np.linalg.lstsq(basis * w[:, None], y * w[:, None], rcond=None)[0]  # (3, 3)
        amplitude = np.clip(coef[0], 0.0, envelope(dirs, values, s, shape, chi_deg[0],
                                                   min_elevation_deg))
        rest = y - np.outer(k, amplitude)
        bg = np.linalg.lstsq(background * w[:, None], rest * w[:, None], rcond=None)[0]
        rel = ring.rms_rel(background @ bg[:, 1] + k * amplitude[1])
        if best is None or rel < best.rms_rel:
            best = AureoleFit(amplitude, shape, bg, rel)
    return best


def split_samples(dirs, radiance_rgb, solid_angle_sr, sun_dir, shapes=None,
                  min_elevation_deg: float = aureole.FIT_MIN_ELEVATION_DEG) -> Split:
    """The rule (module docstring) on sky samples: unit directions (m, 3), linear radiance
    (m, 3) W/(m^2 sr), solid angles (m,) sr (clipped pixels left out). ``shapes``: the free
    fit's grid (default :func:`daylit.aureole.shape_grid`)."""
    shapes = aureole.shape_grid() if shapes is None else shapes
    free = aureole.fit_samples(dirs, radiance_rgb, solid_angle_sr, sun_dir, shapes,
                               min_elevation_deg=min_elevation_deg)
    over = overshoot_rel(dirs, radiance_rgb, solid_angle_sr, sun_dir, free, min_elevation_deg)
    if free.rms_rel <= ACCEPT_RMS_REL and over <= ACCEPT_OVERSHOOT:
        return Split(free, True, free.rms_rel, over, "accepted")
    why = []
    if free.rms_rel > ACCEPT_RMS_REL:
        why.append(f"residual {100 * free.rms_rel:.1f} %")
    if over > ACCEPT_OVERSHOOT:
        why.append(f"overshoot {100 * over:.1f} % of the sky's E_h")
    held = held_fit(dirs, radiance_rgb, solid_angle_sr, sun_dir,
                    min_elevation_deg=min_elevation_deg)
    return Split(held, False, free.rms_rel, over, "refused (" + ", ".join(why) + "): held fit")


def split(image, sun_dir, shapes=None,
          min_elevation_deg: float = aureole.FIT_MIN_ELEVATION_DEG) -> Split:
    """:func:`split_samples` over every pixel of a daylit equirectangular sky map (H, 2H, 3);
    the rest is then ``aureole.subtract(image, sun_dir, split.fit.amplitude,
    split.fit.shape)``."""
    image = np.asarray(image, dtype=np.float64)
    dirs, sr = pixel_directions(image.shape[0])
    return split_samples(dirs.reshape(-1, 3), image.reshape(-1, 3), sr.reshape(-1), sun_dir,
                         shapes, min_elevation_deg)
