"""Issue 18's goals on the standard synthetic sequence, raw and as a site camera sends it.

The sequence (server/occlusion/synthetic.py) is drawn with a broadband camera under daylight
spectra (spectralcamera.py), not with the detector's narrow-band Wien model, and here passes
through JPEG 75 and H.264 (libx264 crf 28, 4:2:0, decoded by OpenCV's FFmpeg) as well as raw.
Goals as issue 18 states them: person IoU at least 0.9 (median over frames with people), shadow
kept at most 10 % of the cast-shadow area, no phantom region (person region of 25 px or more)
in the empty frames after learning.

Since the detector's codec work (2026-11-25: the blue-shift tolerance learned from the frame's
shadows, the codec's chroma and luminance blur at a shadow's edge in its noise model, thin
shadow slivers given back) and its outline work (the same day: outlines moved onto the
luminance edges, person regions ringed by shadow given back) and the standing-height and
shadow-deviation limits (regions lying flat on the ground dropped, candidates far from the
shadow signature never shadow), both codecs meet the shadow goal at this size, and H.264
meets every goal at 1024x512 (the last test); person IoU through either codec is not met at
480x270 (figures here and in docs/benchmarks.md; docs/occlusion.md, Limitations): what is
left is mostly the people's rims, one or two pixels wide, which at this size are a tenth of
a walker's area. Those tests are strict xfails, so that a fix shows as a pass to be taken
out of :data:`NOT_MET`.
"""

from __future__ import annotations

import numpy as np
import pytest

from server.occlusion.settings import OcclusionSettings
from server.occlusion.synthetic import VIRTUAL_BOX, box_depth_image
from tests.server.occlusion.conftest import CODECS, run_sequence

# (test, codec) -> what was measured, 480x270 (2026-11-25, after the standing-height and
# shadow-deviation limits; H.264's shadow goal is met since: 7.9 % kept, was 13.5 %)
NOT_MET = {
    ("iou", "JPEG 75"): "person IoU 0.883 median (goal 0.9): people's rims lost",
    ("iou", "H.264 crf 28"): "person IoU 0.834 median (goal 0.9): rims, camouflaged legs, "
                             "shadow edges kept",
}


def _known(request, test: str, codec: str) -> None:
    if (test, codec) in NOT_MET:
        request.applymarker(pytest.mark.xfail(strict=True, reason=NOT_MET[test, codec]))


def test_person_iou_is_at_least_0_9_median_over_frames(codec_run, request):
    name, stats = codec_run
    _known(request, "iou", name)
    assert len(stats.people_frame_iou) >= 100, name
    assert np.median(stats.people_frame_iou) >= 0.9, (name, np.median(stats.people_frame_iou))


def test_at_most_10_percent_of_the_shadow_is_kept(codec_run, request):
    name, stats = codec_run
    _known(request, "shadow", name)
    assert stats.shadow_truth > 10_000, name  # the sequence does have large shadows
    assert stats.shadow_kept_fraction <= 0.10, (name, stats.shadow_kept_fraction)


def test_no_phantom_in_the_empty_frames(codec_run):
    name, stats = codec_run
    assert len(stats.phantoms) >= 5, name  # 1.6 s empty, 1 s of it learned
    assert sum(stats.phantoms) == 0, (name, stats.phantoms)


@pytest.mark.parametrize("codec", ["raw", "H.264 crf 28"])
def test_the_sequence_fails_without_shadow_handling(codec_site, codec):
    """The sequence exercises shadow removal: with it switched off (a shadow never cheaper as
    background than as a person), the shadow goal fails by far, and with it person IoU."""
    virtual = box_depth_image(codec_site.camera, *VIRTUAL_BOX)
    off = OcclusionSettings(shadow_cost=1e9)
    _, stats = run_sequence(codec_site, virtual, off, codec=CODECS[codec])
    assert stats.shadow_kept_fraction > 0.5, stats.shadow_kept_fraction
    assert np.median(stats.people_frame_iou) < 0.9, np.median(stats.people_frame_iou)


@pytest.mark.parametrize("codec", ["JPEG 75", "H.264 crf 28"])
def test_at_1024x512_both_codecs_meet_issue_18s_goals(codec):
    """Issue 18's goals at the size they are asked at (and the server's default ``max_width``
    for occlusion, 1024), through JPEG 75 and H.264 (libx264 crf 28). Measured: JPEG 75 person
    IoU 0.932 median, 0.4 % of the shadow kept; H.264 0.902 (2026-11-25; 0.882 before the
    standing-height and shadow-deviation limits), 2.8 % kept; no phantom. H.264's IoU is
    within 0.002 of the goal; x264 on one thread (other frames) gave 0.906 (0.884 before), but
    another x264 build may land on either side."""
    from server.occlusion.synthetic import default_site
    from tests.server.occlusion.conftest import CODEC_EMPTY_S

    site = default_site(1024, 512, empty_s=CODEC_EMPTY_S)
    virtual = box_depth_image(site.camera, *VIRTUAL_BOX)
    _, stats = run_sequence(site, virtual, codec=CODECS[codec])
    print(f"{codec} at 1024x512: IoU {np.median(stats.people_frame_iou):.3f}, "
          f"shadow kept {stats.shadow_kept_fraction:.3f}")
    assert len(stats.people_frame_iou) >= 100 and len(stats.phantoms) >= 5
    assert np.median(stats.people_frame_iou) >= 0.9, np.median(stats.people_frame_iou)
    assert stats.shadow_kept_fraction <= 0.10, stats.shadow_kept_fraction
    assert sum(stats.phantoms) == 0, stats.phantoms
