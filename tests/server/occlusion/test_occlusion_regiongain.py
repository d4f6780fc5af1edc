"""The sky's gain of its own (regiongain.py) against gains set by construction.

A coarse background of textured ground below the horizon and a smooth sky gradient above it;
a frame whose ground is dimmed by the global gain and whose sky is brightened by known
per-channel factors in linear light. The region is the sky, its residual gain the sky's
factors over the global gain, and the sky corrected with it is the background again.
"""

from __future__ import annotations

import numpy as np
import pytest

from server.occlusion.colour import Transfer
from server.occlusion.regiongain import RegionGain

SCALE = 4
H, W = 40, 64  # coarse pixels
SKY = H // 2 - 1  # coarse rows of the sky inside the region
GLOBAL = np.array([0.8, 0.8, 0.8], dtype=np.float32)  # BGR, linear: the ground dims


def scene(sky_bgr_linear):
    """(transfer, background codes (H, W, 3) uint8, frame codes (H, W, 3) uint8): ground in
    the lower half (random texture) dimmed by GLOBAL, sky in the upper half brightened by
    ``sky_bgr_linear`` (3,)."""
    tr = Transfer("srgb")
    rng = np.random.default_rng(7)
    lin = np.empty((H, W, 3), dtype=np.float32)
    rows = np.linspace(0.0, 1.0, H // 2, dtype=np.float32)[:, None]
    lin[: H // 2] = np.stack([0.70 - 0.1 * rows, 0.45 - 0.1 * rows, 0.25 - 0.05 * rows],
                             axis=-1) * np.ones((1, W, 1), np.float32)
    lin[H // 2:] = rng.uniform(0.05, 0.4, (H - H // 2, W, 3))

    def codes(linear):
        return np.clip(np.rint(tr.to_codes(np.clip(linear, 0, 1))), 0, 255).astype(np.uint8)

    frame = lin.copy()
    frame[: H // 2] *= np.asarray(sky_bgr_linear, dtype=np.float32)
    frame[H // 2:] *= GLOBAL
    return tr, codes(lin), codes(frame)


def learned(tr, bg_codes):
    above = np.zeros((H, W), dtype=bool)
    above[: H // 2] = True
    rg = RegionGain(tr, SCALE, min_share=0.02, step_codes=4.0)
    full = np.repeat(np.repeat(bg_codes, SCALE, 0), SCALE, 1)
    n = rg.learn(bg_codes.astype(np.float32), above, full,
                 np.repeat(np.repeat(above, SCALE, 0), SCALE, 1))
    return rg, n


def corrected_by_global(tr, frame_codes):
    table = tr.gain_table(GLOBAL)
    return table[frame_codes, 0, np.arange(3)]


def test_the_sky_is_one_region_and_the_ground_none():
    tr, bg, _ = scene((1.0, 1.0, 1.0))
    rg, n = learned(tr, bg)
    assert n == 1
    # The sky's last coarse row borders the ground: not smooth, so only its full-resolution
    # pixels join (by colour, above the horizon).
    assert np.all(rg.coarse_labels[:SKY] == 1)
    assert not rg.coarse_labels[SKY:].any()
    assert np.all(rg.labels[: SCALE * H // 2] == 1)
    assert not rg.labels[SCALE * H // 2:].any()


@pytest.mark.parametrize("person_share", [0.0, 0.3])
def test_the_sky_gain_is_its_brightening_over_the_global_gain(person_share):
    sky = np.array([1.2, 1.4, 1.7])  # BGR: a veiled sun's sky whitens (red grows most)
    tr, bg, frame = scene(sky)
    if person_share:  # someone's head and coat in front of a share of the sky
        rng = np.random.default_rng(1)
        cols = int(person_share * W)
        frame[: H // 2, :cols] = rng.integers(20, 120, (H // 2, cols, 3))
    rg, _ = learned(tr, bg)
    corrected = corrected_by_global(tr, frame)
    bg_linear = tr.to_linear(bg)
    rg.estimate(frame, corrected, bg_linear, bg.astype(np.float32), GLOBAL)
    np.testing.assert_allclose(rg.gains[0], sky / GLOBAL, rtol=0.02)
    # Corrected with it, the sky is its background again (within the codes' rounding).
    rg.apply(corrected, frame, [(0, H, 0, W)], bg, bg_linear, GLOBAL, rg.coarse_labels)
    cols = slice(int(person_share * W), None)
    diff = np.abs(corrected[:SKY, cols].astype(int) - bg[:SKY, cols])
    assert diff.max() <= 2
    assert np.array_equal(corrected[H // 2:], corrected_by_global(tr, frame)[H // 2:])


def test_a_clipped_channel_is_explained_not_measured():
    """The sky's blue clipped by the brightening: the median of the censored ratios is
    still the unclipped channels' gain; every clipped pixel gets its background's code."""
    sky = np.array([2.2, 1.4, 1.7])  # blue (a sky at 0.6-0.7 linear) past 1.0: clipped
    tr, bg, frame = scene(sky)
    assert np.all(frame[: H // 2, :, 0] == 255)
    rg, _ = learned(tr, bg)
    corrected = corrected_by_global(tr, frame)
    bg_linear = tr.to_linear(bg)
    rg.estimate(frame, corrected, bg_linear, bg.astype(np.float32), GLOBAL)
    assert rg.clip_mode[0, 0] and not rg.clip_mode[0, 1:].any()
    np.testing.assert_allclose(rg.gains[0, 1:], sky[1:] / GLOBAL[1:], rtol=0.02)
    rg.apply(corrected, frame, [(0, H, 0, W)], bg, bg_linear, GLOBAL, rg.coarse_labels)
    assert np.array_equal(corrected[:SKY, :, 0], bg[:SKY, :, 0])
    assert np.abs(corrected[:SKY].astype(int) - bg[:SKY]).max() <= 2


def test_a_camera_that_cannot_tell_the_horizon_gets_no_region():
    tr, bg, _ = scene((1.0, 1.0, 1.0))
    rg = RegionGain(tr, SCALE, min_share=0.02, step_codes=4.0)
    full = np.repeat(np.repeat(bg, SCALE, 0), SCALE, 1)
    assert rg.learn(bg.astype(np.float32), None, full) == 0
    assert not rg.labels.any()


def test_the_horizon_of_each_camera():
    """A level panorama's horizon is its middle row; a pinhole camera's where its rays turn
    from the ground to the sky (the synthetic site's camera looks slightly down)."""
    from server.occlusion.depth import EquidistantPanorama
    from server.occlusion.pipeline import OcclusionProcessor
    from server.occlusion.synthetic import make_camera

    pano = OcclusionProcessor(EquidistantPanorama(64, 32, 1.6))._above_horizon(4)
    assert pano.shape == (8, 16)
    assert pano[:4].all() and not pano[4:].any()
    camera = make_camera(480, 270)
    above = OcclusionProcessor(camera)._above_horizon(1)
    _, depth = camera.ground_hit(np.full(270, 240.5), np.arange(270) + 0.5)
    assert np.array_equal(above[:, 240], np.isnan(depth))
    assert above[0].all() and not above[-1].any()
