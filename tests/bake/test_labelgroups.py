"""Labels smoothed a group at a time (bake.labelgroups): the same values as one label at a
time in its own box, on atlases of many labels scattered in small pieces (issue 20)."""

import numpy as np
import pytest

from bake.contact import continued_labels
from bake.denoise import fill_from_nearest, smooth_label_by_label, smooth_within_labels
from bake.labelgroups import GROUPS_FROM, cluster_colours, label_clusters, label_groups

SIGMA = 1.5  # radius 5


def _scattered(seed: int, h: int = 90, w: int = 120, count: int = 300, piece: int = 3):
    """An atlas of ``count`` labels, each in pieces of ``piece`` x ``piece`` texels dropped
    anywhere (a label's box spans most of the atlas, as the palace's roofs), and gutters."""
    rng = np.random.default_rng(seed)
    labels = np.full((h, w), -1, np.int64)
    for y in range(0, h - piece + 1, piece + 1):
        for x in range(0, w - piece + 1, piece):
            labels[y : y + piece, x : x + piece] = rng.integers(0, count)
    return labels


def test_clusters_join_a_labels_texels_within_the_radius_only():
    """Known answer: label 0 in three pieces, two 3 texels apart (one cluster at radius 3,
    two at radius 2), one far off; label 1 between them joins none of label 0's."""
    labels = np.full((5, 30), -1)
    labels[2, 0] = labels[2, 3] = labels[2, 20] = 0
    labels[2, 1] = 1
    clusters, owner = label_clusters(labels, 3)
    assert clusters[2, 0] == clusters[2, 3] != clusters[2, 20]
    assert clusters[2, 1] not in (clusters[2, 0], clusters[2, 20])
    assert list(owner) == [0, 1, 0]  # numbered by first texel, row-major
    clusters, owner = label_clusters(labels, 2)
    assert len({clusters[2, 0], clusters[2, 3], clusters[2, 20]}) == 3
    assert (clusters[labels < 0] == -1).all()


def test_clusters_of_one_colour_lie_farther_apart_than_the_radius():
    labels = _scattered(1)
    radius = 5
    clusters, owner = label_clusters(labels, radius)
    colour = cluster_colours(clusters, len(owner), radius)
    texel_colour = np.where(clusters >= 0, colour[np.maximum(clusters, 0)], -1)
    ys, xs = np.nonzero(clusters >= 0)
    for y, x in zip(ys[::7], xs[::7], strict=True):
        window = (slice(max(y - radius, 0), y + radius + 1),
                  slice(max(x - radius, 0), x + radius + 1))
        same = texel_colour[window] == texel_colour[y, x]
        assert (clusters[window][same] == clusters[y, x]).all()
    assert colour.max() + 1 < len(owner) / 10  # far fewer blurs than clusters


@pytest.mark.parametrize("order", [0, 1])
def test_groups_give_the_label_by_label_values_bit_for_bit(order):
    """300 labels in 3 x 3 pieces over a 90 x 120 atlas (boxes adding up to about 270
    atlases: groups are used), 40 channels: every value equal to one label at a time in its
    own box, to the last bit, also within the kernel's radius of the image's right edge
    (where OpenCV's row tail rounded otherwise before the blurs were padded)."""
    labels = _scattered(2)
    h, w = labels.shape
    boxes = sum(
        (min(ys.max() + 6, h) - max(ys.min() - 5, 0))
        * (min(xs.max() + 6, w) - max(xs.min() - 5, 0))
        for ys, xs in (np.nonzero(labels == k) for k in np.unique(labels[labels >= 0]))
    )
    assert boxes > GROUPS_FROM * h * w
    rng = np.random.default_rng(3)
    values = rng.uniform(0.0, 4.0, (h, w, 40)).astype(np.float32)
    grouped = smooth_within_labels(values, labels, SIGMA, order=order)
    reference = smooth_label_by_label(values, labels, SIGMA, order=order)
    assert np.array_equal(grouped, reference)
    assert np.array_equal(grouped[labels < 0], values[labels < 0])


def test_few_labels_keep_each_its_own_box_bit_for_bit():
    """Where the labels' boxes add up to little (the demo's atlases) each label is fitted in
    its own box: the bits of the code before the groups."""
    labels = np.full((40, 50), -1)
    labels[2:20, 3:25] = 0
    labels[22:38, 3:45] = 1
    labels[2:20, 28:48] = 2
    groups = list(label_groups(labels, 5))
    assert len(groups) == 3
    values = np.random.default_rng(5).uniform(0, 1, (40, 50, 6)).astype(np.float32)
    for order in (0, 1):
        assert np.array_equal(smooth_within_labels(values, labels, SIGMA, order=order),
                              smooth_label_by_label(values, labels, SIGMA, order=order))


def test_only_the_texels_asked_for_get_the_same_values():
    labels = _scattered(6)
    only = np.zeros(labels.shape, bool)
    only[30:50, 40:70] = True
    values = np.random.default_rng(7).uniform(0, 1, labels.shape + (3,)).astype(np.float32)
    some = smooth_within_labels(values, labels, 1.0, order=1, only=only)
    every = smooth_within_labels(values, labels, 1.0, order=1)
    assert np.array_equal(some[only], every[only])
    plan: dict = {}
    for block in (values, 3 * values):  # a plan with ``only`` kept apart from one without
        assert np.array_equal(smooth_within_labels(block, labels, 1.0, 1, plan, only),
                              smooth_within_labels(block, labels, 1.0, 1, None, only))
        assert np.array_equal(smooth_within_labels(block, labels, 1.0, 1, plan),
                              smooth_within_labels(block, labels, 1.0, 1))


def test_boxes_from_one_pass_give_the_whole_image_searchs_answers():
    """continued_labels and fill_from_nearest find each surface's box in one pass now; their
    answers are those of a search of the whole image per label."""
    labels = _scattered(8, count=40)
    rng = np.random.default_rng(9)
    buried = (labels >= 0) & (rng.random(labels.shape) < 0.3)
    marked = np.where(buried, -2 - labels, labels)
    reference = marked >= 0
    import cv2

    surface = np.where(marked <= -2, -2 - marked, marked)
    for label in np.unique(marked[marked <= -2]):
        label = -2 - label
        near = cv2.dilate((marked == label).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        reference |= near & (surface == label)
    assert np.array_equal(continued_labels(marked), reference)
    image = rng.uniform(0, 1, labels.shape + (2,)).astype(np.float32)
    keep = reference
    filled = fill_from_nearest(image.copy(), surface, keep)
    assert np.array_equal(filled[keep], image[keep])
    expected = image.copy()  # the code before: each label's box by a search of the image
    from scipy.ndimage import distance_transform_edt

    for label in np.unique(surface[(surface >= 0) & ~keep]):
        ys, xs = np.nonzero(surface == label)
        y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
        own = surface[y0:y1, x0:x1] == label
        source = own & keep[y0:y1, x0:x1]
        if not source.any():
            continue
        _, (iy, ix) = distance_transform_edt(~source, return_indices=True)
        ty, tx = np.nonzero(own & ~source)
        expected[y0 + ty, x0 + tx] = expected[y0 + iy[ty, tx], x0 + ix[ty, tx]]
    assert np.array_equal(filled, expected)


def _buried_scattered(seed: int):
    """:func:`_scattered` with a quarter of the texels buried (``-2 - label``)."""
    labels = _scattered(seed, count=120)
    rng = np.random.default_rng(seed + 100)
    buried = (labels >= 0) & (rng.random(labels.shape) < 0.25)
    return np.where(buried, -2 - labels, labels)


def test_continuation_in_groups_gives_each_surfaces_own_window_values(monkeypatch):
    """The continuation into buried texels (bake.contact) fitted in groups of surfaces'
    pieces gives the values of each surface fitted in its own window, the same bits (at the
    image's right edge too); a plan gives the same values again."""
    from bake import contact, labelgroups

    labels = _buried_scattered(10)
    values = np.random.default_rng(11).uniform(0, 2, labels.shape + (4, 3)).astype(np.float32)
    monkeypatch.setattr(labelgroups, "CONTINUATION_GROUPS_FROM", 10**9)
    own = contact.continue_into_buried(values, labels)
    monkeypatch.setattr(labelgroups, "CONTINUATION_GROUPS_FROM", 0)
    plan: dict = {}
    grouped = contact.continue_into_buried(values, labels, plan=plan)
    boxes = [fit[0] for fit in plan[(contact.FIT_SIGMA_TEXELS, contact.RINGS)]]
    assert len(boxes) < len(np.unique(labels[labels <= -2])) / 5  # groups, not surfaces
    assert np.array_equal(grouped, own)
    assert np.array_equal(contact.continue_into_buried(values, labels, plan=plan), grouped)
    changed = np.any(grouped != values, axis=(2, 3))
    assert changed.sum() > 100 and (labels[changed] <= -2).all()  # buried texels only
