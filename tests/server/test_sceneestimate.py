"""The sun and sky estimated from a site camera's frames (server.sceneestimate, issue 16).

Known answers: a linear model with planted outliers; the uniform sky's normalisation (pi);
and frames rendered by Radiance (tests/radiance_frames.py: gendaylit skies, rtrace, not
daylit's tracer) of a small site under clear, intermediate and overcast skies at three sun
positions, through a camera model with noise and JPEG, with a person walking through; a van
and a wrong albedo the model does not know; a cloud passing over the sun.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from daylit.sky import CIESky
from daylit.sun import sun_position
from server.robustfit import robust_linear_fit
from server.sceneestimate import (
    OVERCAST_TYPES,
    SceneEstimateError,
    SceneEstimator,
    sky_type_for_ratio,
    tilted_irradiance,
    unit_sky,
)

pytest.importorskip("pyradiance")

HOURS = ("9.5", "12", "14.5")  # decimal hours: see radiance_frames.local_time
# gendaylit conditions (DNI, DHI W/m^2) for 2026-10-15 at the test site
SKIES = {"clear": (800.0, 80.0), "intermediate": (400.0, 200.0), "overcast": (0.0, 150.0)}
FRAMES_PER_CONDITION = 4  # a short stream: noise and JPEG differ frame to frame


def test_robust_fit_recovers_a_known_linear_model_despite_outliers():
    rng = np.random.default_rng(3)
    n = 500
    lit = rng.random(n) < 0.5
    a = np.where(lit, rng.uniform(0.3, 1.0, n), 0.0)
    c = rng.uniform(0.2, 1.0, n)
    y = 800.0 * a + 80.0 * c
    y *= 1.0 + rng.normal(0.0, 0.01, n)
    bad = rng.random(n) < 0.25  # people, wet patches: far too dark or too bright
    y[bad] *= rng.choice([0.2, 0.5, 1.8], bad.sum())
    x, w = robust_linear_fit(np.column_stack([a, c]), y)
    assert x[0] == pytest.approx(800.0, rel=0.02)
    assert x[1] == pytest.approx(80.0, rel=0.03)
    assert np.mean(w[bad] > 0.5) < 0.05  # the outliers were set aside


def test_unit_sky_scales_a_uniform_sky_to_unit_horizontal_irradiance():
    # CIE type 5 is of uniform luminance: radiance L gives E_h = pi L
    sky, to_unit = unit_sky(5, np.array([0.0, 0.7071, -0.7071]))
    assert isinstance(sky, CIESky)
    assert to_unit == pytest.approx(1.0 / math.pi, rel=2e-3)


def test_tilted_irradiance_matches_a_direct_integral_of_the_sky():
    """The bounce surfaces' sky (spherical harmonics to l = 2) against a brute-force
    quadrature of the CIE sky's radiance times the clamped cosine, and the isotropic sky's
    exact ``(1 + n_y) / 2``."""
    rng = np.random.default_rng(4)
    normals = rng.normal(size=(40, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    u, v = np.meshgrid((np.arange(400) + 0.5) / 400, (np.arange(400) + 0.5) / 400)
    # a grid uniform in cos(zenith) and azimuth: equal solid angles, 2 pi / N each
    cz, az = u.ravel(), 2 * np.pi * v.ravel()
    sz = np.sqrt(1 - cz**2)
    dirs = np.column_stack([sz * np.sin(az), cz, -sz * np.cos(az)])
    sun = np.array([0.737, 0.461, 0.494])
    for sky_type in (1, 2, 5, 7, 12):
        sky, to_unit = unit_sky(sky_type, sun)
        radiance = sky.relative_luminance(dirs) * to_unit
        exact = (2 * np.pi / len(dirs)) * (radiance @ np.clip(dirs @ normals.T, 0.0, None))
        got = tilted_irradiance(sky, to_unit, normals)
        assert np.max(np.abs(got - exact)) < 0.03, sky_type
    sky, to_unit = unit_sky(5, sun)
    assert tilted_irradiance(sky, to_unit, normals) == pytest.approx(
        (1 + normals[:, 1]) / 2, abs=0.01)
    # an overcast sky, three times as bright at the zenith as at the horizon: a wall gets
    # well under the isotropic 0.5
    sky, to_unit = unit_sky(1, sun)
    assert tilted_irradiance(sky, to_unit, np.array([[1.0, 0.0, 0.0]]))[0] < 0.42


def test_sky_type_follows_the_sun_to_sky_ratio():
    assert sky_type_for_ratio(0.0) in OVERCAST_TYPES
    assert sky_type_for_ratio(1.0) == 7
    assert sky_type_for_ratio(10.0) == 12
    # by Perez's clearness, not the ratio alone: Radiance's intermediate sky (DNI/DHI 2,
    # clearness 2.28 with the sun 43 degrees up) is partly cloudy even when read at 3.5 (the
    # clear CIE sky's reading of it), the test's clear sky (ratio 10, clearness 7.4) is clear
    assert sky_type_for_ratio(3.5, 43.3) == 7
    assert sky_type_for_ratio(10.0, 43.3) == 12


def test_sky_clearness_is_gendaylits():
    """Perez's sky clearness against the epsilon gendaylit (Radiance; not this code) prints for
    the same DNI and DHI: three skies at three sun positions on the test site."""
    import subprocess

    from benchmarks.radiance import radiance_env
    from server.skyshape import sky_clearness

    _, env = radiance_env()
    for dni, dhi in ((800.0, 80.0), (400.0, 200.0), (100.0, 250.0)):
        for hour in ("8.5", "12", "15.5"):
            text = subprocess.run(
                ["gendaylit", "10", "15", hour, "-y", "2026", "-a", "34.47", "-o", "-135.82",
                 "-m", "-135", "-W", str(dni), str(dhi), "-O", "1"], env=env, check=True,
                capture_output=True, text=True).stdout
            lines = text.splitlines()
            altitude = float(next(x for x in lines if "altitude" in x).split(":")[1].split()[0])
            epsilon = float(next(x for x in lines if "epsilon" in x).split(":")[1].split()[0])
            assert sky_clearness(dni / dhi, altitude) == pytest.approx(epsilon, rel=2e-3), (
                dni, dhi, hour, altitude, epsilon)


def test_bad_frames_get_a_clear_error():
    from tests.radiance_frames import known_site

    site = known_site(64, 36)
    mesh, albedo = site.mesh_and_albedo()
    est = SceneEstimator(mesh, albedo, site.view, pool=400)
    with pytest.raises(SceneEstimateError, match="frame of shape"):
        est.estimate(np.zeros((10, 10, 3)), np.array([0.0, 1.0, 0.0]))
    with pytest.raises(SceneEstimateError, match="usable samples"):
        est.estimate(np.full((36, 64, 3), np.nan), np.array([0.0, 1.0, 0.0]))
    with pytest.raises(SceneEstimateError, match="face_albedo"):
        _ = SceneEstimator(mesh, albedo[:-1], site.view).pool_samples


# ------------------------------------------------------------------------------------------
# Against Radiance


def _person(k: int):
    """Where the walking person is in frame ``k`` (walks across the view)."""
    from tests.radiance_frames import PERSON_ALBEDO, person_mesh

    return ("person", person_mesh((-4.0 + 3.0 * k, 0.0, -11.0)), PERSON_ALBEDO)


@pytest.fixture(scope="module")
def renders():
    """Every condition rendered once per test run: {(sky, hour): RenderedSky}."""
    from benchmarks.radiance import SkySpec
    from tests.radiance_frames import known_site, render_sky

    site = known_site()
    out = {}
    for k, hour in enumerate(HOURS):
        for name, (dni, dhi) in SKIES.items():
            spec = SkySpec(name, 10, 15, hour, dni, dhi)
            out[name, hour] = render_sky(site, spec, extra=[_person(k)])
    return site, out


def _stream(site, rendered, estimator, seed: int, frames: int = FRAMES_PER_CONDITION,
            sun_factors=None):
    """Estimates of a stream of camera frames of one rendered condition (the sun scaled by
    ``sun_factors[i]`` in frame i), with pvlib's sun for the render's time."""
    from tests.radiance_frames import camera_frame, linearise

    sun = sun_position(34.47, 135.82, 100.0, [rendered.when_unix_s]).direction[0]
    assert math.degrees(math.acos(min(1.0, float(sun @ rendered.sun_dir)))) < 0.5
    rng = np.random.default_rng(seed)
    factors = sun_factors or [1.0] * frames
    out = []
    exposure = None
    for f in factors:
        codes, exposure = camera_frame(rendered.image(f), rng, exposure=exposure)
        out.append(estimator.estimate(linearise(codes), sun, 1.0 / exposure, clip_level=0.99))
    return out


def _grey(rgb) -> float:
    return float(np.mean(rgb))


@pytest.mark.slow
def test_clear_sky_sun_and_sky_within_ten_percent(renders):
    site, rendered = renders
    mesh, albedo = site.mesh_and_albedo()
    for k, hour in enumerate(HOURS):
        truth = rendered["clear", hour]
        est = SceneEstimator(mesh, albedo, site.view, seed=k)
        last = _stream(site, truth, est, seed=k)[-1]
        sun_err = _grey(last.sun_normal_irradiance) / truth.dni_w_m2 - 1.0
        sky_err = _grey(last.sky_horizontal_irradiance) / truth.dhi_w_m2 - 1.0
        assert abs(sun_err) < 0.10, (hour, sun_err, last)
        assert abs(sky_err) < 0.10, (hour, sky_err, last)
        assert last.sun_observable and last.sky_type == 12


@pytest.mark.slow
def test_intermediate_sky_global_irradiance_within_ten_percent(renders):
    """What lights the site, the global horizontal irradiance, within 10 %; the split within
    25 % (no goal in the issue for it): the sun reads high and the sky low, as the walls take
    less of Radiance's partly cloudy sky than the CIE skies predict (+7 to +14 % sun, -10 to
    -19 % sky over 9 streams; +3 to +27 % and -4 to -34 % while a ratio of 3 could keep the
    clear CIE sky: docs/benchmarks.md, "The intermediate sky's split"). Perez's clearness of
    this sky is 2.28: the partly cloudy CIE sky (7)."""
    site, rendered = renders
    mesh, albedo = site.mesh_and_albedo()
    # three streams per sun position: a stream that keeps the clear CIE sky is the failure
    for hour, seed in itertools.product(HOURS, (10, 11, 12)):
        truth = rendered["intermediate", hour]
        est = SceneEstimator(mesh, albedo, site.view, seed=seed)
        last = _stream(site, truth, est, seed=seed)[-1]
        sin_el = float(truth.sun_dir[1])
        e_sun, e_sky = _grey(last.sun_normal_irradiance), _grey(last.sky_horizontal_irradiance)
        global_truth = truth.dni_w_m2 * sin_el + truth.dhi_w_m2
        assert e_sun * sin_el + e_sky == pytest.approx(global_truth, rel=0.10), (hour, seed, last)
        assert last.sun_observable and last.sky_type == 7, (hour, seed, last)
        assert e_sun == pytest.approx(truth.dni_w_m2, rel=0.25), (hour, seed, last)
        assert e_sky == pytest.approx(truth.dhi_w_m2, rel=0.25), (hour, seed, last)


@pytest.mark.slow
def test_overcast_sun_below_five_percent_of_the_sky(renders):
    site, rendered = renders
    mesh, albedo = site.mesh_and_albedo()
    for k, hour in enumerate(HOURS):
        truth = rendered["overcast", hour]
        est = SceneEstimator(mesh, albedo, site.view, seed=20 + k)
        last = _stream(site, truth, est, seed=20 + k)[-1]
        sky = _grey(last.sky_horizontal_irradiance)
        assert _grey(last.sun_normal_irradiance) < 0.05 * sky, (hour, last)
        assert sky == pytest.approx(truth.dhi_w_m2, rel=0.15)
        assert last.sky_type in OVERCAST_TYPES


@pytest.mark.slow
def test_overcast_sun_below_five_percent_without_the_significance_test(renders):
    """The cause, not the safety nets: with ``sun_significance`` and the shadow-edge pairs'
    check (``pair_floor``) off, every frame of two streams of six per sun position keeps the
    sun under 5 % of the sky. (With the CIE standard
    overcast, type 1, and bounce surfaces lit as by an isotropic sky, 139 of 448 such frames
    were above 5 % at seven sun positions, up to 9.7 %: docs/benchmarks.md.)"""
    site, rendered = renders
    mesh, albedo = site.mesh_and_albedo()
    worst = []
    for k, hour in enumerate(HOURS):
        truth = rendered["overcast", hour]
        for seed in (30 + k, 40 + k):
            est = SceneEstimator(mesh, albedo, site.view, seed=seed, sun_significance=0.0,
                                 pair_floor=0.0)
            for light in _stream(site, truth, est, seed=seed, frames=6):
                ratio = _grey(light.sun_normal_irradiance) / _grey(
                    light.sky_horizontal_irradiance)
                worst.append(ratio)
                assert ratio < 0.05, (hour, seed, light)
    assert max(worst) > 0.0  # the sun's term was free: the test can see one


@pytest.mark.slow
def test_cloud_over_the_sun_is_followed_within_two_frames(renders):
    site, rendered = renders
    mesh, albedo = site.mesh_and_albedo()
    truth = rendered["clear", "12"]
    factors = [1.0, 1.0, 1.0, 0.1, 0.1, 0.1, 1.0, 1.0, 1.0]
    est = SceneEstimator(mesh, albedo, site.view, seed=5)
    out = _stream(site, truth, est, seed=5, sun_factors=factors)
    # before the cloud, and the second and third frames under it and after it: within 10 %
    # of the clear DNI of the truth of that frame
    for i in (1, 2, 4, 5, 7, 8):
        err = abs(_grey(out[i].sun_normal_irradiance) - factors[i] * truth.dni_w_m2)
        assert err < 0.1 * truth.dni_w_m2, (i, factors[i], out[i])
    # the first frame after each change already moved most of the way
    assert _grey(out[3].sun_normal_irradiance) < 0.3 * truth.dni_w_m2
    assert _grey(out[6].sun_normal_irradiance) > 0.7 * truth.dni_w_m2


@pytest.fixture(scope="module")
def van_render():
    """Clear sky at 14:30 with a person and a van the model does not know (the van's shadow
    falls north-east of it, on open ground in view, where the model expects sun)."""
    from benchmarks.radiance import SkySpec
    from tests.radiance_frames import VAN_ALBEDO, known_site, render_sky, van_mesh

    site = known_site()
    return site, render_sky(site, SkySpec("clear", 10, 15, "14.5", *SKIES["clear"]),
                            extra=[_person(1), ("van", van_mesh(), VAN_ALBEDO)])


def _van_estimate(van_render, building_albedo_scale: float):
    site, rendered = van_render
    mesh, albedo = site.mesh_and_albedo({"building": building_albedo_scale})
    est = SceneEstimator(mesh, albedo, site.view, seed=7)
    return rendered, _stream(site, rendered, est, seed=7)[-1]


@pytest.mark.slow
def test_an_unknown_van_and_its_shadow_stay_within_fifteen_percent(van_render):
    rendered, last = _van_estimate(van_render, 1.0)
    assert _grey(last.sun_normal_irradiance) == pytest.approx(rendered.dni_w_m2, rel=0.15)
    assert _grey(last.sky_horizontal_irradiance) == pytest.approx(rendered.dhi_w_m2, rel=0.15)


@pytest.fixture(scope="module", params=[0.7, 1.3], ids=["albedo0.7x", "albedo1.3x"])
def wrong_albedo_estimates(request, van_render):
    """(rendered condition, {seed: last estimate}) of streams at seeds 7, 8, 9 with the
    building's albedo wrong by the factor ``request.param``."""
    site, rendered = van_render
    mesh, albedo = site.mesh_and_albedo({"building": request.param})
    return rendered, {
        seed: _stream(site, rendered, SceneEstimator(mesh, albedo, site.view, seed=seed),
                      seed=seed)[-1]
        for seed in (7, 8, 9)
    }


@pytest.mark.slow
def test_a_building_albedo_wrong_by_30_percent_keeps_the_sun_within_fifteen_percent(
        wrong_albedo_estimates):
    rendered, lasts = wrong_albedo_estimates
    for seed, last in lasts.items():
        assert _grey(last.sun_normal_irradiance) == pytest.approx(rendered.dni_w_m2,
                                                                  rel=0.15), seed


@pytest.mark.slow
def test_a_building_albedo_wrong_by_30_percent_keeps_the_sky_within_fifteen_percent(
        wrong_albedo_estimates):
    rendered, lasts = wrong_albedo_estimates
    for seed, last in lasts.items():
        assert _grey(last.sky_horizontal_irradiance) == pytest.approx(rendered.dhi_w_m2,
                                                                      rel=0.15), seed
