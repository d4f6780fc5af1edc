"""The bounce's smoothing within a surface (bake/denoise.py), against known answers: a plane
(a linear ramp of the bounce) must come back exactly from the local linear fit, at the
surface's edges too, where the plain normalised Gaussian is biased inward; buried texels
take their nearest open neighbour's value."""

from __future__ import annotations

import numpy as np
import pytest

from bake.denoise import fill_from_nearest, smooth_within_labels

SIGMA = 1.5


def ramp_surface(h=20, w=30):
    """A rectangle (label 0) inside an empty border (-1) and a second surface (label 1) next
    to it with a different ramp; values (H, W, 2): two channels, two slopes."""
    labels = np.full((h, w), -1)
    labels[2:h - 2, 2:18] = 0
    labels[2:h - 2, 18:w - 2] = 1
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    values = np.stack([10.0 + 2.0 * xx - 0.5 * yy, 50.0 + 0.25 * xx + 1.0 * yy], -1)
    values[labels == 1] += 100.0  # a step between the two surfaces: never blended
    values[labels < 0] = 0.0
    return labels, values.astype(np.float32)


def test_a_linear_bounce_comes_back_exactly_with_the_linear_fit_at_the_edges_too():
    labels, values = ramp_surface()
    out = smooth_within_labels(values, labels, SIGMA, order=1)
    inside = labels >= 0
    assert np.allclose(out[inside], values[inside], rtol=1e-5, atol=1e-3)
    assert np.all(out[~inside] == 0.0)  # untouched


def test_the_plain_mean_is_biased_at_an_edge_and_exact_inside():
    labels, values = ramp_surface()
    out = smooth_within_labels(values, labels, SIGMA, order=0)
    # Deep inside (3 sigma from every edge) a symmetric kernel returns a plane exactly.
    assert np.allclose(out[8:12, 7:13], values[8:12, 7:13], atol=2e-3)
    # At the left edge of surface 0 (slope +2 per texel in x) it returns more: the mean of
    # the inward values, slope times the mean offset of a half Gaussian sampled at texels
    # 0, 1, 2, ... (1.82; 2 sigma sqrt(2 / pi) = 2.39 for a continuous one).
    k = np.arange(0, 20)
    g = np.exp(-(k**2) / (2 * SIGMA**2))
    bias = out[10, 2, 0] - values[10, 2, 0]
    assert bias == pytest.approx(2.0 * (k * g).sum() / g.sum(), rel=0.02)


def test_a_one_texel_strip_falls_back_to_its_own_mean_across():
    labels = np.full((9, 40), -1)
    labels[4, 2:38] = 0
    values = np.zeros((9, 40, 1), np.float32)
    values[4, 2:38, 0] = 5.0 + 0.5 * np.arange(36)
    out = smooth_within_labels(values, labels, SIGMA, order=1)
    assert np.all(np.isfinite(out))
    assert np.allclose(out[4, 2:38, 0], values[4, 2:38, 0], rtol=1e-5, atol=1e-3)


def test_the_linear_fit_never_goes_below_zero():
    labels = np.zeros((12, 12), int)
    values = np.zeros((12, 12, 1), np.float32)
    values[:, :3, 0] = 100.0  # a cliff: a plane through it undershoots on the far side
    out = smooth_within_labels(values, labels, SIGMA, order=1)
    assert out.min() >= 0.0


def test_buried_texels_take_the_nearest_open_value_of_their_own_surface():
    labels = np.zeros((6, 8), int)
    labels[:, 6:] = 1
    keep = np.ones((6, 8), bool)
    keep[:, 2:6] = False  # surface 0's texels at x 2..5 buried
    image = np.arange(48, dtype=np.float32).reshape(6, 8, 1) * 1.0
    expected = image.copy()
    expected[:, 2:6, 0] = image[:, 1:2, 0]  # x = 1 is nearest for every buried texel
    out = fill_from_nearest(image.copy(), labels, keep)
    assert np.array_equal(out, expected)  # surface 1 (x >= 6) never lends its values


def test_a_plan_keeps_per_texel_weights_only_and_gives_the_same_values():
    """The plan a stack's blocks share keeps each label's fit weights, K per weight (K its
    texels), not box-sized images: on an atlas of 400 labels each scattered over the whole
    image (every box the whole atlas) it holds at most the three plane weights per labelled
    texel (float64) and each texel's place and coordinates (three int32); and the values are
    the plain call's, bit for bit, block after block."""
    rng = np.random.default_rng(4)
    h, w = 60, 80
    labels = rng.integers(0, 400, (h, w))
    labels[rng.random((h, w)) < 0.1] = -1
    values = rng.uniform(0.0, 5.0, (h, w, 3)).astype(np.float32)
    plan: dict = {}
    for block in (values, 2.0 * values):
        planned = smooth_within_labels(block, labels, SIGMA, order=1, plan=plan)
        assert np.array_equal(planned, smooth_within_labels(block, labels, SIGMA, order=1))
    held = _array_bytes(plan)
    labelled = int((labels >= 0).sum())
    assert held <= (3 * 8 + 3 * 4) * labelled, (held, labelled)
    # Box-sized images per label, as the plan held before, would be 400 x 60 x 80 x 21 bytes.
    assert held < 400 * h * w * 21 / 50


def _array_bytes(held) -> int:
    """The bytes of every numpy array in nested lists, tuples and dicts."""
    if isinstance(held, np.ndarray):
        return held.nbytes
    if isinstance(held, dict):
        held = list(held.values())
    if isinstance(held, (list, tuple)):
        return sum(_array_bytes(item) for item in held)
    return 0


def test_a_moment_blur_is_the_same_bits_whatever_the_channels_and_the_images_end():
    """The fit's blurs (bake.denoise.MomentBlurs) give a texel the same bits whether its
    channel is blurred alone or with 1 to 128 others, and wherever its window lies: a
    stack's blocks of lights, and groups of labels, then give the values of the whole
    (OpenCV's scalar row tail, without the padding, rounded the last texels of a row
    otherwise). The first moment of a ramp is the kernel's own second moment, away from the
    image's edges."""
    from bake.denoise import MomentBlurs

    blurs = MomentBlurs(SIGMA)
    blur = blurs.blur
    rng = np.random.default_rng(4)
    for h, w in [(37, 53), (12, 7), (64, 129)]:
        values = rng.uniform(0.0, 1.0, (h, w, 128)).astype(np.float32)
        wider = np.concatenate([values, np.zeros((h, blurs.radius, 128), np.float32),
                                rng.uniform(0.0, 1.0, (h, 40, 128)).astype(np.float32)], 1)
        for name in blurs.kernels:
            whole = blur(name, values)
            assert np.array_equal(blur(name, wider)[:, :w], whole)
            for channels in (1, 2, 3, 5, 21, 64, 127):
                part = blur(name, np.ascontiguousarray(values[:, :, :channels]))
                assert np.array_equal(part, whole[:, :, :channels]), (h, w, name, channels)
    g = np.exp(-0.5 * (np.arange(-blurs.radius, blurs.radius + 1) / SIGMA) ** 2)
    second_moment = (g * np.arange(-blurs.radius, blurs.radius + 1) ** 2).sum() / g.sum()
    ramp = np.tile(np.arange(40, dtype=np.float64), (30, 1))
    inner = blur("x", ramp)[blurs.radius:-blurs.radius, blurs.radius:-blurs.radius]
    assert np.allclose(inner, second_moment, rtol=1e-12)
