"""The pipeline against exact ground truth on the standard synthetic sequence (issue 6 targets).

Every frame after the background is learned counts, including the first ones of each person.
"""

from __future__ import annotations

import numpy as np

from tests.server.occlusion.conftest import STANDING


def test_the_background_is_learned_from_the_empty_frames(standard_run):
    proc, stats = standard_run
    assert stats.learning_frames == proc.settings.learn_frames
    assert stats.skipped == 0
    assert stats.frames >= 100


def test_person_mask_iou_is_at_least_0_9(standard_run):
    _, stats = standard_run
    assert stats.person_iou >= 0.9, stats.person_iou
    # Not only on average: no frame falls apart.
    assert min(stats.frame_iou) >= 0.8, min(stats.frame_iou)


def test_foreground_before_shadow_removal_matches_people_and_shadows(standard_run):
    _, stats = standard_run
    assert stats.foreground_iou >= 0.9, stats.foreground_iou


def test_cast_shadows_are_removed_and_people_kept(standard_run):
    _, stats = standard_run
    assert stats.shadow_truth > 10_000  # the sequence does have large shadows
    assert stats.shadow_removed_fraction >= 0.9, stats.shadow_removed_fraction
    assert stats.person_kept >= 0.95, stats.person_kept


def test_depth_from_the_foot_line_is_within_5_percent(standard_run):
    _, stats = standard_run
    depth = np.array([(est, true) for _, _, est, true in stats.depth])
    assert len(depth) >= 100
    assert {who for _, who, _, _ in stats.depth} == {0, 1, 2, 3}  # all four, 7 m to 26 m
    error = np.abs(depth[:, 0] / depth[:, 1] - 1.0)
    assert error.max() <= 0.05, sorted(stats.depth, key=lambda r: -abs(r[2] / r[3] - 1))[:3]


def test_people_in_front_of_the_building_hide_it_and_people_behind_do_not(standard_run):
    _, stats = standard_run
    in_front = [shown for _, _, front, shown in stats.decisions if front]
    behind = [shown for _, _, front, shown in stats.decisions if not front]
    assert len(in_front) >= 30 and len(behind) >= 30  # both cases occur, often
    assert {who for _, who, front, _ in stats.decisions if front} >= {0, 2}
    assert 1 in {who for _, who, front, _ in stats.decisions if not front}
    # In front: (nearly) all of the person's pixels over the building are in the mask.
    assert min(in_front) >= 0.9, min(in_front)
    # Behind: none are (the building must hide them).
    assert max(behind) <= 0.02, max(behind)


def test_the_person_standing_still_is_not_absorbed_into_the_background(standard_run):
    proc, stats = standard_run
    assert len(stats.standing_iou) >= 45  # 5 s of standing still, checked every frame
    ious = [iou for _, iou in stats.standing_iou]
    assert min(ious) >= 0.9, min(ious)
    # ... and right to the end of it, while the daylight kept changing,
    assert np.mean(ious[-10:]) >= 0.95
    # the background model under them is still the empty site.
    assert stats.standing_background_change <= 0.02, stats.standing_background_change
    assert STANDING == 2
