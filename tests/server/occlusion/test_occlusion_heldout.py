"""The held-out sequence generator (heldout.py): its light, its ground truth, its camera and
codecs, checked against physics and against the frames it draws."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from tests.server.occlusion.heldout import (
    CONDITIONS,
    HeldoutConditions,
    HeldoutSequence,
    camera_response,
    planck,
    shadow_ratio,
)


def _srgb_to_linear(codes: np.ndarray) -> np.ndarray:
    c = codes.astype(np.float64) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def test_planck_peaks_where_wiens_displacement_law_says():
    lam = np.arange(200.0, 3000.0, 0.5)
    for t in (3000.0, 5500.0, 8000.0):
        peak_nm = lam[np.argmax(planck(lam, t))]
        assert abs(peak_nm - 2.897771955e6 / t) < 1.0, (t, peak_nm)


def test_shadows_are_neutral_or_mildly_blue():
    assert np.allclose(shadow_ratio("neutral"), 0.4)
    b, g, r = shadow_ratio("bluish")
    assert g == pytest.approx(0.4)
    assert b > g > r  # the sky alone is bluer than sun and sky
    assert 0.05 < np.log(b / g) < 0.3 and 0.05 < np.log(g / r) < 0.3  # mild
    # a hotter illuminant is bluer on the broadband camera, monotonically
    ratios = [camera_response(t)[0] / camera_response(t)[2] for t in (4000, 5500, 8000, 12000)]
    assert ratios == sorted(ratios)
    with pytest.raises(ValueError, match="neutral or bluish"):
        shadow_ratio("green")


@pytest.fixture(scope="module")
def clean():
    seq = HeldoutSequence(width=512, height=256, duration_s=4.0,
                          conditions=HeldoutConditions(shadow="bluish"))
    return seq, list(seq.frames())


def test_the_ground_truth_matches_the_pixels(clean):
    seq, frames = clean
    bg = _srgb_to_linear(frames[0].image)
    assert all(f.people == 0 and not f.person.any() for f in frames[:seq.empty_frames])
    assert all(np.array_equal(f.image, frames[0].image) for f in frames[:seq.empty_frames])
    late = frames[-1]
    assert late.people == 3 and late.person.sum() > 1500 and late.shadow.sum() > 300
    lin = _srgb_to_linear(late.image)
    # Shadowed ground, covered c of the way (penumbra: 0 < c <= 1), is the background times
    # 1 - c (1 - ratio) per channel: c from green must predict blue and red.
    full = shadow_ratio("bluish")
    by_person = cv2.dilate(late.person.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    ok = late.shadow & (bg.min(axis=2) > 0.05) & ~by_person  # not mixed with a person's edge
    assert ok.sum() > 200
    got = lin[ok] / bg[ok]
    c = (1.0 - got[:, 1]) / (1.0 - full[1])
    assert np.median(c) > 0.5 and c.max() > 0.7
    want = 1.0 - c[:, None] * (1.0 - full)[None, :]
    assert np.abs(got - want).max() < 0.03, np.abs(got - want).max()
    # away from people and shadows (the truth holds coverage >= 0.5; the penumbra's outer
    # half, up to 3 of its widest blur, is in neither), nothing changed
    still = ~(cv2.dilate((late.person | late.shadow).astype(np.uint8),
                         np.ones((41, 41), np.uint8)) > 0)
    assert still.mean() > 0.7
    assert np.abs(late.image[still].astype(int) - frames[0].image[still]).max() <= 3


def test_the_camera_shake_moves_image_and_truth_together():
    seq = HeldoutSequence(width=256, height=128, duration_s=4.0,
                          conditions=HeldoutConditions(jitter_px=0.5))
    frames = list(seq.frames())
    steady = list(dataclasses.replace(seq, conditions=HeldoutConditions()).frames())
    moved = 0
    for f, s in zip(frames, steady, strict=True):
        diff = np.abs(f.image.astype(int) - s.image).mean()
        moved += diff > 0.5
        if s.person.any():  # the truth follows the image: same people, at most a pixel off
            assert abs(int(f.person.sum()) - int(s.person.sum())) < 0.2 * s.person.sum()
            near = cv2.dilate(s.person.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
            assert not (f.person & ~near).any()
    assert moved > 0.8 * len(frames)


@pytest.mark.parametrize("name", ["JPEG 75", "video mp4v", "video H.264"])
def test_the_codecs_change_the_pixels_but_keep_every_frame(name):
    seq = HeldoutSequence(width=256, height=128, duration_s=2.0, conditions=CONDITIONS[name])
    plain = HeldoutSequence(width=256, height=128, duration_s=2.0,
                            conditions=dataclasses.replace(CONDITIONS[name], jpeg_quality=None,
                                                           video_fourcc=None, h264_crf=None))
    coded, raw = list(seq.frames()), list(plain.frames())
    assert len(coded) == len(raw) == 20
    errors = [np.abs(c.image.astype(int) - r.image).mean() for c, r in zip(coded, raw,
                                                                          strict=True)]
    assert 0.3 < np.median(errors) < 8.0, errors  # lossy, but the same picture
