"""The streaming contract of OcclusionProcessor: bad frames are skipped with a log line, nothing
raises, and the frames after them come out as if the bad ones had never been sent."""

from __future__ import annotations

import logging

import cv2
import numpy as np
import pytest

from server.occlusion import OcclusionProcessor, OcclusionSettings, PerspectiveCamera
from server.occlusion.synthetic import SyntheticSite, Walker

BAD_FRAMES = {
    "none": None,
    "empty array": np.zeros((0, 0, 3), np.uint8),
    "wrong size": np.zeros((100, 100, 3), np.uint8),
    "transposed": np.zeros((480, 270, 3), np.uint8),
    "grey": np.zeros((270, 480), np.uint8),
    "float": np.zeros((270, 480, 3), np.float32),
    "empty bytes": b"",
    "corrupt bytes": b"\xff\xd8\xff\xe0 this is not a JPEG at all" * 10,
    "not an image": "frame.jpg",
}


@pytest.fixture(scope="module")
def frames(standard_site):
    return [standard_site.frame(i).image for i in range(22)]


def run(site, frames, bad_every=None):
    proc = OcclusionProcessor(site.camera, None)
    results = []
    for i, frame in enumerate(frames):
        if bad_every and i % bad_every == 3:
            for bad in BAD_FRAMES.values():
                r = proc.process(bad)
                assert not r.ok and r.skipped_reason and r.mask is None
        results.append(proc.process(frame))
    return proc, results


@pytest.mark.parametrize("name", sorted(BAD_FRAMES))
def test_a_bad_frame_is_skipped_with_a_log_line(standard_site, name, caplog):
    proc = OcclusionProcessor(standard_site.camera, None)
    with caplog.at_level(logging.WARNING, logger="daylit.occlusion"):
        result = proc.process(BAD_FRAMES[name], capture_time_s=12.5)
    assert not result.ok
    assert result.capture_time_s == 12.5 and result.frame_index == 0
    assert result.mask is None and result.people == []
    [record] = [r for r in caplog.records if r.name == "daylit.occlusion"]
    assert record.levelno == logging.WARNING
    assert "frame 0 skipped" in record.getMessage()
    assert result.skipped_reason in record.getMessage()


def test_processing_goes_on_after_bad_frames_as_if_they_never_came(standard_site, frames):
    _, clean = run(standard_site, frames)
    _, noisy = run(standard_site, frames, bad_every=4)
    assert len(clean) == len(noisy)
    for a, b in zip(clean, noisy, strict=True):
        assert a.ok and b.ok and a.learning == b.learning
        assert np.array_equal(a.mask, b.mask)
        assert np.array_equal(a.person_mask, b.person_mask)
    assert any(np.count_nonzero(r.person_mask) > 1000 for r in clean)  # people were there


def test_encoded_images_are_accepted(standard_site, frames):
    """PNG bytes (lossless) give exactly the labels of the array; JPEG bytes are decoded."""
    _, arrays = run(standard_site, frames)
    png = [cv2.imencode(".png", f)[1].tobytes() for f in frames]
    _, decoded = run(standard_site, png)
    assert all(np.array_equal(a.person_mask, b.person_mask) for a, b in zip(arrays, decoded,
                                                                             strict=True))
    proc = OcclusionProcessor(standard_site.camera, None)
    result = proc.process(cv2.imencode(".jpg", frames[0])[1].tobytes())
    assert result.ok and result.learning


def test_repeated_bad_frames_do_not_flood_the_log(standard_site, caplog):
    proc = OcclusionProcessor(standard_site.camera, None)
    with caplog.at_level(logging.WARNING, logger="daylit.occlusion"):
        for _ in range(200):
            proc.process(b"")
    lines = [r for r in caplog.records if r.name == "daylit.occlusion"]
    assert 1 <= len(lines) <= 3  # at most one a second for the same reason


def test_an_internal_failure_skips_the_frame_and_the_stream_goes_on(standard_site, frames,
                                                                      caplog, monkeypatch):
    proc = OcclusionProcessor(standard_site.camera, None)
    for frame in frames[:12]:
        proc.process(frame)
    original = proc.segmenter.segment

    def broken(*args):
        raise FloatingPointError("something inside went wrong")

    monkeypatch.setattr(proc.segmenter, "segment", broken)
    with caplog.at_level(logging.ERROR, logger="daylit.occlusion"):
        result = proc.process(frames[12])
    assert not result.ok and "FloatingPointError" in result.skipped_reason
    assert any("occlusion pipeline failed" in r.getMessage() for r in caplog.records)
    monkeypatch.setattr(proc.segmenter, "segment", original)
    result = proc.process(frames[13])
    assert result.ok and not result.learning and np.count_nonzero(result.person_mask) > 500


def test_the_first_frames_learn_the_empty_site(standard_site, frames):
    proc, results = run(standard_site, frames)
    n = proc.settings.learn_frames
    assert all(r.learning and not r.mask.any() for r in results[:n])
    assert proc.ready and not results[n].learning
    assert set(results[n].timings_ms) >= {"gain", "regions", "segment", "depth", "update",
                                          "total"}


def test_learn_background_explicitly_leaves_bad_frames_out(standard_site, frames, caplog):
    proc = OcclusionProcessor(standard_site.camera, None, OcclusionSettings(learn_frames=3))
    with caplog.at_level(logging.WARNING, logger="daylit.occlusion"):
        used = proc.learn_background([frames[0], None, frames[1], b"junk", frames[2]])
    assert used == 3 and proc.ready
    assert len([r for r in caplog.records if r.name == "daylit.occlusion"]) == 2
    assert not proc.process(frames[3]).learning
    with pytest.raises(ValueError, match="no usable frame"):
        proc.learn_background([None])


def test_a_virtual_depth_of_the_wrong_size_is_refused(standard_site):
    with pytest.raises(ValueError, match="virtual depth"):
        OcclusionProcessor(standard_site.camera, np.zeros((10, 10), np.float32))


@pytest.mark.slow
def test_from_build_uses_the_kiosk_view_of_a_baked_site(demo_draft_build):
    """The demo site's kiosk camera and virtual depth, with two people walking across it."""
    proc = OcclusionProcessor.from_build(demo_draft_build, "kiosk")
    cam = proc.camera
    assert isinstance(cam, PerspectiveCamera) and (cam.width, cam.height) == (320, 180)
    depth = proc.virtual_depth_m
    assert depth.shape == (180, 320) and np.isfinite(depth).any() and np.isinf(depth).any()
    # A column through the virtual building, and the ground distance of its base there.
    rows, cols = np.nonzero(np.isfinite(depth))
    u = int(np.median(cols))
    base_row = rows[cols == u].max()
    building_m = float(depth[base_row, u])
    forward = cam.R[:, 2]
    ray = cam.ray_directions(u + 0.5, 90.0)[0]
    heading = np.array([ray[0], 0.0, ray[2]]) / np.hypot(ray[0], ray[2])
    side = np.array([heading[2], 0.0, -heading[0]])

    def standing_at(depth_m, start_side_m, speed_mps, **clothes):
        along = depth_m / float(heading @ forward)  # horizontal distance for that depth
        p = cam.origin_m * [1, 0, 1] + heading * along + side * start_side_m
        v = side * speed_mps
        return Walker((p[0], p[2]), (v[0], v[2]), enter_s=1.0, **clothes)

    walkers = [standing_at(0.6 * building_m, -1.5, 0.6),
               standing_at(1.2 * building_m, 1.5, -0.6, shirt=(0.1, 0.5, 0.2))]
    site = SyntheticSite(cam, walkers, fps=10.0, duration_s=2.5)
    for i in range(site.frame_count):
        truth = site.frame(i)
        result = proc.process(truth.image)
        assert result.ok
    assert len(truth.people) == 2 and len(result.people) == 2
    near, far = sorted(truth.people, key=lambda t: t.depth_m)
    over = np.isfinite(depth)
    ideal = truth.in_front(depth)
    near_px = (truth.person_index == near.index) & over
    far_px = (truth.person_index == far.index) & over
    assert near_px.sum() > 20 and far_px.sum() > 10  # both are seen against the building
    assert ideal[near_px].all() and not ideal[far_px].any()
    assert (result.mask[near_px] > 0).mean() > 0.9  # the near one hides it
    assert (result.mask[far_px] > 0).mean() < 0.05  # the building hides the far one


@pytest.mark.slow
def test_from_build_at_another_frame_size(demo_draft_build):
    """A live camera delivering twice the baked view's size: same rays, depth resampled."""
    view = OcclusionProcessor.from_build(demo_draft_build, "kiosk")
    big = OcclusionProcessor.from_build(demo_draft_build, "kiosk", frame_size=(640, 360))
    assert (big.camera.width, big.camera.height) == (640, 360)
    assert big.virtual_depth_m.shape == (360, 640)
    # A ground point projects to the same place, relatively, in both.
    point = view.camera.ground_hit(200.5, 150.5)[0]
    uv_small, _ = view.camera.project(point)
    uv_big, _ = big.camera.project(point)
    assert np.allclose(uv_big, 2.0 * uv_small)
    assert big.camera.foot_depth_m(401.0, 301.0) == pytest.approx(
        view.camera.foot_depth_m(200.5, 150.5))
    assert np.array_equal(big.virtual_depth_m[1::2, 1::2], view.virtual_depth_m)
