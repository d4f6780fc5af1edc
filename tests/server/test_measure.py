"""Measuring recovers known skies (Sato Sec. 5): exact patches, analytic skies, the clipped sun."""

import math

import numpy as np
import pytest

from bake.dome import Dome
from daylit.sky import UniformSky, patch_mean_radiance
from daylit.spherical import PatchLookup
from server.fisheye import FisheyeCamera
from server.measure import Frame, FrameError, SkyMeter
from server.photometry import Photometry, inverse_response_table
from server.simsky import SimulatedSky
from server.temporalfilter import TemporalFilter


def opencv_camera(size):
    """A distorted, slightly anamorphic, off-centre lens whose 180-degree circle fits."""
    D = np.array([0.04, -0.012, 0.003, -0.0004])
    cam = FisheyeCamera(size, size, np.eye(3), D)
    radius = cam.distort_theta(np.array(np.pi / 2))
    f = 0.47 * size / float(radius)
    K = np.array([[f, 0.0, size / 2 + 3.3], [0.0, 0.97 * f, size / 2 - 2.1], [0, 0, 1]])
    return FisheyeCamera(size, size, K, D)


def render_piecewise_constant(cam, tris, L, samples=7):
    """Linear image of a sky that is ``L[i]`` over patch i, by point-sampling ``samples^2``
    jittered sub-pixel positions (a different pattern from the measuring code's)."""
    lookup = PatchLookup(tris)
    px = cam.pixel_grid()
    image = np.zeros((px.shape[0], 3))
    rng = np.random.default_rng(123)
    for i in range(samples):
        for j in range(samples):
            offset = (np.array([i, j]) + rng.random(px.shape)) / samples - 0.5
            d, ok = cam.unproject(px + offset)
            patch = np.where(ok, lookup(d), -1)
            image += np.where((patch >= 0)[:, None], L[np.maximum(patch, 0)], 0.0)
    return (image / samples**2).reshape(cam.height, cam.width, 3).astype(np.float32)


@pytest.mark.parametrize("projection", ["equidistant", "opencv"])
def test_piecewise_constant_sky_is_recovered_within_half_a_percent(projection):
    tris = Dome.for_light_count(100).vertices
    cam = FisheyeCamera.equidistant(288, 288) if projection == "equidistant" else opencv_camera(288)
    rng = np.random.default_rng(7)
    L = rng.uniform(0.1, 1.0, (len(tris), 3))  # contrast up to 10:1 between neighbours
    image = render_piecewise_constant(cam, tris, L)
    meter = SkyMeter(tris, Photometry(response="linear"), camera=cam)
    m = meter.measure(Frame(image, 0.0, bgr=False, exposure=1.0))
    assert meter.matrix.covered.all()
    rel = np.abs(m.radiance / L - 1.0)
    print(projection, "max relative error", rel.max())
    assert rel.max() < 0.005, f"worst light {np.unravel_index(rel.argmax(), rel.shape)}"
    # A plain coverage-weighted mean (Sato as written) is visibly worse on such a sky: the test
    # can tell the methods apart.
    mat = meter.matrix
    x = meter.linearize(image, mat)[0].reshape(-1, 3)
    plain = mat.whole @ x + mat.pairs_to_light @ x[mat.pair_pixel]
    plain /= mat.norm[:, None]
    assert np.abs(plain / L - 1.0).max() > 0.02


def test_simulated_sky_matches_the_analytic_patch_integrals(dome160):
    sim = SimulatedSky.for_site(34.47, 135.82, 100.0, "Asia/Tokyo", cloud_cover=0.4,
                                size_px=480, start="2026-06-21T10:30")
    frame = sim.render_at(sim.clock.start_s)
    assert frame.image.dtype == np.uint8 and frame.image.max() == 255  # the sun clips
    truth = patch_mean_radiance(frame.truth, dome160, samples_per_side=32)
    m = SkyMeter(dome160, Photometry()).measure(frame)
    sun_patch = PatchLookup(dome160)(frame.truth.sun.direction[None])[0]
    assert m.saturated[sun_patch]
    assert m.radiance[sun_patch].max() < 0.1 * truth[sun_patch].max()  # clipped: a lower bound
    away = ~m.saturated
    assert away.sum() >= len(dome160) - 4  # only the sun's patch and its neighbours
    rel = np.abs(m.radiance[away] / truth[away] - 1.0)
    assert rel.max() < 0.02
    assert rel.mean() < 0.005


def test_exposure_vignetting_and_photometric_factor_are_undone():
    tris = Dome.for_light_count(40).vertices
    cam = FisheyeCamera.equidistant(200, 200)
    L = np.array([3.0, 4.0, 2.0])
    photometry = Photometry(response="linear", vignetting=(-0.15, 0.02),
                            photometric_factor=(2.0, 1.0, 0.5))
    dirs, ok = cam.unproject(cam.pixel_grid())
    theta = np.arccos(np.clip((dirs @ cam.site_from_camera)[:, 2], -1, 1))
    exposure = 0.1
    image = (L * exposure * photometry.vignetting_gain(theta)[:, None] / [2.0, 1.0, 0.5])
    image = (image * ok[:, None]).reshape(200, 200, 3).astype(np.float32)
    m = SkyMeter(tris, photometry).measure(Frame(image, 0.0, bgr=False, exposure=exposure))
    assert np.allclose(m.radiance, L, rtol=1e-3)
    assert not m.saturated.any()


@pytest.mark.parametrize("response", ["srgb", "gamma:2.2"])
def test_response_curve_is_inverted(response):
    tris = Dome.for_light_count(40).vertices
    sky = UniformSky(L=(0.2, 0.45, 0.7))
    table = inverse_response_table(response)
    cam = FisheyeCamera.equidistant(160, 160)
    codes = np.stack([np.abs(table[:, c] - v).argmin() for c, v in enumerate(sky.L)])
    image = np.broadcast_to(codes.astype(np.uint8), (160, 160, 3)).copy()
    m = SkyMeter(tris, Photometry(response=response), camera=cam).measure(
        Frame(image[..., ::-1].copy(), 0.0, bgr=True, exposure=1.0))
    expected = table[codes, [0, 1, 2]]
    assert np.allclose(m.radiance, expected, rtol=2e-4)
    # And the quantised codes are within half a code of the sky we meant.
    assert np.allclose(m.radiance, sky.L, rtol=0.02)


def test_lens_narrower_than_the_dome_fills_horizon_lights_from_neighbours():
    tris = Dome.for_light_count(40).vertices
    cam = FisheyeCamera.equidistant(200, 200, fov_deg=100.0)
    meter = SkyMeter(tris, Photometry(response="linear"), camera=cam)
    m = meter.measure(Frame(np.full((200, 200, 3), 0.5, np.float32), 0.0, bgr=False))
    assert not meter.matrix.covered.all() and meter.matrix.covered.any()
    assert np.allclose(m.radiance, 0.5, rtol=1e-4)


def test_frames_that_cannot_be_measured_raise_frame_error():
    tris = Dome.for_light_count(40).vertices
    meter = SkyMeter(tris)
    with pytest.raises(FrameError):
        meter.measure(Frame(np.zeros((100, 100), np.uint8), 0.0))
    with pytest.raises(FrameError):
        meter.measure(Frame(np.zeros((100, 100, 3), np.int32), 0.0))
    nan = np.full((100, 100, 3), np.nan, np.float32)
    with pytest.raises(FrameError):
        meter.measure(Frame(nan, 0.0))
    with pytest.raises(FrameError):
        meter.measure(Frame(np.zeros((100, 100, 3), np.uint8), 0.0, exposure=0.0))
    calibrated = SkyMeter(tris, camera=FisheyeCamera.equidistant(100, 100))
    with pytest.raises(FrameError, match="calibration"):
        calibrated.measure(Frame(np.zeros((100, 120, 3), np.uint8), 0.0))


def test_temporal_filter_smooths_with_its_time_constant():
    f = TemporalFilter(time_constant_s=2.0, change_threshold=0.01, max_interval_s=100.0)
    f.update(np.zeros((4, 3)), 0.0)
    out = f.update(np.ones((4, 3)), 2.0)
    assert np.allclose(out, 1.0 - math.exp(-1.0))
    off = TemporalFilter(time_constant_s=0.0)
    off.update(np.zeros((4, 3)), 0.0)
    assert np.allclose(off.update(np.ones((4, 3)), 0.001), 1.0)


def test_change_threshold_flags_and_keepalive_decide_what_is_sent():
    f = TemporalFilter(time_constant_s=0.0, change_threshold=0.01, max_interval_s=10.0)
    base = np.ones((4, 3))
    f.update(base, 0.0)
    assert f.should_send(0.0, flags=0)
    f.mark_sent(0.0, flags=0)
    f.update(base * 1.005, 1.0)  # 0.5 % of the mean: below the threshold
    assert not f.should_send(1.0, flags=0)
    assert f.should_send(1.0, flags=1)  # a flag change is always sent
    f.update(base * 1.02, 2.0)
    assert f.should_send(2.0, flags=0)
    f.mark_sent(2.0, flags=0)
    assert not f.should_send(5.0, flags=0)
    assert f.should_send(12.5, flags=0)  # keep-alive


def test_temporal_filter_smooths_the_sun_and_sends_its_changes():
    f = TemporalFilter(time_constant_s=2.0, change_threshold=0.01, max_interval_s=100.0)
    sky = np.full((4, 3), 10.0)
    up = np.array([0.0, 1.0, 0.0])
    f.update(sky, 0.0, np.zeros(3), up)
    f.mark_sent(0.0)
    f.update(sky, 2.0, np.full(3, 900.0), up)
    assert np.allclose(f.sun, 900.0 * (1.0 - math.exp(-1.0)))  # the same time constant
    assert f.should_send(2.0)
    f.mark_sent(2.0)
    # Threshold: 1 % of pi x the sky's mean radiance, 0.314 W/m^2.
    f = TemporalFilter(time_constant_s=0.0, change_threshold=0.01, max_interval_s=100.0)
    f.update(sky, 0.0, np.full(3, 900.0), up)
    f.mark_sent(0.0)
    f.update(sky, 1.0, np.full(3, 900.2), up)
    assert not f.should_send(1.0)
    f.update(sky, 2.0, np.full(3, 900.5), up)
    assert f.should_send(2.0)
    f.mark_sent(2.0)
    tilted = np.array([math.sin(math.radians(0.1)), math.cos(math.radians(0.1)), 0.0])
    f.update(sky, 3.0, np.full(3, 900.5), tilted)  # the sun moved 0.1 degrees
    assert f.should_send(3.0)
    f.mark_sent(3.0)
    f.update(sky, 4.0, np.zeros(3), np.zeros(3))  # it set
    assert f.should_send(4.0)
