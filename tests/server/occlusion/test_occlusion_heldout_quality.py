"""The detector on held-out sequences (heldout.py: a camera model other than the detector's),
against the generator's exact person and shadow masks: issue 18's goals in every condition at
1024x512, the size they are asked at; at 512x256 the goals where they are met at that size,
the level reached where they are not (docs/occlusion.md)."""

from __future__ import annotations

import statistics

import cv2
import numpy as np
import pytest

from server.occlusion import OcclusionProcessor
from server.occlusion.synthetic import make_camera
from tests.server.occlusion.heldout import CONDITIONS, HeldoutSequence

W, H = 512, 256

# condition: (least median person IoU, most shadow area kept as person). Issue 18 asks 0.9
# and 0.1; at 1024x512 (bench_occlusion.py --heldout, docs/benchmarks.md) every condition
# meets them (noise 3 codes on shadow since shadow_signature_core_px). At this half size
# the people have a quarter of the pixels and the outer penumbra (kept: shadow_penumbra is
# off) weighs more; three fall short (measured: bluish keeps 0.21 of the shadow, the shake
# gives IoU 0.88 and keeps 0.25, JPEG 75 keeps 0.13): those hold the level reached, with margin.
REGION_SHARE_MAX = 0.25  # of the frame, median over frames with people (measured: see the test)

GOALS = {
    "neutral shadows": (0.9, 0.1),
    "bluish shadows": (0.9, 0.25),
    "jitter 0.5 px": (0.85, 0.3),
    # 3 codes of sensor noise: the outer penumbra at the candidates' rim outnumbered the umbra
    # and the shadow signature locked onto it, keeping 39 % of the shadow (1024x512, before
    # shadow_signature_core_px); measured 6 % kept at this size with it.
    "noise 3 codes": (0.9, 0.1),
    "JPEG 75": (0.85, 0.15),
}


def _run(name: str, w: int = W, h: int = H):
    seq = HeldoutSequence(width=w, height=h, duration_s=6.0).with_conditions(CONDITIONS[name])
    proc = OcclusionProcessor(make_camera(w, h))
    ious, phantoms, shadow, shadow_kept = [], [], 0, 0
    for f in seq.frames():
        r = proc.process(f.image)
        if r.learning:
            continue
        m = r.person_mask > 0
        if not f.person.any():
            n, _, stats, _ = cv2.connectedComponentsWithStats(m.view(np.uint8))
            phantoms.append(int(np.count_nonzero(stats[1:, cv2.CC_STAT_AREA] >= 25)))
            continue
        ious.append(np.count_nonzero(m & f.person) / np.count_nonzero(m | f.person))
        shadow += np.count_nonzero(f.shadow)
        shadow_kept += np.count_nonzero(m & f.shadow)
    return ious, phantoms, shadow, shadow_kept


@pytest.mark.parametrize("name", list(GOALS))
def test_people_without_their_shadows_at_half_size(name):
    iou_min, kept_max = GOALS[name]
    ious, phantoms, shadow, kept = _run(name)
    assert len(ious) >= 40 and len(phantoms) >= 5
    assert shadow > 5000  # there are shadows to remove
    assert statistics.median(ious) >= iou_min, statistics.median(ious)
    assert kept / shadow <= kept_max, kept / shadow
    assert phantoms == [0] * len(phantoms)


@pytest.mark.parametrize("name", list(CONDITIONS))
def test_issue_18s_goals_in_every_condition_at_1024x512(name):
    """Issue 18's goals at the size they are asked at (the server's default ``max_width`` for
    occlusion is 1024), in every held-out condition: person IoU at least 0.9 (median over the
    frames with people), at most 10 % of the cast-shadow area kept, no phantom region in the
    empty frames. Measured 2026-12-05: IoU 0.914 (all at once, H.264) to 0.987, shadow kept
    0.0-1.6 %. H.264 is as an IP camera streams it live (libx264 crf 28, 4:2:0, no B-frames;
    heldout.py), decoded by OpenCV's FFmpeg as the server decodes RTSP. (With x264's default
    B-frames, which live cameras leave off for latency, the frame before a walker enters
    carried a 34 px ghost of him.)"""
    ious, phantoms, shadow, kept = _run(name, 2 * W, 2 * H)
    assert len(ious) >= 40 and len(phantoms) >= 5
    assert shadow > 20000
    print(f"{name}: IoU {statistics.median(ious):.3f}, shadow kept {kept / shadow:.3f}")
    assert statistics.median(ious) >= 0.9, statistics.median(ious)
    assert kept / shadow <= 0.1, kept / shadow
    assert phantoms == [0] * len(phantoms)


def test_a_white_balance_and_exposure_jump_changes_nothing():
    """The camera's auto white balance and exposure jump with people in view (per-channel
    gains x0.98, x1.2, x1.38 on linear light, heldout.py): the per-channel daylight gain takes
    it, so the frames from the jump on are segmented as well as without it (the same
    sequence, same noise), and no phantom appears."""
    def after_jump(name):
        seq = HeldoutSequence(width=W, height=H, duration_s=6.0).with_conditions(
            CONDITIONS[name])
        proc = OcclusionProcessor(make_camera(W, H))
        ious, false_px = [], []
        for i, f in enumerate(seq.frames()):
            r = proc.process(f.image)
            if r.learning or i < seq.frame_count // 2 or not f.person.any():
                continue
            m = r.person_mask > 0
            ious.append(np.count_nonzero(m & f.person) / np.count_nonzero(m | f.person))
            false_px.append(np.count_nonzero(m & ~f.person & ~f.shadow))
        return np.array(ious), np.array(false_px)

    jump_iou, jump_false = after_jump("white balance jump")
    base_iou, base_false = after_jump("bluish shadows")
    assert len(jump_iou) == len(base_iou) >= 20
    assert jump_iou.min() >= base_iou.min() - 0.02, (jump_iou.min(), base_iou.min())
    assert np.median(jump_iou) >= np.median(base_iou) - 0.01
    # false person pixels off the people and their shadows: not more than without the jump
    assert jump_false.max() <= 2 * base_false.max() + 50, (jump_false.max(), base_false.max())


def test_regions_stay_around_the_people_in_codec_frames():
    """A video codec's scattered errors, labelled shadow by the cut, must not feed the next
    frame's regions of interest: they did, and one region grew to half the frame (the cut's
    cost with it, 73 ms at 1024x512). The regions follow the coarse difference and last
    frame's people only. At 1024x512, where the regions grew (at 512x256 they did not)."""
    w, h = 2 * W, 2 * H
    seq = HeldoutSequence(width=w, height=h, duration_s=4.0).with_conditions(
        CONDITIONS["video mp4v"])
    proc = OcclusionProcessor(make_camera(w, h))
    shares, ious = [], []
    for f in seq.frames():
        r = proc.process(f.image)
        if r.learning or not f.person.any():
            continue
        area = sum((y1 - y0) * (x1 - x0) for y0, y1, x0, x1 in r.regions)
        shares.append(area / (w * h))
        m = r.person_mask > 0
        ious.append(np.count_nonzero(m & f.person) / np.count_nonzero(m | f.person))
    assert len(shares) >= 20
    print(f"region share median {statistics.median(shares):.3f}, IoU {statistics.median(ious):.3f}")
    assert statistics.median(shares) <= REGION_SHARE_MAX, statistics.median(shares)
    assert statistics.median(ious) >= 0.9, statistics.median(ious)
