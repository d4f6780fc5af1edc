"""The Perez all-weather sky's shape (server.perezsky) against Radiance's gendaylit, an
independent implementation of the same published model (Perez, Seals & Michalsky 1993)."""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np
import pytest

from server.perezsky import PerezShape, air_mass, sky_brightness
from server.skyshape import sky_clearness

pytest.importorskip("pyradiance")

SITE = {"scene": {"latitude_deg": 34.47, "longitude_deg": 135.82, "timezone": "Asia/Tokyo"}}


def _gendaylit_relative(spec, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """gendaylit's sky radiance at site directions (m, 3) over its zenith's, and its sun."""
    from benchmarks.radiance import gendaylit, oconv, radiance_env, rtrace, sky_rad
    from tests.radiance_frames import to_radiance

    _, env = radiance_env()
    sky = gendaylit(spec, SITE, env)
    all_dirs = np.vstack([[0.0, 1.0, 0.0], dirs])
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        (work / "sky.rad").write_text(sky_rad(sky.skyfunc))
        octree = oconv(work / "sky.oct", [work / "sky.rad"], env)
        rays = np.hstack([np.zeros_like(all_dirs), to_radiance(all_dirs)])
        grey = rtrace(octree, rays, ["-ab", "0"], env, irradiance=False).mean(axis=1)
    return grey[1:] / grey[0], sky.sun_dir


@pytest.mark.parametrize("hour,dni,dhi", [("12", 800.0, 80.0), ("9.5", 800.0, 80.0),
                                          ("14.5", 600.0, 120.0), ("12", 400.0, 200.0)])
def test_perez_shape_matches_gendaylits_sky(hour, dni, dhi):
    from benchmarks.radiance import SkySpec

    rng = np.random.default_rng(1)
    el = np.radians(rng.uniform(15.0, 88.0, 200))  # above gendaylit's ground blend
    az = rng.uniform(0.0, 2.0 * math.pi, 200)
    dirs = np.column_stack([np.cos(el) * np.sin(az), np.sin(el), -np.cos(el) * np.cos(az)])
    truth, sun_dir = _gendaylit_relative(SkySpec("t", 10, 15, hour, dni, dhi), dirs)
    sun_el = math.degrees(math.asin(float(sun_dir[1])))
    shape = PerezShape(sky_clearness(dni / dhi, sun_el), sky_brightness(dhi, sun_el), sun_dir)
    got = shape.relative_luminance(dirs)
    # gendaylit's brightness takes the date's extraterrestrial irradiance and its own air mass
    assert np.max(np.abs(got / truth - 1.0)) < 0.02, np.max(np.abs(got / truth - 1.0))


def test_air_mass_is_kasten_and_youngs():
    assert air_mass(90.0) == pytest.approx(1.0, abs=1e-3)
    assert air_mass(30.0) == pytest.approx(1.995, abs=0.01)
    assert air_mass(0.0) == pytest.approx(38.09, rel=0.01)
