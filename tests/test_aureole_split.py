"""daylit.aureole_split, the server's rule for the aureole drawn apart, against skies built in
the test with a known aureole: CIE general skies (daylit.sky, whose indicatrix holds the same
circumsolar term, amplitude in closed form), with clouds drawn by another model (the
simulated sky's drifting deck, server.clouds.CloudLayer, lit grey with a cos^16 forward glow,
not the CIE term) or a dark cloud whose bound on the amplitude is known."""

import math

import numpy as np
import pytest

from daylit import aureole, aureole_split
from daylit.envmap import pixel_directions
from daylit.sky import CIE_SKY_TYPES, CIESky, direction_from_azimuth_elevation
from server.clouds import CloudLayer

HEIGHT = 180
ZENITH = 30.0  # W/(m^2 sr)


def cie_sky(az, el, sky_type=12):
    """A grey CIE general sky map (HEIGHT, 2 HEIGHT, 3), its pixel directions and solid
    angles, and its circumsolar term's amplitude at the sun's centre in closed form."""
    sky = CIESky(sky_type=sky_type, sun_azimuth_deg=az, sun_elevation_deg=el)
    dirs, sr = pixel_directions(HEIGHT)
    rel = sky.relative_luminance(dirs.reshape(-1, 3)).reshape(dirs.shape[:2])
    rel[dirs[..., 1] <= 0.0] = 0.0
    a, b, c, d, e = CIE_SKY_TYPES[sky_type]
    z = math.radians(90.0 - el)
    f_sun = 1 + c * (math.exp(d * z) - math.exp(d * math.pi / 2)) + e * math.cos(z) ** 2
    amplitude = ZENITH * c * (1 - math.exp(d * math.pi / 2)) * (
        1 + a * math.exp(b / math.cos(z))) / (f_sun * (1 + a * math.exp(b)))
    return ZENITH * np.repeat(rel[..., None], 3, axis=2), dirs, sr, amplitude


def read_by_the_rule(dirs, s):
    """The pixels the rule keeps the model under: 2 to 90 degrees from the sun, 10 up."""
    chi = np.degrees(np.arccos(np.clip(dirs @ s, -1.0, 1.0)))
    return (chi >= 2.0) & (chi < 90.0) & (dirs[..., 1] > math.sin(math.radians(10.0)))


@pytest.mark.parametrize("sky_type,az_el", [(12, (150.0, 40.0)), (12, (237.0, 26.6)),
                                             (7, (120.0, 55.0))])
def test_a_clear_sky_is_accepted_with_its_own_aureole(sky_type, az_el):
    image, dirs, _, amplitude = cie_sky(*az_el, sky_type)
    s = direction_from_azimuth_elevation(*az_el)
    split = aureole_split.split(image, s)
    assert split.accepted and split.reason == "accepted"
    assert split.fit.amplitude == pytest.approx(np.full(3, amplitude), rel=1e-6)
    assert split.free_overshoot_rel < 1e-9
    # The held fit (the clear skies' shapes) finds the same aureole on a clear sky.
    flat = (dirs.reshape(-1, 3), image.reshape(-1, 3), pixel_directions(HEIGHT)[1].reshape(-1))
    held = aureole_split.held_fit(*flat, s)
    assert held.amplitude == pytest.approx(np.full(3, amplitude), rel=1e-6)


@pytest.mark.parametrize("cover,seed,time_s", [(0.3, 0, 0.0), (0.3, 1, 600.0), (0.5, 1, 0.0),
                                               (0.5, 2, 0.0), (0.7, 0, 600.0)])
def test_clouds_near_the_sun_are_refused_and_the_rest_stays_non_negative(cover, seed, time_s):
    az, el = 150.0, 40.0
    clear, dirs, sr, amplitude = cie_sky(az, el)
    s = direction_from_azimuth_elevation(az, el)
    tau = CloudLayer(cover=cover, seed=seed).opacity(dirs.reshape(-1, 3), time_s)
    tau = tau.reshape(dirs.shape[:2])[..., None]
    chi = np.arccos(np.clip(dirs @ s, -1.0, 1.0))
    cloud = 20.0 * (1.0 + 6.0 * np.clip(np.cos(chi), 0.0, 1.0) ** 16)  # not the CIE term
    image = (1.0 - tau) * clear + tau * cloud[..., None]
    image[dirs[..., 1] <= 0.0] = 0.0
    split = aureole_split.split(image, s)
    assert not split.accepted and split.free_rms_rel > aureole_split.ACCEPT_RMS_REL
    shape = split.fit.shape
    assert min(aureole_split.HELD_FALLOFFS) <= shape.falloff <= max(aureole_split.HELD_FALLOFFS)
    assert shape.gradation[0] == 0.0 or (
        min(aureole_split.HELD_GRADATION_B) <= shape.gradation[1]
        <= max(aureole_split.HELD_GRADATION_B))
    model = aureole.radiance(dirs, s, split.fit.amplitude, shape)
    # Nowhere above the sky where the rule reads it: the rest is non-negative there, and
    # subtracting loses nothing to clipping.
    read = read_by_the_rule(dirs, s)
    assert np.all(model[read] <= image[read] + 1e-9)
    # Below 10 degrees (not read) the model may pass the sky: at most 0.1 % of the sky's
    # horizontal irradiance is lost there.
    weight = np.clip(dirs[..., 1], 0.0, None) * sr
    lost = np.sum(np.maximum(model - image, 0.0)[..., 1] * weight)
    assert lost <= 1e-3 * np.sum(image[..., 1] * weight)
    # Something is taken out (the bases without the CIE term cannot draw a glow at the sun):
    # here 20-90 % of the clear sky's aureole.
    clear_aureole = aureole.radiance(dirs, s, amplitude, aureole.AureoleShape())
    assert 0.15 < np.sum(model[..., 1] * weight) / np.sum(clear_aureole * weight) < 1.0


def test_a_dark_cloud_caps_the_amplitude_at_its_own_radiance():
    # A clear CIE sky (its aureole's shape in the held range) with a uniformly dark cloud 60-80
    # degrees from the sun, outside the fit's ring: the ring fits exactly, but the model
    # would pass the cloud, so the fit is refused; the largest amplitude of the sky's shape
    # under the sky is the cloud's radiance over the kernel's largest value in it.
    az, el = 150.0, 40.0
    image, dirs, _, amplitude = cie_sky(az, el)
    s = direction_from_azimuth_elevation(az, el)
    chi = np.degrees(np.arccos(np.clip(dirs @ s, -1.0, 1.0)))
    cloud = (chi >= 60.0) & (chi <= 80.0) & (dirs[..., 1] > 0.3)
    k = aureole.kernel(dirs, s, aureole.AureoleShape())
    radiance = 0.2 * amplitude * k[cloud].max()
    image[cloud] = radiance
    split = aureole_split.split(image, s)
    assert not split.accepted and split.free_rms_rel < 1e-6
    model = aureole.radiance(dirs, s, split.fit.amplitude, split.fit.shape)
    read = read_by_the_rule(dirs, s)
    assert np.all(model[read] <= image[read] + 1e-9)
    # Held to the sky's own shape, the amplitude is the cloud's bound exactly.
    flat = (dirs.reshape(-1, 3), image.reshape(-1, 3), pixel_directions(HEIGHT)[1].reshape(-1))
    want = np.full(3, radiance / k[cloud].max())
    assert aureole_split.envelope(*flat[:2], s, aureole.AureoleShape()) == pytest.approx(
        want, rel=1e-9)
    held = aureole_split.held_fit(*flat, s, shapes=[aureole.AureoleShape()])
    assert held.amplitude == pytest.approx(want, rel=1e-9)
