"""The scene estimate beside a sky camera (server.fusion, issue 16).

Known answers: a uniform sky's horizontal irradiance (pi times its radiance) from the dome's
projected solid angles; which sun wins (the sky camera's measured disc; the scene's where the
camera clipped it); a disagreement warning past the factor. End to end through the real
server: a replay sky camera (a bracket of 8-bit PNGs whose sun clips in every exposure) of a
gendaylit sky rendered by Radiance, and a site camera (an OpenEXR replay) of the same sky over
the build's real proxies, rendered by Radiance too; the streamed sun is the scene's, within
10 % of gendaylit's DNI, where the clear-sky model alone is not; a sky camera whose frames
are scaled by 0.7 or 1.4 (drift, a fogged lens) makes ``/api/status`` warn, the undrifted one
does not.
"""

from __future__ import annotations

import asyncio
import math

import numpy as np
import pytest

from daylit.sun import SunSource
from server.fusion import SceneFusion, projected_solid_angles_sr
from server.measure import Measurement
from server.sceneestimate import SceneLight
from server.sunmeter import SunMeasurement
from tests.server.test_scene_source import write_exr

# gendaylit: a clear but hazy day, so the clear-sky model (Linke turbidity 3) is far off
SKY = ("clear", 10, 15, "11", 650.0, 110.0)


def _dome(count: int = 160) -> np.ndarray:
    from bake.dome import Dome

    return Dome.for_light_count(count).vertices


def test_projected_solid_angles_give_a_uniform_sky_pi_times_its_radiance():
    omega = projected_solid_angles_sr(_dome())
    assert omega.sum() == pytest.approx(math.pi, rel=1e-3)
    fusion = SceneFusion(meter=None, dome_vertices=_dome())
    e = fusion.sky_horizontal_irradiance(np.full((160, 3), 20.0))
    assert e == pytest.approx(np.full(3, 20.0 * math.pi), rel=1e-3)


class _Meter:
    estimates = 1


def _fusion_with(sun_w_m2: float, sky_w_m2: float, observable: bool = True) -> SceneFusion:
    fusion = SceneFusion(_Meter(), _dome(), disagreement_factor=1.3, max_age_s=5.0)
    fusion.latest = SceneLight(np.full(3, sun_w_m2), np.full(3, sky_w_m2), 12,
                               np.array([0.0, 0.6, -0.8]), observable, 500, 0.9)
    fusion.latest_wall_s = 1000.0
    return fusion


def _measurement(source: SunSource, sun_w_m2: float, sky_radiance: float) -> Measurement:
    d = np.array([0.0, 0.6, -0.8])
    sun = SunMeasurement(d, np.full(3, sun_w_m2), source, 1.0, False, d)
    return Measurement(np.full((160, 3), sky_radiance, np.float32), np.zeros(160, bool), 0.0,
                       0, sun, 0.1)


def test_the_scene_sun_replaces_the_model_where_the_sky_camera_clipped_it():
    fusion = _fusion_with(640.0, 100.0)
    m = fusion.fuse(_measurement(SunSource.MODEL, 900.0, 100.0 / math.pi), now_s=1001.0)
    assert m.sun.source == SunSource.SCENE
    assert m.sun.normal_irradiance_w_m2 == pytest.approx([640.0] * 3)
    assert fusion.status()["sun_from"] == "scene"
    assert fusion.ratios()[1] == pytest.approx(1.0, rel=2e-3)
    assert fusion.warning() == ""


def test_a_measured_sun_wins_and_an_old_or_sunless_estimate_is_not_used():
    fusion = _fusion_with(640.0, 100.0)
    m = fusion.fuse(_measurement(SunSource.MEASURED, 700.0, 100.0 / math.pi), now_s=1001.0)
    assert m.sun.source == SunSource.MEASURED and m.sun.normal_irradiance_w_m2[0] == 700.0
    assert fusion.ratios()[0] == pytest.approx(700.0 / 640.0)
    old = fusion.fuse(_measurement(SunSource.MODEL, 900.0, 30.0), now_s=1006.0)
    assert old.sun.source == SunSource.MODEL
    unseen = _fusion_with(640.0, 100.0, observable=False)
    m = unseen.fuse(_measurement(SunSource.MODEL, 900.0, 30.0), now_s=1001.0)
    assert m.sun.source == SunSource.MODEL and m.sun.normal_irradiance_w_m2[0] == 900.0


def test_a_disagreement_past_the_factor_is_a_warning():
    fusion = _fusion_with(640.0, 100.0)
    for _ in range(10):
        fusion.fuse(_measurement(SunSource.MODEL, 900.0, 0.6 * 100.0 / math.pi), now_s=1001.0)
    assert fusion.ratios()[1] == pytest.approx(0.6, rel=2e-3)
    assert "sky horizontal irradiance" in fusion.warning()
    assert fusion.status()["warning"] == fusion.warning()
    for _ in range(10):  # the median window forgets it
        fusion.fuse(_measurement(SunSource.MODEL, 900.0, 1.2 * 100.0 / math.pi), now_s=1001.0)
    assert fusion.warning() == ""


# ------------------------------------------------------------------------------------------
# Through the real server, against Radiance


@pytest.fixture(scope="module")
def renders(scene_build):
    """The site camera's view of the build and the sky camera's fisheye, one gendaylit sky."""
    pytest.importorskip("pyradiance")
    from benchmarks.radiance import SkySpec
    from daylit import manifest as manifest_io
    from tests.radiance_frames import (
        ACCURATE_CAMERA_RAYS,
        render_build_view,
        render_sky_camera,
    )

    spec = SkySpec(*SKY)
    site_view, _ = render_build_view(scene_build, spec, 320, 180, procs=1,
                                     rays=ACCURATE_CAMERA_RAYS)
    sky_image, sky = render_sky_camera(spec, manifest_io.load(scene_build), 256)
    return site_view, sky_image, sky


def _app(scene_build, tmp_path, renders, sky_scale: float):
    from server.app import create_app
    from tests.radiance_frames import write_sky_bracket
    from tests.server.helpers import settings_for

    site_view, sky_image, _ = renders
    exposure = 0.8 / float(np.percentile(site_view.sun_image, 99.0))
    site = tmp_path / "site"
    site.mkdir()
    write_exr(site / "frame.exr", site_view.sun_image * exposure, site_view.when_unix_s)
    sky = tmp_path / "sky"
    write_sky_bracket(sky / "b0", sky_scale * sky_image, site_view.when_unix_s)
    return create_app(scene_build, settings_for(
        tmp_path, sky__source=f"replay:{sky}", sky__rate_hz=4.0, sky__stale_after_s=5.0,
        site_camera__source=f"replay:{site}", site_camera__rate_hz=4.0,
        occlusion__enabled=False, scene__radiance_per_unit=1.0 / exposure))


async def _status_when(client, predicate, timeout_s: float = 120.0) -> dict:
    """``/api/status`` once ``predicate(body)`` holds (polled; the timeout only bounds a
    loaded machine)."""
    from tests.server.helpers import wait_for

    body: dict = {}
    ready = asyncio.Event()

    async def poll():
        nonlocal body
        while not predicate(body := await (await client.get("/api/status")).json()):
            await asyncio.sleep(0.2)
        ready.set()

    task = asyncio.create_task(poll())
    try:
        await wait_for(ready.is_set, timeout_s)
    finally:
        task.cancel()
    return body


async def _light_from_scene(ws, messages: int = 200):
    """The next LIGHT message whose sun is the scene's (earlier ones may be the model's)."""
    from server import protocol

    for _ in range(messages):
        m = protocol.decode((await ws.receive(timeout=30)).data)
        if m.type == protocol.MessageType.LIGHT and m.sun.source == SunSource.SCENE:
            return m
    raise AssertionError(f"no LIGHT with the scene's sun in {messages} messages")


@pytest.mark.slow
async def test_a_clipped_sun_streams_the_scene_estimate(
        aiohttp_client, scene_build, tmp_path, renders):
    from daylit.sun import SunPath
    from server import protocol
    from tests.server.helpers import first_light_v2

    site_view, _, sky = renders
    truth = sky.dni
    client = await aiohttp_client(_app(scene_build, tmp_path, renders, 1.0))
    ws, _ = await first_light_v2(client)
    m = await _light_from_scene(ws)
    status = await _status_when(client, lambda b: b["fusion"].get("sun_from") == "scene"
                                and b["fusion"]["sky_ratio"] is not None)
    assert m.flags & protocol.Flags.SUN_ESTIMATED and m.sun.estimated
    streamed = float(np.mean(m.sun.normal_irradiance_w_m2))
    assert streamed == pytest.approx(truth, rel=0.10)
    # the sky camera alone (its sun clipped in every exposure) would stream the model's
    fusion = status["fusion"]
    assert fusion["sky_camera"]["sun_source"] == "model"
    model = float(np.mean(SunPath(34.47, 135.82, 100.0).at(site_view.when_unix_s).dni_rgb_w_m2))
    assert abs(model / truth - 1.0) > 0.15
    # the two agree on the sky: no warning
    # (with the CIE clear sky the estimate's sky ran about 17 % low on this sky, its sun 4 %
    # high: the circumsolar sky partly taken for the sun; docs/benchmarks.md)
    assert 1 / 1.3 < fusion["sky_ratio"] < 1.3 and fusion["warning"] is None, fusion
    # the finer check: the sky camera's own sky fitted to the site's pixels needs no scale
    status = await _status_when(client, lambda b: b["fusion"].get("scene_estimates", 0) >= 12
                                and b["fusion"].get("sky_camera_gain") is not None)
    fusion = status["fusion"]
    # (0.90-0.93 on this hazy sky, 0.96-1.09 on the nine skies of test_sceneestimate's site:
    # docs/benchmarks.md)
    assert 1 / 1.25 < fusion["sky_camera_gain"] < 1.25 and fusion["warning"] is None, fusion
    assert np.mean(fusion["sky_camera"]["sky_horizontal_irradiance_W_m2"]) == pytest.approx(
        110.0, rel=0.10)
    await ws.close()


@pytest.mark.slow
@pytest.mark.parametrize("drift", [0.7, 1.4])
async def test_a_drifting_sky_camera_is_reported(
        aiohttp_client, scene_build, tmp_path, renders, drift):
    """A sky camera whose frames read the sky x0.7 (a fogged lens) or x1.4 (a gain change).
    The sky camera's gain against the site's pixels (server.skycheck, drift factor 1.25)
    reports both; so does the comparison with the scene estimate's own sky (factor 1.3),
    since that sky is Perez's clear sky: with the CIE clear sky it ran 17-20 % low on this sky,
    the ratio read 0.7 x 1.2 and missed the fogged lens. (The site's frame is rendered without
    Radiance's ambient cache, whose brightened shade reads as too much sky: with it the
    estimate's sky read 39 % above the sky camera's.)"""
    client = await aiohttp_client(_app(scene_build, tmp_path, renders, drift))
    status = await _status_when(client, lambda b: b["fusion"].get("scene_estimates", 0) >= 12
                                and b["fusion"].get("sky_camera_gain") is not None
                                and b["frames_measured"] >= 10)
    fusion = status["fusion"]
    assert fusion["sky_camera_gain"] == pytest.approx(drift, rel=0.12), fusion
    assert not 1 / 1.25 <= fusion["sky_camera_gain"] <= 1.25, fusion
    assert "sky camera gain" in fusion["warning"], fusion
    assert fusion["sky_ratio"] == pytest.approx(drift, rel=0.12), fusion
    # the sky camera measured the drifted sky (the drift is in its frames)
    assert np.mean(fusion["sky_camera"]["sky_horizontal_irradiance_W_m2"]) == pytest.approx(
        drift * 110.0, rel=0.10)


@pytest.mark.parametrize("fuse, why", [(True, "no fixed view"), (False, "fuse_scene = false")])
def test_without_fusion_the_status_says_why(build_dir, tmp_path, fuse, why):
    import cv2

    from server.app import PIPELINE, create_app
    from tests.server.helpers import settings_for

    frames = tmp_path / "frames"
    frames.mkdir()
    cv2.imwrite(str(frames / "a.png"), np.full((32, 32, 3), 128, np.uint8))
    app = create_app(build_dir, settings_for(  # build_dir: a build without a fixed view
        tmp_path, sky__source=f"replay:{frames}", site_camera__source=f"replay:{frames}",
        sky__fuse_scene=fuse, occlusion__enabled=False))
    pipeline = app[PIPELINE]
    assert pipeline.fusion is None
    assert why in pipeline.status()["fusion"]["off"]
