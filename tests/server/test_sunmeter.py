"""The sun apart from the sky: frames drawn here, with this file's own equidistant projection,
sky, limb-darkened disc and encodings (not server.fisheye or server.simsky), measured through
the server's reading and measuring code; answers from pvlib called directly."""

import datetime as dt
import math

import cv2
import numpy as np
import pandas as pd
import pytest

from bake.dome import Dome
from daylit.spherical import PatchLookup
from daylit.sun import SunSource
from server.measure import Frame, SkyMeter
from server.photometry import Photometry
from server.sources.replay import read_frame_image
from server.sunmeter import SunMeter

SITE = (34.4686, 135.8194, 100.0)  # Nara
WHEN = dt.datetime(2026, 6, 21, 1, 0, tzinfo=dt.UTC)  # 10:00 local
SIZE = 640
SUN_RADIUS_RAD = math.radians(0.2666)
LIMB_U = 0.6  # linear limb darkening I(mu) = I0 (1 - u (1 - mu))
DNI_TRUE = np.array([880.0, 850.0, 790.0])
BASE_SKY = np.array([14.0, 20.0, 34.0])


def true_sun() -> np.ndarray:
    from pvlib.solarposition import get_solarposition

    pos = get_solarposition(pd.DatetimeIndex([WHEN]), *SITE[:2], altitude=SITE[2],
                            method="nrel_numpy")
    az = math.radians(float(pos["azimuth"].iloc[0]))
    el = math.radians(float(pos["apparent_elevation"].iloc[0]))
    return np.array([math.cos(el) * math.sin(az), math.sin(el), -math.cos(el) * math.cos(az)])


def yawed(d: np.ndarray, yaw_deg: float) -> np.ndarray:
    """Directions turned clockwise (seen from above) by ``yaw_deg`` about +Y."""
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    return np.stack([x * c - z * s, y, z * c + x * s], axis=-1)


def pixel_directions(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """This test's lens: equidistant, 180 degrees across the image, zenith up, north at the
    top of the image and east on the left (looking up from below)."""
    c = (SIZE - 1) / 2.0
    f = (SIZE / 2.0) / (math.pi / 2.0)
    dx, dy = u - c, v - c
    theta = np.hypot(dx, dy) / f
    phi = np.arctan2(dy, dx)
    return np.stack([-np.sin(theta) * np.cos(phi), np.cos(theta),
                     np.sin(theta) * np.sin(phi)], axis=-1)


def sky_radiance(d: np.ndarray, sun: np.ndarray, cloud_deg: float = 0.0) -> np.ndarray:
    """A smooth sky: brighter toward the horizon and around the sun; optionally a grey cloud
    of ``cloud_deg`` radius over the sun."""
    up = np.clip(d[..., 1], 0.0, 1.0)
    gamma = np.arccos(np.clip(d @ sun, -1.0, 1.0))
    L = BASE_SKY * ((0.7 + 0.6 * (1.0 - up)) * (1.0 + 1.5 * np.exp(-gamma / 0.4)))[..., None]
    if cloud_deg:
        cloud = gamma < math.radians(cloud_deg)
        L[cloud] = 45.0
    L[d[..., 1] < 0.0] = 0.0
    return L


def disc_radiance(d: np.ndarray, sun: np.ndarray) -> np.ndarray:
    """The limb-darkened disc whose integral over solid angle is ``DNI_TRUE``."""
    rho = np.arccos(np.clip(d @ sun, -1.0, 1.0)) / SUN_RADIUS_RAD
    mu = np.sqrt(np.clip(1.0 - rho**2, 0.0, 1.0))
    i0 = DNI_TRUE / (math.pi * SUN_RADIUS_RAD**2 * (1.0 - LIMB_U / 3.0))
    return np.where((rho <= 1.0)[..., None], i0 * (1.0 - LIMB_U * (1.0 - mu))[..., None], 0.0)


def render(yaw_deg: float = 0.0, with_disc: bool = True, cloud_deg: float = 0.0,
           sub: int = 24) -> np.ndarray:
    """Linear radiance image (SIZE, SIZE, 3) float32 of the sky seen by a camera whose north
    is ``yaw_deg`` off: what the meter takes for azimuth a is really a + yaw."""
    sun = true_sun()
    v, u = np.mgrid[0:SIZE, 0:SIZE].astype(float)
    d = yawed(pixel_directions(u, v), yaw_deg)
    image = sky_radiance(d, sun, cloud_deg)
    if with_disc:
        # Supersample the pixels near the disc (sub x sub points each).
        hit = np.arccos(np.clip(d @ sun, -1, 1)) < SUN_RADIUS_RAD + math.radians(1.0)
        rows, cols = np.nonzero(hit)
        off = (np.arange(sub) + 0.5) / sub - 0.5
        ou, ov = np.meshgrid(off, off)
        pu = cols[:, None] + ou.ravel()[None]
        pv = rows[:, None] + ov.ravel()[None]
        dd = yawed(pixel_directions(pu, pv), yaw_deg)
        disc = disc_radiance(dd, sun).mean(axis=1)
        if cloud_deg:
            disc *= math.exp(-20.0)  # a thick cloud: the direct sun is gone
        image[rows, cols] += disc
    return image.astype(np.float32)


def write_exr(path, rgb: np.ndarray) -> None:
    """With the capture time as OpenEXR's standard capDate (local, UTC+9) and utcOffset."""
    import OpenEXR

    channels = {c: np.ascontiguousarray(rgb[:, :, k]) for k, c in enumerate("RGB")}
    local = WHEN + dt.timedelta(hours=9)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
              "capDate": local.strftime("%Y:%m:%d %H:%M:%S"), "utcOffset": -9 * 3600.0}
    with OpenEXR.File(header, channels) as f:
        f.write(str(path))


def srgb_codes(linear: np.ndarray, rng, noise: float = 0.002) -> np.ndarray:
    x = np.clip(linear + rng.normal(0.0, noise, linear.shape) * np.sqrt(np.clip(linear, 0, 1)),
                0.0, 1.0)
    v = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
    return np.round(v * 255.0).astype(np.uint8)


@pytest.fixture(scope="module")
def dome():
    return Dome.for_light_count(160).vertices


def meter_for(dome, response="linear") -> SkyMeter:
    return SkyMeter(dome, Photometry(response=response, exposure=1.0),
                    sun=SunMeter(*SITE, linke_turbidity=3.0))


def measure_exr(tmp_path, dome, image, name="sky.exr"):
    path = tmp_path / name
    write_exr(path, image)
    read, bgr, hdr, sky_time_s = read_frame_image(path)
    assert read.dtype == np.float32 and hdr and not bgr
    assert sky_time_s == WHEN.timestamp()
    return meter_for(dome).measure(Frame(read, 0.0, bgr=bgr, hdr=hdr, sky_time_s=sky_time_s))


def angle_deg(a, b) -> float:
    return math.degrees(math.acos(np.clip(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b),
                                          -1, 1)))


@pytest.mark.parametrize("yaw_deg", [0.0, 3.0])
def test_hdr_frame_measures_the_disc_unclipped(tmp_path, dome, yaw_deg):
    m = measure_exr(tmp_path, dome, render(yaw_deg))
    sun = m.sun
    assert sun.source == SunSource.MEASURED and sun.direction_measured
    np.testing.assert_allclose(sun.normal_irradiance_w_m2, DNI_TRUE, rtol=0.03)
    seen_at = yawed(true_sun(), -yaw_deg)  # where the camera model sees the disc
    assert angle_deg(sun.direction, seen_at) < 0.5
    if yaw_deg:
        assert angle_deg(sun.ephemeris, seen_at) > 1.2  # measured, not the ephemeris
    assert not m.saturated.any()


def test_sky_patches_near_the_sun_are_not_lifted_by_the_disc(tmp_path, dome):
    with_sun = measure_exr(tmp_path, dome, render())
    without = measure_exr(tmp_path, dome, render(with_disc=False), "clear.exr")
    lookup = PatchLookup(dome)
    patch = lookup(true_sun()[None])[0]
    # The disc alone would add DNI / omega_patch: hundreds of times the sky's radiance.
    np.testing.assert_allclose(with_sun.radiance[patch], without.radiance[patch], rtol=0.01)
    np.testing.assert_allclose(with_sun.radiance, without.radiance, rtol=0.01)


def clear_sky_dni() -> float:
    from pvlib.location import Location

    site = Location(*SITE[:2], altitude=SITE[2])
    return float(site.get_clearsky(pd.DatetimeIndex([WHEN]), model="ineichen",
                                   linke_turbidity=3.0)["dni"].iloc[0])


def eight_bit(image: np.ndarray, jpeg: bool = False, seed: int = 0) -> np.ndarray:
    """The test's camera: exposure so the sky's brightest reaches 80 %, noise, sRGB, 8 bits,
    clipping; optionally through JPEG at quality 90. RGB order."""
    exposure = 0.8 / float(render(with_disc=False).max())
    codes = srgb_codes(image * exposure, np.random.default_rng(seed))
    if jpeg:
        ok, buf = cv2.imencode(".jpg", codes[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, 90])
        codes = cv2.imdecode(buf, cv2.IMREAD_COLOR)[:, :, ::-1]
    return codes, exposure


@pytest.mark.parametrize("jpeg", [False, True], ids=["png-like", "jpeg90"])
def test_clipped_sun_is_the_clear_sky_model(dome, jpeg):
    codes, exposure = eight_bit(render(), jpeg)
    meter = meter_for(dome, "srgb")
    m = meter.measure(Frame(codes, 0.0, bgr=False, exposure=exposure,
                            sky_time_s=WHEN.timestamp()))
    sun = m.sun
    assert sun.source == SunSource.MODEL and not sun.direction_measured
    assert sun.visible_fraction > 0.9
    luminance = float(sun.normal_irradiance_w_m2 @ [0.2126, 0.7152, 0.0722])
    assert luminance == pytest.approx(clear_sky_dni() * sun.visible_fraction, rel=0.005)
    assert luminance == pytest.approx(clear_sky_dni(), rel=0.1)
    assert angle_deg(sun.direction, true_sun()) < 0.01
    assert not m.saturated.any()  # the clipped disc was replaced, nothing else clipped
    clear, _ = eight_bit(render(with_disc=False), jpeg)
    truth = meter.measure(Frame(clear, 0.0, bgr=False, exposure=exposure,
                                sky_time_s=WHEN.timestamp()))
    np.testing.assert_allclose(m.radiance, truth.radiance, rtol=0.02)


def test_a_cloud_over_the_sun_leaves_almost_nothing(dome):
    codes, exposure = eight_bit(render(cloud_deg=4.0))
    m = meter_for(dome, "srgb").measure(Frame(codes, 0.0, bgr=False, exposure=exposure,
                                              sky_time_s=WHEN.timestamp()))
    assert m.sun.source == SunSource.MODEL
    assert m.sun.visible_fraction == 0.0
    assert np.all(m.sun.normal_irradiance_w_m2 < 0.05 * clear_sky_dni())


def test_no_sun_at_night(dome):
    night = WHEN + dt.timedelta(hours=12)
    codes = np.full((SIZE, SIZE, 3), 3, np.uint8)
    m = meter_for(dome, "srgb").measure(Frame(codes, 0.0, bgr=False,
                                              sky_time_s=night.timestamp()))
    assert m.sun.source == SunSource.NONE
    assert not np.any(m.sun.normal_irradiance_w_m2) and not np.any(m.sun.direction)


def assert_replayed_true_sun(m):
    """A version-2 LIGHT message from a replay carries the test sky's sun, measured: its DNI
    within 3 % and its direction within 0.5 degrees (issue 15's goals)."""
    from server import protocol

    assert m.sun.source_name == "measured" and not m.sun.estimated
    assert m.flags & protocol.Flags.REPLAY and not m.saturated.any()
    np.testing.assert_allclose(m.sun.normal_irradiance_w_m2, DNI_TRUE, rtol=0.03)
    assert angle_deg(m.sun.direction, true_sun()) < 0.5


async def test_an_exr_replay_streams_the_measured_sun(aiohttp_client, build_dir, tmp_path):
    """The whole chain: EXR files in a replay folder -> the server -> a version-2 client.
    (The test build's site is Nara, as here.)"""
    from server.app import create_app
    from tests.server.helpers import first_light_v2, settings_for

    folder = tmp_path / "exr"
    folder.mkdir()
    write_exr(folder / "sky_000.exr", render())
    app = create_app(build_dir, settings_for(tmp_path, sky__source=f"replay:{folder}"))
    client = await aiohttp_client(app)
    ws, m = await first_light_v2(client)
    assert_replayed_true_sun(m)
    await ws.close()


def nara_sim(**kw):
    from server.simsky import SimulatedSky

    return SimulatedSky.for_site(*SITE, "Asia/Tokyo", cloud_cover=0.0, **kw)


def test_simulated_sky_follows_the_sun_noon_bright_dusk_dim():
    from pvlib.location import Location

    from server.simsky import diffuse_horizontal_irradiance

    sim = nara_sim()
    noon = dt.datetime(2026, 6, 21, 3, 0, tzinfo=dt.UTC).timestamp()
    evening = noon + np.arange(5 * 3600.0, 8 * 3600.0, 60.0)
    elevations = np.array([sim.sun_at(t)[1] for t in evening])
    dusk = float(evening[np.argmin(np.abs(elevations - 5.0))])
    site = Location(*SITE[:2], altitude=SITE[2])
    dhi = {}
    for name, t in (("noon", noon), ("dusk", dusk)):
        sky = sim.sky_at(t)
        dhi[name] = diffuse_horizontal_irradiance(sky)
        expected = site.get_clearsky(pd.DatetimeIndex([pd.Timestamp(t, unit="s", tz="UTC")]),
                                     model="ineichen", linke_turbidity=3.0)
        assert dhi[name] == pytest.approx(float(expected["dhi"].iloc[0]), rel=0.02)
        luminance = float(sky.sun.normal_irradiance @ [0.2126, 0.7152, 0.0722])
        assert luminance == pytest.approx(float(expected["dni"].iloc[0]), rel=0.02)
    assert dhi["noon"] > 3.0 * dhi["dusk"]


def test_clear_simulated_frame_estimates_the_true_sun(dome):
    sim = nara_sim()
    meter = SkyMeter(dome, Photometry(response="srgb"), camera=sim.camera,
                     sun=SunMeter(*SITE))
    for hours in (0.0, 7.5):  # 10:00 and 17:30 local
        frame = sim.render_at(WHEN.timestamp() + 3600.0 * hours, capture_time_s=0.0)
        m = meter.measure(frame)
        truth = frame.truth.sun
        assert m.sun.source == SunSource.MODEL
        np.testing.assert_allclose(m.sun.normal_irradiance_w_m2, truth.normal_irradiance,
                                   rtol=0.03)
        assert angle_deg(m.sun.direction, truth.direction) < 0.05
        assert not m.saturated.any()
