"""The sky camera's gain against the site's pixels (server.skycheck, issue 16's drift check).

Known answers from Radiance (tests/radiance_frames.py): the site camera's frames of the test
site and the sky camera's fisheye of the same gendaylit sky, clear, intermediate and overcast
at three sun positions. The sky camera's frame goes through the server's SkyMeter; a sky
camera that reads the sky x0.7 (a fogged lens) must come out below ``1 / drift_factor``, the
right one within ``[1 / drift_factor, drift_factor]`` on every sky. (The renders are the same
every run: correlated sampling, tests/radiance_frames.py. How the render is made still moves
the undrifted gain: 0.96-1.09 over the nine skies at the tests' settings, 0.89-1.10 with a
finer ambient cache, 0.88-1.09 with uncorrelated sampling. 1.25 holds that spread; 1.13 would
not: docs/benchmarks.md.)
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pyradiance")

HOURS = ("9.5", "12", "14.5")
SKIES = {"clear": (800.0, 80.0), "intermediate": (400.0, 200.0), "overcast": (0.0, 150.0)}
DRIFT_FACTOR = 1.25  # server.config's default


def _sky_camera(name: str, hour: str, dome: np.ndarray, when_s: float) -> np.ndarray:
    """(n, 3) patch radiances the server's sky meter measures from one 8-bit fisheye frame
    of the gendaylit sky (exposed to put the sky's 99th percentile at 0.8: the sun clips)."""
    from benchmarks.radiance import SkySpec
    from server.measure import Frame, SkyMeter
    from server.photometry import Photometry
    from server.sunmeter import SunMeter
    from tests.radiance_frames import SITE, render_sky_camera, srgb_encode

    radiance, _ = render_sky_camera(SkySpec(name, 10, 15, hour, *SKIES[name]), SITE, 256)
    exposure = 0.8 / float(np.percentile(radiance[radiance > 0], 99.0))
    codes = np.round(srgb_encode(radiance * exposure) * 255.0).astype(np.uint8)
    meter = SkyMeter(dome, Photometry(exposure=exposure), sun=SunMeter(34.47, 135.82, 100.0))
    return meter.measure(Frame(codes, when_s, bgr=False, sky_time_s=when_s)).radiance.astype(
        float)


@pytest.mark.slow
def test_the_sky_camera_gain_is_one_on_every_sky_and_a_fogged_lens_is_seen():
    from bake.dome import Dome
    from benchmarks.radiance import SkySpec
    from daylit.sun import sun_position
    from server.fusion import projected_solid_angles_sr
    from server.sceneestimate import SceneEstimator
    from server.skycheck import SkyPatches, sky_camera_gain
    from tests.radiance_frames import (
        PERSON_ALBEDO,
        camera_frame,
        known_site,
        linearise,
        person_mesh,
        render_sky,
    )

    site = known_site()
    mesh, albedo = site.mesh_and_albedo()
    dome = Dome.for_light_count(160).vertices
    omega = projected_solid_angles_sr(dome)
    medians = {}
    for k, hour in enumerate(HOURS):
        for name in SKIES:
            person = ("person", person_mesh((-4.0 + 3.0 * k, 0.0, -11.0)), PERSON_ALBEDO)
            rendered = render_sky(site, SkySpec(name, 10, 15, hour, *SKIES[name]),
                                  extra=[person])
            sky = _sky_camera(name, hour, dome, rendered.when_unix_s)
            sun = sun_position(34.47, 135.82, 100.0, [rendered.when_unix_s]).direction[0]
            est = SceneEstimator(mesh, albedo, site.view, seed=k)
            patches = SkyPatches(est, dome)
            rng = np.random.default_rng(60 + k)
            exposure, gains, fogged = None, [], []
            for _ in range(10):  # the fusion's window
                codes, exposure = camera_frame(rendered.image(), rng, exposure=exposure)
                linear = linearise(codes)
                est.estimate(linear, sun, 1.0 / exposure, clip_level=0.99)
                for scale, out in ((1.0, gains), (0.7, fogged)):
                    out.append(sky_camera_gain(patches, linear, sun, scale * sky,
                                               scale * float(np.mean(omega @ sky)),
                                               1.0 / exposure, 0.99))
            medians[name, hour] = (float(np.median(gains)), float(np.median(fogged)))
    for key, (right, fog) in medians.items():
        assert 1 / DRIFT_FACTOR < right < DRIFT_FACTOR, (key, medians)
        assert fog < 1 / DRIFT_FACTOR, (key, medians)
        assert fog == pytest.approx(0.7 * right, rel=0.03), (key, medians)
