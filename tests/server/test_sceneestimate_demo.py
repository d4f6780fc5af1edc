"""The scene estimate on the demo site's own real proxies, a site it was not tuned on (issue 16).

The estimator's other tests use one small test site (``tests/radiance_frames.known_site``).
Here the truth is Radiance's render (gendaylit skies, 15 October at 9:30, 12:00 and 14:30,
without the ambient cache, whose bias brightens shade) of the demo build's real proxies and
ground (the visitor centre, the tree, the ground; ``render_build_view``), seen by a site camera
north-west of the visitor centre so that the centre and its shadow are in view. (The demo's
kiosk view sees the ground and the tree's thin shadow only: docs/benchmarks.md, "On a site it
was not tuned on".) Each condition is a stream of camera frames (noise, JPEG 85) per seed,
through the server's estimator built from the build as ``daylit serve --sky scene`` builds it.
"""

from __future__ import annotations

import numpy as np
import pytest

HOURS = ("9.5", "12", "14.5")
SKIES = {"clear": (800.0, 80.0), "overcast": (0.0, 150.0)}
EYE_M, TARGET_M = (30.0, 6.0, -45.0), (46.0, 2.0, -6.0)
SIZE = (160, 90)  # a quarter of the tests' usual 320x180: uncached renders take 10-20 s
SEEDS = range(6)
FRAMES = 4


@pytest.fixture(scope="module")
def demo_streams(demo_draft_build):
    """{(sky, hour): [last estimate of each seed's stream]} and the renders' truths."""
    from benchmarks.radiance import SkySpec
    from daylit import manifest as manifest_io
    from daylit.sun import sun_position
    from server.sceneestimate import SceneEstimator
    from server.scenemeter import real_proxies
    from tests.radiance_frames import (
        ACCURATE_CAMERA_RAYS,
        last_estimate,
        look_at_view,
        render_build_view,
    )

    manifest = manifest_io.load(demo_draft_build)
    mesh, albedo = real_proxies(demo_draft_build, manifest)
    ground = float(np.mean(manifest["ground"]["albedo"]))
    scene = manifest["scene"]
    view = look_at_view(EYE_M, TARGET_M, *SIZE, 75.0)
    out = {}
    for hour in HOURS:
        for name, (dni, dhi) in SKIES.items():
            rendered, _ = render_build_view(demo_draft_build, SkySpec(name, 10, 15, hour, dni,
                                                                      dhi),
                                            *SIZE, procs=1, view=view, rays=ACCURATE_CAMERA_RAYS)
            sun = sun_position(scene["latitude_deg"], scene["longitude_deg"],
                               scene["elevation_m"], [rendered.when_unix_s]).direction[0]
            lasts = [last_estimate(SceneEstimator(mesh, albedo, view, environment_albedo=ground,
                                                  seed=seed), rendered, sun, seed, FRAMES)
                     for seed in SEEDS]
            out[name, hour] = (rendered, lasts)
    return out


def _grey(rgb) -> float:
    return float(np.mean(rgb))


@pytest.mark.slow
def test_clear_sun_within_ten_percent_on_the_demo(demo_streams):
    for hour in HOURS:
        rendered, lasts = demo_streams["clear", hour]
        for seed, last in zip(SEEDS, lasts, strict=True):
            err = _grey(last.sun_normal_irradiance) / rendered.dni_w_m2 - 1.0
            assert abs(err) < 0.10, (hour, seed, err, last)


@pytest.mark.slow
def test_overcast_sun_below_five_percent_of_the_sky_on_the_demo(demo_streams):
    """Before the shadow-edge pairs' check this failed (at 9:30 the first stream kept a sun of
    7.1 % of the sky; at 320x180, 3-11 of 40 streams an hour kept one above 5 %)."""
    for hour in HOURS:
        rendered, lasts = demo_streams["overcast", hour]
        for seed, last in zip(SEEDS, lasts, strict=True):
            sky = _grey(last.sky_horizontal_irradiance)
            assert _grey(last.sun_normal_irradiance) < 0.05 * sky, (hour, seed, last)
            assert sky == pytest.approx(rendered.dhi_w_m2, rel=0.10), (hour, seed, last)


@pytest.mark.slow
def test_clear_sky_within_ten_percent_on_the_demo(demo_streams):
    """The clear sky's horizontal irradiance (a tenth of the light) within the issue's 10 %.
    Before the clear sky's shape was the Perez all-weather sky of the measured state, with
    the open sky found on a fine grid per sample (server/perezsky.py, server/scenesamples.py),
    this failed: the CIE clear sky and 96 directions shared by every sample read it up to
    22 % off at 12:00 (docs/benchmarks.md, "On a site it was not tuned on")."""
    for hour in HOURS:
        rendered, lasts = demo_streams["clear", hour]
        for seed, last in zip(SEEDS, lasts, strict=True):
            err = _grey(last.sky_horizontal_irradiance) / rendered.dhi_w_m2 - 1.0
            assert abs(err) < 0.10, (hour, seed, err, last)


KIOSK_SIZE = (160, 90)
KIOSK_HOURS = ("9.5", "12")


@pytest.fixture(scope="module")
def kiosk_overcast_streams(demo_draft_build):
    """The demo's kiosk view (the build's first fixed view, scaled to ``KIOSK_SIZE``) under
    the overcast sky: {hour: (rendered, [last estimate of each seed's stream])}. The view sees
    the ground and a tree whose shadow is under a pixel wide here: no shade to tell a sun from
    the sky, and no pairs across shadow edges."""
    from benchmarks.radiance import SkySpec
    from daylit import manifest as manifest_io
    from daylit.sun import sun_position
    from server.sceneestimate import SceneEstimator
    from server.scenemeter import real_proxies
    from tests.radiance_frames import ACCURATE_CAMERA_RAYS, last_estimate, render_build_view

    manifest = manifest_io.load(demo_draft_build)
    mesh, albedo = real_proxies(demo_draft_build, manifest)
    ground = float(np.mean(manifest["ground"]["albedo"]))
    scene = manifest["scene"]
    out = {}
    for hour in KIOSK_HOURS:
        dni, dhi = SKIES["overcast"]
        rendered, view = render_build_view(demo_draft_build,
                                           SkySpec("overcast", 10, 15, hour, dni, dhi),
                                           *KIOSK_SIZE, procs=1, rays=ACCURATE_CAMERA_RAYS)
        sun = sun_position(scene["latitude_deg"], scene["longitude_deg"],
                           scene["elevation_m"], [rendered.when_unix_s]).direction[0]
        out[hour] = (rendered, [
            last_estimate(SceneEstimator(mesh, albedo, view, environment_albedo=ground,
                                         seed=seed), rendered, sun, seed, FRAMES)
            for seed in SEEDS])
    return out


@pytest.mark.slow
def test_overcast_sun_below_five_percent_on_a_view_without_shade(kiosk_overcast_streams):
    """Before the sun had to explain the pixels clearly better than the sky alone under every
    sky type (``sun_significance``; before, under the overcast types only), this failed: over
    40 streams at this size 27 (9:30) and 8 (12:00) kept a sun above 5 % of the sky, up to
    5.5 times the sky, the fit having taken an intermediate or clear shape on noise."""
    for hour in KIOSK_HOURS:
        rendered, lasts = kiosk_overcast_streams[hour]
        for seed, last in zip(SEEDS, lasts, strict=True):
            sky = _grey(last.sky_horizontal_irradiance)
            assert _grey(last.sun_normal_irradiance) < 0.05 * sky, (hour, seed, last)
            assert sky == pytest.approx(rendered.dhi_w_m2, rel=0.10), (hour, seed, last)


KIOSK_CLEAR_SIZE = (320, 180)  # the tree's shaded canopy is a few dozen pixels here


@pytest.fixture(scope="module")
def kiosk_clear(demo_draft_build):
    """The demo's kiosk view (the build's first fixed view) under the clear sky at 12:00 and
    9:30, rendered by Radiance without the ambient cache: {hour: (rendered, sun direction,
    estimator arguments)}. The view sees sunlit ground, the tree's shadow 1-2 px wide and its
    canopy of faces a few pixels across: no 3 x 3 patch of the pool is in shadow; 179 single
    pixels are wholly in the model's shadow at 12:00, 17 at 9:30."""
    from benchmarks.radiance import SkySpec
    from daylit import manifest as manifest_io
    from daylit.sun import sun_position
    from server.scenemeter import real_proxies
    from tests.radiance_frames import ACCURATE_CAMERA_RAYS, render_build_view

    manifest = manifest_io.load(demo_draft_build)
    mesh, albedo = real_proxies(demo_draft_build, manifest)
    ground = float(np.mean(manifest["ground"]["albedo"]))
    scene = manifest["scene"]
    dni, dhi = SKIES["clear"]
    out = {}
    for hour in ("12", "9.5"):
        rendered, view = render_build_view(
            demo_draft_build, SkySpec("clear", 10, 15, hour, dni, dhi), *KIOSK_CLEAR_SIZE,
            procs=1, rays=ACCURATE_CAMERA_RAYS)
        sun = sun_position(scene["latitude_deg"], scene["longitude_deg"],
                           scene["elevation_m"], [rendered.when_unix_s]).direction[0]
        out[hour] = (rendered, sun, {"mesh": mesh, "face_albedo": albedo, "view": view,
                                     "environment_albedo": ground})
    return out


@pytest.mark.slow
def test_the_kiosk_views_clear_sky_within_ten_percent(kiosk_clear):
    """Streams of camera frames (noise, JPEG 85) of the kiosk view at noon: the sun and the
    sky within the issue's 10 %, from samples of which many are wholly in shadow, and the
    estimate says the sky is separable. Before the pool was topped up with single pixels
    wholly in the model's shadow (server/shadepool.py) this failed: with no sample in shade
    the fit read the sky from sunlit ground, where sun and sky are nearly collinear (seeds 1
    and 2: +29 % and +11 %; over 40 streams 22 off by up to 70 %, docs/benchmarks.md)."""
    _assert_clear_goal_met(*kiosk_clear["12"], min_shaded=50)


def _assert_clear_goal_met(rendered, sun, kwargs, min_shaded):
    """Each seed's stream: the sun and the sky within the issue's 10 %, at least
    ``min_shaded`` samples in shade and the sky said separable."""
    from server.sceneestimate import SceneEstimator
    from tests.radiance_frames import last_estimate

    for seed in SEEDS:
        light = last_estimate(SceneEstimator(**kwargs, seed=seed), rendered, sun, seed, FRAMES)
        sky = _grey(light.sky_horizontal_irradiance) / rendered.dhi_w_m2 - 1.0
        sun_err = _grey(light.sun_normal_irradiance) / rendered.dni_w_m2 - 1.0
        assert light.shaded >= min_shaded and light.sky_separable, (seed, light)
        assert abs(sky) < 0.10, (seed, sky, light)
        assert abs(sun_err) < 0.10, (seed, sun_err, light)


@pytest.mark.slow
def test_the_kiosk_view_says_when_its_shade_cannot_separate_the_sky(kiosk_clear):
    """At 9:30 the kiosk view has 17 pixels wholly in shade: the sun stays within 10 % but the
    sky may not (over 40 streams 10 were 10-29 % off, docs/benchmarks.md), and the estimate
    says so: every stream's sky is flagged not separable, while at noon none is (the test
    above). On main there was no such flag (and the sky was up to 63 % off)."""
    from server.sceneestimate import SceneEstimator
    from tests.radiance_frames import last_estimate

    rendered, sun, kwargs = kiosk_clear["9.5"]
    for seed in SEEDS:
        light = last_estimate(SceneEstimator(**kwargs, seed=seed), rendered, sun, seed, FRAMES)
        sun_err = _grey(light.sun_normal_irradiance) / rendered.dni_w_m2 - 1.0
        assert abs(sun_err) < 0.10, (seed, sun_err, light)
        assert not light.sky_separable, (seed, light)


KIOSK_OWN_SIZE = (640, 360)  # the kiosk view's own size (scenes/demo/scene.toml)


@pytest.fixture(scope="module")
def kiosk_clear_own_size(demo_draft_build):
    """The kiosk view at its own 640x360 (the draft build's view, 320x180, scaled up) under
    the clear sky at 9:30, rendered once by Radiance without the ambient cache (about 2-5 min
    with one process): (rendered, sun direction, estimator arguments). 268 pixels are wholly
    in the model's shadow there (17 at 320x180)."""
    from benchmarks.radiance import SkySpec
    from daylit import manifest as manifest_io
    from daylit.sun import sun_position
    from server.scenemeter import real_proxies
    from tests.radiance_frames import ACCURATE_CAMERA_RAYS, render_build_view

    manifest = manifest_io.load(demo_draft_build)
    mesh, albedo = real_proxies(demo_draft_build, manifest)
    ground = float(np.mean(manifest["ground"]["albedo"]))
    scene = manifest["scene"]
    dni, dhi = SKIES["clear"]
    rendered, view = render_build_view(
        demo_draft_build, SkySpec("clear", 10, 15, "9.5", dni, dhi), *KIOSK_OWN_SIZE,
        procs=1, rays=ACCURATE_CAMERA_RAYS)
    sun = sun_position(scene["latitude_deg"], scene["longitude_deg"], scene["elevation_m"],
                       [rendered.when_unix_s]).direction[0]
    return rendered, sun, {"mesh": mesh, "face_albedo": albedo, "view": view,
                           "environment_albedo": ground}


@pytest.mark.slow
def test_the_kiosk_view_at_its_own_size_meets_the_goal_at_930(kiosk_clear_own_size):
    """At its own 640x360 the kiosk view at 9:30 holds the issue's goal that it misses at half
    the size (the test above): the sun and the sky within 10 %, from a couple of hundred
    samples wholly in shade, and the estimate says the sky is separable. main already met it
    (over 40 streams: the sky at most 6.5 % off, the sun 0.4 %, its standard error 0.6-0.9 %;
    docs/benchmarks.md): this holds the goal at the view's real size."""
    _assert_clear_goal_met(*kiosk_clear_own_size, min_shaded=150)


def test_the_shade_search_near_the_parts_finds_what_casting_every_pixel_finds(
        demo_draft_build):
    """The shade search casts only the pixels whose ray toward the sun could meet a part's
    bounding box (``server.shadepool.sunward_near_parts``): on the kiosk view at its own size,
    over the day, the pixels wholly in shadow are those found by casting every pixel's ray."""
    import dataclasses

    from benchmarks.radiance import SkySpec
    from daylit import manifest as manifest_io
    from daylit.sun import sun_position
    from server.sceneestimate import PinholeView, intersector
    from server.scenemeter import real_proxies
    from server.shadepool import view_hits, wholly_shaded_pixels
    from tests.radiance_frames import local_time

    manifest = manifest_io.load(demo_draft_build)
    mesh, _ = real_proxies(demo_draft_build, manifest)
    scene = manifest["scene"]
    first = PinholeView.from_manifest(manifest["views"][0])
    s = KIOSK_OWN_SIZE[0] / first.width
    view = PinholeView(np.diag([s, s, 1.0]) @ first.K, first.world_from_camera,
                       *KIOSK_OWN_SIZE)
    hit = intersector(mesh)
    hits = view_hits(mesh, view, hit)
    every = dataclasses.replace(hits, boxes_m=None)
    found = 0
    for hour in np.arange(7.0, 17.01, 0.5):
        when = local_time(SkySpec("clear", 10, 15, str(hour), 800.0, 80.0), scene["timezone"])
        sun = sun_position(scene["latitude_deg"], scene["longitude_deg"],
                           scene["elevation_m"], [when]).direction[0]
        for margin in (0, 1):
            near = wholly_shaded_pixels(hits, hit, sun, margin_px=margin)
            assert np.array_equal(near, wholly_shaded_pixels(every, hit, sun,
                                                             margin_px=margin)), (hour, margin)
            found += len(near)
    assert found > 1000
