"""The occlusion worker's engine (server/occlusionfeed.py) without the server around it:
the pipeline is built before the first frame, so the frames learned as the empty site are
the camera's first frames whatever the machine's speed."""

from __future__ import annotations

import logging

import numpy as np

from server.occlusionfeed import OcclusionConfig, OcclusionEngine
from tests.server.helpers import KioskSequence


def _engine(build, learn_frames=3) -> OcclusionEngine:
    from server.occlusion import OcclusionProcessor

    cam = OcclusionProcessor.from_build(build, "kiosk").camera
    return OcclusionEngine(OcclusionConfig(str(build), "kiosk", (cam.width, cam.height),
                                           learn_frames=learn_frames))


def test_prepare_builds_the_pipeline_before_the_first_frame(demo_draft_build):
    engine = _engine(demo_draft_build)
    assert engine.processor is None
    engine.prepare()
    built = engine.processor
    assert built is not None and engine.size == engine.config.view_size
    kiosk = KioskSequence(demo_draft_build, frames=6, empty_frames=6)
    outs = [engine.process(image) for image in kiosk.images[:4]]
    assert engine.processor is built  # the same pipeline: not rebuilt on the first frame
    assert [o.ok for o in outs] == [True] * 4
    assert [o.learning for o in outs] == [True, True, True, False]


def test_frames_of_another_size_right_after_prepare_are_taken_at_once(demo_draft_build,
                                                                      caplog):
    import cv2

    engine = _engine(demo_draft_build)
    engine.prepare()
    w, h = engine.config.view_size
    frame = np.full((2 * h, 2 * w, 3), 120, np.uint8)  # the camera delivers twice the size
    with caplog.at_level(logging.WARNING):
        out = engine.process(frame)
    assert out.ok and out.learning and engine.size == (2 * w, 2 * h)
    assert not [r for r in caplog.records if "skipping" in r.getMessage()]
    # once frames came, another size is a stray frame again (skipped until it persists)
    out = engine.process(cv2.resize(frame, (w, h)))
    assert not out.ok and "the frames before were" in out.reason


def test_relearn_learns_again_without_reading_the_build(demo_draft_build, monkeypatch):
    from server.occlusion import OcclusionProcessor

    engine = _engine(demo_draft_build, learn_frames=2)
    engine.prepare()
    kiosk = KioskSequence(demo_draft_build, frames=4, empty_frames=4)
    assert [engine.process(i).learning for i in kiosk.images[:3]] == [True, True, False]

    def no_build(*args, **kwargs):
        raise AssertionError("the build was read again")

    monkeypatch.setattr(OcclusionProcessor, "from_build", no_build)
    engine.relearn()
    assert [engine.process(i).learning for i in kiosk.images[:3]] == [True, True, False]


def test_prepare_on_a_broken_build_logs_and_the_first_frame_tries_again(tmp_path, caplog):
    engine = OcclusionEngine(OcclusionConfig(str(tmp_path / "nothing"), "kiosk", (64, 36)))
    with caplog.at_level(logging.ERROR):
        engine.prepare()  # does not raise
    assert engine.processor is None
    assert any("could not be built" in r.getMessage() for r in caplog.records)
    out = engine.process(np.zeros((36, 64, 3), np.uint8))
    assert not out.ok and "pipeline error" in out.reason
