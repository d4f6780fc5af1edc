"""The sun's aureole (circumsolar glow) as a model: its radiance, its irradiance, its fit.

Without its disc a clear sky is brightest in the sun's aureole, whose soft shadows move with
the sun and set the rank of the basis stacks (docs/benchmarks.md, "The aureole drawn
apart"). This module holds the one function the server would subtract from a measured sky,
the bake's test skies would leave out, and the client and the oracle would draw as a
directional light (docs/sun.md, "The aureole"). It is the circumsolar term of the CIE
general sky's indicatrix (ISO 15469), the same form as Perez's ``c exp(d chi)``, times the
CIE gradation:

    L_a(w) = A * k(chi) * phi(Z) / phi(Z_s)          above the horizon, chi < 90 deg
    k(chi) = (exp(d chi) - exp(d pi/2)) / (1 - exp(d pi/2))    (k(0) = 1, k(90 deg) = 0)
    phi(Z) = 1 + a exp(b / cos Z)

with ``chi`` the angle between ``w`` and the sun's centre, ``Z`` the zenith angle of ``w``
and ``Z_s`` the sun's. ``A`` (W/(m^2 sr), per RGB channel) is the aureole's radiance at the
sun's centre, extrapolated (the disc itself is not part of it); ``d`` (1/rad) its fall-off
(CIE clear skies -3: e-fold every 19 degrees); ``(a, b)`` the gradation (CIE clear sky
``(-1, -0.32)``; ``a = 0`` for none). Zero below the horizon (the open ground hides it) and
beyond 90 degrees from the sun.

Directions follow docs/architecture.md: site frame +X east, +Y up, -Z north, unit vectors.
Equirectangular maps are daylit's (daylit/envmap.py): ``(H, 2H, 3)``, row 0 at the zenith,
column 0 at north, azimuth growing toward east, linear radiance in W/(m^2 sr).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from daylit.envmap import pixel_directions
from daylit.spherical import normalize

CIE_CLEAR_FALLOFF = -3.0  # d, 1/rad (CIE types 11-14)
CIE_CLEAR_GRADATION = (-1.0, -0.32)  # (a, b), CIE type 12
FIT_CHI_DEG = (2.0, 45.0)  # the ring of sky around the sun the fit reads, degrees
FIT_MIN_ELEVATION_DEG = 10.0  # the fit reads no pixel lower (haze, ground glare, obstacles)


@dataclass(frozen=True)
class AureoleShape:
    """The aureole's shape: fall-off ``d`` (1/rad, negative) and gradation ``(a, b)``."""

    falloff: float = CIE_CLEAR_FALLOFF
    gradation: tuple[float, float] = CIE_CLEAR_GRADATION


def _unit(v) -> np.ndarray:
    return normalize(np.asarray(v, dtype=np.float64))


def _phi(cos_z, gradation) -> np.ndarray:
    a, b = gradation
    return 1.0 + a * np.exp(b / np.clip(cos_z, 1e-6, 1.0))


def kernel(dirs, sun_dir, shape: AureoleShape = AureoleShape()) -> np.ndarray:
    """``k(chi) phi(Z) / phi(Z_s)`` at unit directions ``dirs`` (..., 3): the aureole's
    radiance per unit ``A``, shape ``(...)``, dimensionless; 0 below the horizon and beyond
    90 degrees from the sun."""
    dirs = np.asarray(dirs, dtype=np.float64)
    s = _unit(sun_dir)
    chi = np.arccos(np.clip(dirs @ s, -1.0, 1.0))
    d = shape.falloff
    floor = np.exp(d * np.pi / 2)
    k = np.where(chi < np.pi / 2, (np.exp(d * chi) - floor) / (1.0 - floor), 0.0)
    g = _phi(dirs[..., 1], shape.gradation) / _phi(max(s[1], 0.0), shape.gradation)
    return np.where(dirs[..., 1] > 0.0, k * g, 0.0)


def radiance(dirs, sun_dir, amplitude, shape: AureoleShape = AureoleShape()) -> np.ndarray:
    """The aureole's radiance ``L_a`` at ``dirs`` (..., 3), W/(m^2 sr): ``(..., 3)`` for an
    RGB ``amplitude`` (its radiance at the sun's centre), ``(...)`` for a number."""
    k = kernel(dirs, sun_dir, shape)
    amplitude = np.asarray(amplitude, dtype=np.float64)
    return k[..., None] * amplitude if amplitude.ndim else k * amplitude


def _sun_frame(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    helper = np.array([0.0, 1.0, 0.0]) if abs(s[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    t1 = np.cross(s, helper)
    t1 /= np.linalg.norm(t1)
    return t1, np.cross(s, t1)


def quadrature(sun_dir, steps: int = 360) -> tuple[np.ndarray, np.ndarray]:
    """Directions (n, 3) and solid angles (n,) sr of a grid in polar coordinates about the
    sun (``chi`` in [0, 90] degrees in ``steps`` rings, ``2 steps`` azimuths), where the
    aureole lives: the peak at the sun is resolved however small ``d`` is."""
    s = _unit(sun_dir)
    t1, t2 = _sun_frame(s)
    edges = np.linspace(0.0, np.pi / 2, steps + 1)
    chi = 0.5 * (edges[:-1] + edges[1:])
    ring_sr = 2.0 * np.pi * (np.cos(edges[:-1]) - np.cos(edges[1:]))
    psi = (np.arange(2 * steps) + 0.5) * np.pi / steps
    C, P = np.meshgrid(chi, psi, indexing="ij")
    dirs = (np.cos(C)[..., None] * s + (np.sin(C) * np.cos(P))[..., None] * t1
            + (np.sin(C) * np.sin(P))[..., None] * t2)
    sr = np.repeat(ring_sr / (2 * steps), 2 * steps)
    return dirs.reshape(-1, 3), sr


def irradiance_vector(sun_dir, shape: AureoleShape = AureoleShape(), steps: int = 360
                      ) -> np.ndarray:
    """``int L_a w dOmega`` over the sky per unit ``A`` (3,), sr: its component along a unit
    normal ``n`` is the aureole's irradiance on a surface facing ``n`` that sees all of it
    (no caster, and ``n . w >= 0`` over the aureole)."""
    dirs, sr = quadrature(sun_dir, steps)
    return (kernel(dirs, sun_dir, shape) * sr) @ dirs


def normal_irradiance(sun_dir, amplitude, shape: AureoleShape = AureoleShape()) -> np.ndarray:
    """The normal irradiance (W/m^2, like ``amplitude``) of the directional light from the
    sun's direction that stands for the aureole: the one that gives the open ground the
    aureole's own horizontal irradiance, ``(int L_a w_y dOmega) / s_y`` (the aureole's part
    below the horizon is hidden and the gradation tilts it; the projection on ``s`` leaves the
    ground 5-7 % too bright on bench_fidelity's clear and intermediate skies). ``nan`` for a
    sun at or below the horizon."""
    s = _unit(sun_dir)
    if s[1] <= 0.0:
        return np.full(np.shape(amplitude), np.nan)
    return irradiance_vector(s, shape)[1] / s[1] * np.asarray(amplitude, dtype=np.float64)


@dataclass
class AureoleFit:
    """A fitted aureole: amplitude ``A`` (3,) W/(m^2 sr), its shape, the background's two
    coefficients per channel (2, 3), and the fit's RMS residual relative to the mean radiance
    of the pixels it read."""

    amplitude: np.ndarray
    shape: AureoleShape
    background: np.ndarray
    rms_rel: float


GRID_FALLOFFS = tuple(np.round(np.arange(-6.0, -0.95, 0.1), 2))  # d, 1/rad
# b every 0.05 from -1 to -0.1, and the CIE clear sky's -0.32.
GRID_GRADATION_B = tuple(sorted(set(np.round(np.arange(-1.0, -0.09, 0.05), 2)) | {-0.32}))


def shape_grid(falloffs=GRID_FALLOFFS, gradation_b=GRID_GRADATION_B) -> list[AureoleShape]:
    """Candidate shapes for :func:`fit`: every fall-off ``d`` with every gradation ``b`` at
    ``a = -1`` (the CIE clear and intermediate skies: ``b`` -0.15 to -0.55; Perez's gendaylit
    skies about -0.2 to -0.6) and with no gradation (``a = 0``: CIE types 5-8)."""
    return [AureoleShape(float(d), (-1.0, float(b))) for d in falloffs for b in gradation_b] + [
        AureoleShape(float(d), (0.0, -1.0)) for d in falloffs]


def fit(image, sun_dir, shapes=(AureoleShape(),), chi_deg=FIT_CHI_DEG,
        min_elevation_deg: float = FIT_MIN_ELEVATION_DEG) -> AureoleFit:
    """:func:`fit_samples` over every pixel of a daylit equirectangular sky map."""
    image = np.asarray(image, dtype=np.float64)
    dirs, sr = pixel_directions(image.shape[0])
    return fit_samples(dirs.reshape(-1, 3), image.reshape(-1, 3), sr.reshape(-1), sun_dir,
                       shapes, chi_deg, min_elevation_deg)


def fit_samples(dirs, radiance_rgb, solid_angle_sr, sun_dir, shapes=(AureoleShape(),),
                chi_deg=FIT_CHI_DEG, min_elevation_deg: float = FIT_MIN_ELEVATION_DEG
                ) -> AureoleFit:
    """Fit ``A`` from sky samples (a map's pixels, a camera's unclipped pixels): unit
    directions ``dirs`` (m, 3), linear radiance ``radiance_rgb`` (m, 3) W/(m^2 sr) and each
    sample's solid angle (m,) sr. Only samples between ``chi_deg[0]`` and ``chi_deg[1]``
    degrees from the sun and at least ``min_elevation_deg`` up count (the disc and the pixels
    the server fills in for it left out; near the horizon a sky is hazy and a camera sees
    obstacles); leave clipped pixels out of the samples.

    Per channel, least squares weighted by solid angle of
    ``L = A k phi/phi_s + B0 phi/phi_s + B1 phi/phi_s cos^2 chi`` (the rest of a CIE
    indicatrix, ``1 + e cos^2 chi``, as background), ``A`` kept >= 0, for each of ``shapes``
    (e.g. :func:`shape_grid`); the shape with the least residual (green channel) is kept.
    """
    ring = Ring.of(dirs, radiance_rgb, solid_angle_sr, sun_dir, chi_deg, min_elevation_deg)
    d, w, y, s = ring.dirs, ring.weight, ring.values, ring.sun
    best = None
    for shape in shapes:
        basis = fit_basis(d, s, shape)
        coef = np.linalg.lstsq(basis * w[:, None], y * w[:, None], rcond=None)[0]  # (3, 3)
        for c in np.flatnonzero(coef[0] < 0.0):  # no aureole in a channel: refit without it
            sub = np.linalg.lstsq(basis[:, 1:] * w[:, None], y[:, c] * w, rcond=None)[0]
            coef[:, c] = [0.0, *sub]
        rel = ring.rms_rel(basis @ coef[:, 1])
        if best is None or rel < best.rms_rel:
            best = AureoleFit(coef[0], shape, coef[1:], rel)
    return best


@dataclass
class Ring:
    """The sky samples a fit reads: those between ``chi_deg[0]`` and ``chi_deg[1]`` degrees
    from the sun and above ``min_elevation_deg``. ``dirs`` (m, 3), ``values`` (m, 3)
    W/(m^2 sr), ``weight`` (m,) the square roots of their solid angles, ``sun`` the unit sun
    direction, ``mean`` the green radiance's solid-angle mean."""

    dirs: np.ndarray
    values: np.ndarray
    weight: np.ndarray
    sun: np.ndarray
    mean: float

    @classmethod
    def of(cls, dirs, radiance_rgb, solid_angle_sr, sun_dir, chi_deg=FIT_CHI_DEG,
           min_elevation_deg: float = FIT_MIN_ELEVATION_DEG) -> Ring:
        dirs = np.asarray(dirs, dtype=np.float64)
        values = np.asarray(radiance_rgb, dtype=np.float64)
        sr = np.asarray(solid_angle_sr, dtype=np.float64)
        s = _unit(sun_dir)
        chi = np.degrees(np.arccos(np.clip(dirs @ s, -1.0, 1.0)))
        keep = (chi >= chi_deg[0]) & (chi <= chi_deg[1])
        keep &= dirs[:, 1] > max(np.sin(np.radians(min_elevation_deg)), 0.0)
        if keep.sum() < 16:
            raise ValueError(
                f"too few sky samples {chi_deg} degrees from the sun to fit its aureole")
        y = values[keep]
        mean = float(np.sum(y[:, 1] * sr[keep]) / np.sum(sr[keep]))
        return cls(dirs[keep], y, np.sqrt(sr[keep]), s, mean)

    def rms_rel(self, model_green: np.ndarray) -> float:
        """A model's (m,) solid-angle weighted RMS residual in green, of the ring's mean."""
        resid = (model_green - self.values[:, 1]) * self.weight
        return float(np.sqrt(np.sum(resid**2) / np.sum(self.weight**2))) / max(self.mean, 1e-12)


def fit_basis(dirs, sun_dir, shape: AureoleShape) -> np.ndarray:
    """(m, 3) the fit's columns at unit directions ``dirs`` (m, 3): the aureole's kernel
    ``k``, and the background ``phi/phi_s`` and ``phi/phi_s cos^2 chi`` (``sun_dir`` unit)."""
    g = _phi(dirs[:, 1], shape.gradation) / _phi(max(sun_dir[1], 0.0), shape.gradation)
    return np.stack([kernel(dirs, sun_dir, shape), g, g * (dirs @ sun_dir) ** 2], axis=1)


def subtract(image, sun_dir, amplitude, shape: AureoleShape = AureoleShape()) -> np.ndarray:
    """The sky map without the aureole: ``max(0, image - L_a)`` at every pixel centre (the
    same shape; a sky map holds no negative radiance, so where the model overshoots the
    sky the overshoot is lost: :func:`overshoot` says how much)."""
    return np.maximum(0.0, image - _model_map(image, sun_dir, amplitude, shape))


def _model_map(image, sun_dir, amplitude, shape) -> np.ndarray:
    image = np.asarray(image, dtype=np.float64)
    dirs, _ = pixel_directions(image.shape[0])
    return radiance(dirs, sun_dir, np.broadcast_to(amplitude, (3,)), shape)


def overshoot(image, sun_dir, amplitude, shape: AureoleShape = AureoleShape()) -> np.ndarray:
    """The horizontal irradiance (3,) W/m^2 of where the model exceeds the sky map, which
    :func:`subtract` clips away (0 for a model that stays under the sky)."""
    image = np.asarray(image, dtype=np.float64)
    dirs, sr = pixel_directions(image.shape[0])
    over = np.maximum(0.0, _model_map(image, sun_dir, amplitude, shape) - image)
    return np.einsum("hwc,hw->c", over, np.clip(dirs[..., 1], 0.0, None) * sr)
