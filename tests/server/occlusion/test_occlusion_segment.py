"""The graph cut minimises the energy exactly, and the real-time shortcuts change no label."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from server.occlusion.background import block_any
from server.occlusion.colour import colour_index, table_costs
from server.occlusion.graphcut import graph_cut
from server.occlusion.pipeline import OcclusionProcessor
from server.occlusion.segment import regions_of_interest
from server.occlusion.settings import OcclusionSettings


def energy(labels, cost_fg, cost_bg, w_right, w_down):
    e = np.where(labels, cost_fg, cost_bg).sum()
    e += (w_right[:, :-1] * (labels[:, :-1] != labels[:, 1:])).sum()
    e += (w_down[:-1] * (labels[:-1] != labels[1:])).sum()
    return e


@pytest.mark.parametrize("seed", range(6))
def test_graph_cut_finds_the_minimum_energy_labelling(seed):
    rng = np.random.default_rng(seed)
    h, w = 3, 4  # 4096 labellings: brute force is exact
    cost_fg = rng.uniform(0, 10, (h, w))
    cost_bg = rng.uniform(0, 10, (h, w))
    w_right = rng.uniform(0, 6, (h, w))
    w_down = rng.uniform(0, 6, (h, w))
    terms = (cost_fg, cost_bg, w_right, w_down)

    def brute_force(free):
        best = np.inf
        for bits in itertools.product([False, True], repeat=int(free.sum())):
            labels = np.zeros((h, w), bool)
            labels[free] = bits
            best = min(best, energy(labels, *terms))
        return best

    everywhere = np.ones((h, w), bool)
    labels = graph_cut(*terms)
    assert energy(labels, *terms) == pytest.approx(brute_force(everywhere), abs=1e-6)
    # With some pixels fixed to background, the cut is the minimum over the others.
    free = rng.random((h, w)) < 0.7
    best_free = brute_force(free)
    labels = graph_cut(*terms, free)
    assert not labels[~free].any()
    assert energy(labels, *terms) == pytest.approx(best_free, abs=1e-6)


@pytest.mark.parametrize("seed", range(4))
def test_deciding_nodes_before_the_cut_keeps_the_minimum(seed):
    """Nodes decided by their own costs (graphcut._decide) take the label of the plain cut
    over every node: a blob that prefers person on a field that prefers background, noisy
    costs, strong edges, a random free set; same energy, same labels."""
    rng = np.random.default_rng(100 + seed)
    h, w = 60, 80
    yy, xx = np.mgrid[0:h, 0:w]
    blob = (yy - 30) ** 2 / 300 + (xx - 40) ** 2 / 500 < 1
    cost_fg = np.where(blob, 2.0, 14.0) + rng.normal(0, 6, (h, w))
    cost_bg = np.where(blob, 20.0, 3.0) + rng.normal(0, 6, (h, w))
    w_right = rng.uniform(0, 16, (h, w))  # strong edges: a quarter to a third undecided
    w_down = rng.uniform(0, 16, (h, w))
    free = rng.random((h, w)) < 0.95
    terms = (cost_fg, cost_bg, w_right, w_down)
    decided = graph_cut(*terms, free)
    plain = graph_cut(*terms, free, decide=False)
    assert 500 < np.count_nonzero(plain) < h * w - 500  # both labels in play
    assert energy(decided, *terms) == pytest.approx(energy(plain, *terms), abs=1e-6)
    assert np.array_equal(decided, plain)


def test_regions_are_padded_merged_and_small_ones_dropped():
    coarse = np.zeros((20, 40), bool)
    coarse[2:6, 3:6] = True  # 12 coarse pixels: 192 at scale 4
    coarse[5:9, 7:9] = True  # overlaps the first once padded
    coarse[15, 30] = True  # one coarse pixel: 16 full-resolution pixels, noise
    boxes = regions_of_interest(coarse, scale=4, pad_px=4, min_px=48, shape=(80, 160))
    assert boxes == [(4, 40, 8, 40)]


def test_regions_and_band_give_the_labels_of_the_whole_frame_cut(standard_site,
                                                                  standard_virtual_depth):
    """The optimisation is exact in practice: same energy, same labels, a fraction of the
    graph."""
    fast = OcclusionProcessor(standard_site.camera, standard_virtual_depth)
    slow = OcclusionProcessor(standard_site.camera, standard_virtual_depth,
                              OcclusionSettings(full_frame=True))
    differ = total = 0
    for i in range(40):
        frame = standard_site.frame(i).image
        a, b = fast.process(frame), slow.process(frame)
        if a.learning:
            continue
        total += np.count_nonzero(a.person_mask | b.person_mask)
        differ += np.count_nonzero(a.person_mask != b.person_mask)
    assert total > 10_000
    assert differ / total < 0.002, differ / total


@pytest.mark.parametrize("scale", [2, 3, 4, 8])
def test_block_any_is_any_pixel_of_each_block(scale):
    """The word-wide block test against numpy's any over each block (remainders dropped)."""
    rng = np.random.default_rng(scale)
    mask = rng.random((67, 133)) < 0.01
    h, w = 67 // scale, 133 // scale
    expected = mask[: h * scale, : w * scale].reshape(h, scale, w, scale).any(axis=(1, 3))
    assert expected.any() and not expected.all()
    assert np.array_equal(block_any(mask, scale), expected)
    assert np.array_equal(block_any(mask.view(np.uint8) * np.uint8(255), scale), expected)


@pytest.mark.parametrize("bits", [4, 5, 6])
def test_table_costs_read_the_table_at_each_colour_bin(bits):
    """The compiled look-up against colour_index and numpy's gather, on a box view."""
    rng = np.random.default_rng(bits)
    frame = rng.integers(0, 256, (40, 50, 3), dtype=np.uint8)
    table = rng.normal(size=1 << (3 * bits)).astype(np.float32)
    box = frame[5:31, 7:43]
    expected = -table[colour_index(box.reshape(-1, 3), bits)].reshape(box.shape[:2])
    assert np.array_equal(table_costs(box, table, bits), expected)
