"""A broadband camera under daylight spectra: the light model of the synthetic sequences.

The occlusion detector (shadow.py) assumes a narrow-band camera and Planckian (Wien)
illuminants. Sequences drawn with that same model cannot fail the way a real camera does, so
the synthetic sequence (synthetic.py) and the tests' held-out one
(tests/server/occlusion/heldout.py) draw their light with this module instead, which shares
none of those assumptions:

- **Sensitivities**: broad, overlapping curves over 380-720 nm (:func:`gaussian_sensitivities`),
  integrated over the spectrum, not sampled at one wavelength per channel.
- **Daylight** (:class:`SkyState`): the sun as an exact Planck spectrum (5778 K) through an
  atmosphere of Rayleigh scattering (``tau ~ lambda^-4.05``) and aerosol (Angstrom's law), and
  optionally a thin, spectrally flat cloud. What the atmosphere scatters out of the beam comes
  down as skylight, so the sky is bluer than the sun by physics, not by an assumed
  temperature, and a shadow (the direct component lost) has the colour those spectra give.
- **Surfaces** have smooth reflectance *spectra*: three coefficients (R, G, B) on a partition of
  unity over the spectrum (:data:`REFLECTANCE_BASIS`), so (g, g, g) is a flat grey and
  every coefficient in 0-1 is a physical reflectance. Under an illuminant the camera sees
  ``M @ a`` with ``M`` a full 3x3 matrix (:func:`camera_matrix`): a shadow's colour ratio
  depends on the surface too, as with a real camera, not on the illuminant alone.

Spectra are arrays over :data:`WAVELENGTHS_NM`, in arbitrary (consistent) radiometric units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

WAVELENGTHS_NM = np.arange(380.0, 721.0, 5.0)  # (n,) the integration grid
SUN_TEMPERATURE_K = 5778.0  # the sun's photosphere, as a black body
C2_M_K = 1.4388e-2  # second radiation constant, m K


def planck(wavelength_nm: np.ndarray, temperature_k: float) -> np.ndarray:
    """Exact Planck spectral radiance (arbitrary units) at ``wavelength_nm`` (any shape)."""
    lam = np.asarray(wavelength_nm, dtype=np.float64) * 1e-9
    return lam**-5.0 / np.expm1(C2_M_K / (lam * temperature_k))


def gaussian_sensitivities(peaks_nm, sigmas_nm, side_lobes=None,
                           wavelengths_nm: np.ndarray = WAVELENGTHS_NM) -> np.ndarray:
    """(3, n) channel sensitivities, one Gaussian per channel in the order given; a channel's
    ``side_lobes`` entry ``(peak_nm, sigma_nm, weight)`` adds a second, weaker Gaussian (the
    blue lobe of a real red channel), ``None`` none."""
    out = []
    for c, (p, s) in enumerate(zip(peaks_nm, sigmas_nm, strict=True)):
        curve = np.exp(-0.5 * ((wavelengths_nm - p) / s) ** 2)
        lobe = side_lobes[c] if side_lobes else None
        if lobe is not None:
            curve = curve + lobe[2] * np.exp(-0.5 * ((wavelengths_nm - lobe[0]) / lobe[1]) ** 2)
        out.append(curve)
    return np.array(out)


# The synthetic sequence's camera, RGB order: broad, overlapping, a red channel with a weak
# blue lobe (as a CMOS sensor behind its colour filter array and IR cut), peaks unlike the
# held-out camera's (455/540/600 nm, pure Gaussians) and unlike the detector's narrow-band
# wavelengths (610/540/465 nm).
SITE_CAMERA_RGB = gaussian_sensitivities((598.0, 532.0, 462.0), (36.0, 42.0, 28.0),
                                         ((445.0, 22.0, 0.06), None, None))


def _logistic(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-x))


# (3, n) smooth reflectance basis, RGB order, summing to 1 at every wavelength: a "blue" part
# falling across 490 nm, a "red" part rising across 585 nm, "green" the rest.
_B = _logistic(-(WAVELENGTHS_NM - 490.0) / 14.0)
_R = _logistic((WAVELENGTHS_NM - 585.0) / 14.0)
REFLECTANCE_BASIS = np.stack([_R, 1.0 - _R - _B, _B])


def reflectance_spectrum(rgb) -> np.ndarray:
    """(..., n) reflectance spectrum of (..., 3) RGB coefficients on :data:`REFLECTANCE_BASIS`."""
    return np.asarray(rgb, dtype=np.float64) @ REFLECTANCE_BASIS


def camera_matrix(illuminant: np.ndarray, sensitivities: np.ndarray = SITE_CAMERA_RGB
                  ) -> np.ndarray:
    """(3, 3) camera response to a surface of reflectance coefficients ``a`` (RGB) under
    ``illuminant`` (n,): ``rgb = M @ a`` with ``M[j, k] = sum(s_j E b_k)`` over the grid."""
    return (sensitivities * illuminant) @ REFLECTANCE_BASIS.T


def response(spectrum: np.ndarray, sensitivities: np.ndarray = SITE_CAMERA_RGB) -> np.ndarray:
    """(3,) camera response to light of ``spectrum`` (n,) reaching the sensor directly."""
    return sensitivities @ spectrum


def air_mass(elevation_deg: float) -> float:
    """Relative optical air mass toward the sun (Kasten & Young 1989)."""
    el = max(elevation_deg, 0.5)
    return 1.0 / (math.sin(math.radians(el)) + 0.50572 * (el + 6.07995) ** -1.6364)


@dataclass(frozen=True)
class SkyState:
    """The state of the sky over a site: its atmosphere and an optional thin cloud.

    Attributes
    ----------
    name : for reports
    aerosol_depth_550 : aerosol optical depth at 550 nm (0.05 very clear, 0.3 hazy)
    angstrom_alpha : Angstrom exponent of the aerosol's optical depth (about 1.3)
    cloud_transmission : share of the direct beam a thin cloud lets through (1: no cloud);
        the rest comes down as diffuse light of the beam's colour (grey scattering)
    """

    name: str
    aerosol_depth_550: float
    angstrom_alpha: float = 1.3
    cloud_transmission: float = 1.0

    def irradiance(self, sun_elevation_deg: float) -> tuple[np.ndarray, np.ndarray]:
        """``(direct, diffuse)`` (n,) spectral irradiance on the horizontal ground: the sun's
        beam and the skylight. A simple single-scattering model: the light scattered out of
        the beam comes down as sky light, half of the Rayleigh part and 75 % of the aerosol
        part (forward scattering); the scattered light's own path is not attenuated."""
        lam_um = WAVELENGTHS_NM * 1e-3
        m = air_mass(sun_elevation_deg)
        sin_el = math.sin(math.radians(max(sun_elevation_deg, 0.5)))
        top = planck(WAVELENGTHS_NM, SUN_TEMPERATURE_K)
        tau_r = 0.0088 * lam_um**-4.05  # Rayleigh, sea level (0.097 at 550 nm)
        tau_a = self.aerosol_depth_550 * (lam_um / 0.55) ** -self.angstrom_alpha
        beam = top * np.exp(-(tau_r + tau_a) * m)
        scattered = top * (0.5 * -np.expm1(-tau_r * m) + 0.75 * -np.expm1(-tau_a * m))
        direct = self.cloud_transmission * beam * sin_el
        # A thin cloud scatters the beam it stops (80 % of it downward), whatever its colour.
        diffuse = (scattered + 0.8 * (1.0 - self.cloud_transmission) * beam) * sin_el
        return direct, diffuse


SKY_STATES: dict[str, SkyState] = {
    "clear": SkyState("clear", aerosol_depth_550=0.08),
    "hazy": SkyState("hazy", aerosol_depth_550=0.25, angstrom_alpha=1.0),
    # a thin veil over the sun: paler, nearly neutral shadows
    "thin cloud": SkyState("thin cloud", aerosol_depth_550=0.15, cloud_transmission=0.45),
}
