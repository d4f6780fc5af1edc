"""daylit.aureole against answers it does not compute itself: a closed-form integral, a
quadrature done another way (over an equirectangular map's pixels), and the CIE standard
clear sky of daylit.sky (whose indicatrix holds the same circumsolar term)."""

import math

import numpy as np
import pytest

from daylit import aureole
from daylit.envmap import pixel_directions
from daylit.sky import CIE_SKY_TYPES, CIESky, direction_from_azimuth_elevation


def closed_form_zenith(d: float) -> float:
    """int k(chi) cos(chi) dOmega over chi < 90 deg, sun at the zenith, no gradation:
    2 pi / (1 - F) [(1 + F) / (d^2 + 4) - F / 2], F = exp(d pi / 2), from
    int_0^{pi/2} exp(d x) sin x cos x dx = (1 + F) / (d^2 + 4)."""
    f = math.exp(d * math.pi / 2)
    return 2 * math.pi / (1 - f) * ((1 + f) / (d * d + 4) - f / 2)


@pytest.mark.parametrize("d", [-1.5, -3.0, -4.5])
def test_irradiance_of_a_zenith_sun_against_the_closed_form(d):
    shape = aureole.AureoleShape(d, (0.0, -1.0))  # a = 0: no gradation
    vector = aureole.irradiance_vector([0.0, 1.0, 0.0], shape)
    assert vector[1] == pytest.approx(closed_form_zenith(d), rel=1e-4)
    assert abs(vector[0]) < 1e-9 and abs(vector[2]) < 1e-9
    assert aureole.normal_irradiance([0.0, 1.0, 0.0], 2.0, shape) == pytest.approx(
        2.0 * closed_form_zenith(d), rel=1e-4)


@pytest.mark.parametrize("az_el", [(237.0, 26.6), (133.4, 44.7), (90.0, 8.0)])
def test_irradiance_against_an_equirectangular_quadrature(az_el):
    # The horizon cuts the aureole and the gradation tilts it: the polar grid about the sun
    # against a sum over a 1440 x 720 map's pixel centres.
    s = direction_from_azimuth_elevation(*az_el)
    shape = aureole.AureoleShape()
    dirs, sr = pixel_directions(720)
    by_pixels = np.einsum("hw,hwc->c", aureole.kernel(dirs, s, shape) * sr, dirs)
    vector = aureole.irradiance_vector(s, shape)
    assert np.allclose(vector, by_pixels, rtol=0, atol=2e-3 * np.linalg.norm(by_pixels))
    # The directional light gives the open ground the aureole's own horizontal irradiance.
    assert aureole.normal_irradiance(s, 1.0, shape) * s[1] == pytest.approx(by_pixels[1],
                                                                             rel=2e-3)


def cie_map(az, el, sky_type=12, height=360, zenith=30.0):
    """A CIE general sky (type 12: the standard clear sky) as a grey equirectangular map, from
    daylit.sky."""
    sky = CIESky(sky_type=sky_type, sun_azimuth_deg=az, sun_elevation_deg=el)
    dirs, _ = pixel_directions(height)
    rel = sky.relative_luminance(dirs.reshape(-1, 3)).reshape(dirs.shape[:2])
    rel[dirs[..., 1] <= 0.0] = 0.0
    return zenith * np.repeat(rel[..., None], 3, axis=2), sky


@pytest.mark.parametrize("sky_type,az_el", [(12, (237.0, 26.6)), (12, (133.4, 44.7)),
                                             (12, (200.0, 60.0)), (7, (150.0, 35.0))])
def test_fit_recovers_a_cie_skys_circumsolar_term(sky_type, az_el):
    zenith = 30.0
    image, sky = cie_map(*az_el, sky_type=sky_type, zenith=zenith)
    a, b, c, d, e = CIE_SKY_TYPES[sky_type]
    z_sun = math.radians(90.0 - az_el[1])
    f_sun = 1 + c * (math.exp(d * z_sun) - math.exp(d * math.pi / 2)) + e * math.cos(z_sun) ** 2
    phi_sun = 1 + a * math.exp(b / math.cos(z_sun))
    phi_zenith = 1 + a * math.exp(b)
    # The CIE term c (exp(d chi) - exp(d pi/2)) phi(Z) / (f(Z_s) phi(0)) at the sun's centre.
    want = zenith * c * (1 - math.exp(d * math.pi / 2)) * phi_sun / (f_sun * phi_zenith)
    s = direction_from_azimuth_elevation(*az_el)
    got = aureole.fit(image, s, [aureole.AureoleShape(d, (a, b))])
    assert got.amplitude == pytest.approx(np.full(3, want), rel=1e-6)
    assert got.rms_rel < 1e-6
    # The shape fitted on the grid finds the sky's own (clear: d = -3, a = -1, b = -0.32;
    # type 7: d = -2.5, no gradation).
    found = aureole.fit(image, s, aureole.shape_grid()).shape
    assert found.falloff == pytest.approx(d)
    assert found.gradation[0] == a and (a == 0 or found.gradation[1] == pytest.approx(b))
    # Subtracted, what is left within 90 degrees of the sun is the CIE sky without its term:
    # (1 + e cos^2 chi) phi(Z) / (f(Z_s) phi(0)) times the zenith radiance.
    rest = aureole.subtract(image, s, got.amplitude, got.shape)
    dirs, _ = pixel_directions(image.shape[0])
    chi = np.arccos(np.clip(dirs @ s, -1, 1))
    keep = (chi < np.pi / 2 - 0.01) & (dirs[..., 1] > 0.01)
    phi = 1 + a * np.exp(b / dirs[..., 1][keep])
    without = zenith * (1 + e * np.cos(chi[keep]) ** 2) * phi / (f_sun * phi_zenith)
    assert np.allclose(rest[keep][:, 1], without, rtol=1e-6)
    assert np.all(aureole.overshoot(image, s, got.amplitude, got.shape) < 1e-9)


def test_no_aureole_below_the_horizon_or_beyond_90_degrees():
    s = direction_from_azimuth_elevation(180.0, 5.0)
    dirs = direction_from_azimuth_elevation([180.0, 180.0, 0.0, 90.0], [-5.0, 40.0, 5.0, 30.0])
    k = aureole.kernel(dirs, s)
    assert k[0] == 0.0 and k[2] == 0.0  # below the horizon; 170 degrees away
    assert k[1] > 0.0 and k[3] > 0.0
    assert aureole.kernel(s[None], s)[0] == pytest.approx(1.0)
