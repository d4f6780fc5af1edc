"""The outline refinement (server/occlusion/outline.py) against shapes drawn independently.

A figure (an ellipse with arms, drawn by OpenCV at 8x and area-averaged down, so its rim is
partly covered as a real camera sees it) over textured ground, passed through JPEG 75 at 4:2:0;
the mask handed to the refinement is the true figure moved, grown or shrunk by a pixel, as the
graph cut's outline is off through a codec. The answer is the figure as drawn.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from server.occlusion.outline import refine_outline
from tests.server.occlusion.codecs import jpeg_round_trip

SIZE = (120, 160)  # h, w


def _scene(seed: int = 3):
    """(frame (h, w, 3) uint8 BGR through JPEG 75, truth (h, w) bool)."""
    h, w = SIZE
    s = 8
    big = np.zeros((h * s, w * s), np.uint8)
    cv2.ellipse(big, (80 * s, 62 * s), (16 * s, 40 * s), 0, 0, 360, 255, -1)
    cv2.line(big, (66 * s, 40 * s), (50 * s, 80 * s), 255, 6 * s)  # an arm
    cover = cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA).astype(np.float32) / 255
    rng = np.random.default_rng(seed)
    ground = np.empty((h, w, 3), np.float32)
    ground[:] = (150, 160, 165)  # grey-beige paving
    ground += cv2.GaussianBlur(rng.normal(0, 12, (h, w)).astype(np.float32), (0, 0), 1.5)[..., None]
    coat = np.array([70, 80, 200], np.float32)  # red: mostly a change of colour, less of grey
    frame = ground * (1 - cover[..., None]) + coat * cover[..., None]
    frame += rng.normal(0, 2, frame.shape)
    frame = np.clip(frame, 0, 255).astype(np.uint8)
    return jpeg_round_trip(frame, 75), cover > 0.5


def _iou(a, b):
    return np.count_nonzero(a & b) / np.count_nonzero(a | b)


@pytest.mark.parametrize("off", ["grown", "shrunk", "moved"])
def test_an_outline_off_by_a_pixel_or_two_moves_onto_the_figure(off):
    frame, truth = _scene()
    t8 = truth.view(np.uint8)
    k = np.ones((3, 3), np.uint8)
    mask = {"grown": cv2.dilate(t8, k), "shrunk": cv2.erode(t8, k),
            "moved": np.roll(t8, 1, axis=1)}[off] > 0
    before = _iou(mask, truth)
    after = _iou(refine_outline(mask, frame, 2, 25.0), truth)
    assert before < 0.92, before  # the test is not trivially met
    # Measured 0.87-0.91 -> 0.92-0.96 (a window of radius 2 follows an offset of one pixel;
    # two pixels it follows only in part: 0.83 -> 0.86).
    assert after > before + 0.03, (before, after)
    assert after > 0.91, after


def test_it_changes_nothing_farther_than_its_radius_from_the_outline():
    frame, truth = _scene()
    mask = cv2.dilate(truth.view(np.uint8), np.ones((3, 3), np.uint8)) > 0
    out = refine_outline(mask, frame, 2, 25.0)
    k = np.ones((5, 5), np.uint8)
    far = (cv2.dilate(mask.view(np.uint8), k) == cv2.erode(mask.view(np.uint8), k))
    assert np.array_equal(out[far], mask[far])
    assert np.count_nonzero(out != mask) > 50  # it did move the outline where it could


def test_an_empty_mask_stays_empty_and_radius_zero_is_off():
    frame, truth = _scene()
    empty = np.zeros(truth.shape, bool)
    assert not refine_outline(empty, frame, 2, 25.0).any()
    moved = np.roll(truth, 2, axis=1)
    assert np.array_equal(refine_outline(moved, frame, 0, 25.0), moved)
