"""Surface labels packed into groups that one blur smooths at once (issue 20).

:func:`bake.denoise.smooth_within_labels` blurs each surface on its own, so that no light
bleeds from one surface onto another. Done one label at a time in the label's bounding box,
that cost the palace's lightmap (10,146 labels, most of them a few texels of corrugated roof
in charts scattered over the atlas) 490 atlas-sized blurs per channel: its bounding boxes
summed to 490 times the atlas (docs/benchmarks.md, "issue 20, 2026-12-05").

A Gaussian cut at ``radius`` texels reads, at a texel, only the texels within ``radius`` of
it (Chebyshev distance). So a label's texels fall into *clusters*: texels of one label
joined when within ``radius`` of each other; a cluster's fit reads its own texels only.
Clusters that lie more than ``radius`` apart can share one image and one blur: each texel's
blur then reads exactly the values it read in its own cluster's box, and OpenCV's separable
filter sums the same products in the same order wherever the window lies in the image (it
pads with zeros at the border, as the box's own crop did), so the values are the same bits.
The clusters are coloured greedily so that clusters of one colour lie more than ``radius``
apart: 31 colours for the palace's lightmap, hence 31 blurs per channel instead of 490
atlases' worth.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import find_objects
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

# Labels are grouped only where their boxes add up to more than this many images: below it the
# groups' blurs, most of them over nearly the whole image, save little (the demo's lightmap,
# 15 images: 1.2 s against 2.0 s for 17 lights), and each label in its own box gives the bits
# of the code before the groups exactly. Groups give them too: the blurs pad each row past
# OpenCV's scalar row tail (bake.denoise.MomentBlurs), which rounded otherwise than its vector
# loop and made a texel within ``radius`` of the image's right edge differ in its last bit.
GROUPS_FROM = 32
# The continuation into buried texels (bake.contact) fits a few texels along contact lines
# from windows spanning a surface's scattered pieces: on the palace's lightmap 22 images of
# windows for 10 k texels, 1.9 in groups (0.9 s against 9.8 s for 4 lights, the same bits).
CONTINUATION_GROUPS_FROM = 4


def _window_shifts(radius: int):
    """The offsets (dy, dx) of half the (2 radius + 1)^2 window, without (0, 0): each pair
    of texels within ``radius`` of each other is met once."""
    for dy in range(0, radius + 1):
        for dx in range(-radius, radius + 1):
            if dy > 0 or dx > 0:
                yield dy, dx


def _shifted(image: np.ndarray, dy: int, dx: int, fill) -> np.ndarray:
    """``image`` (H, W) read at (y + dy, x + dx), ``fill`` outside it."""
    h, w = image.shape
    out = np.full((h, w), fill, dtype=image.dtype)
    out[max(0, -dy) : h - max(0, dy), max(0, -dx) : w - max(0, dx)] = image[
        max(0, dy) : h + min(0, dy), max(0, dx) : w + min(0, dx)
    ]
    return out


def label_clusters(labels: np.ndarray, radius: int) -> tuple[np.ndarray, np.ndarray]:
    """The clusters of ``labels`` (H, W) int (labels >= 0; others are no texel): texels of one
    label joined when within ``radius`` texels (Chebyshev) of each other.

    Returns ``(clusters, cluster_label)``: (H, W) int64, each texel's cluster (-1 where
    ``labels`` < 0), clusters numbered in the row-major order of their first texel; and
    (n,) the label of each cluster."""
    h, w = labels.shape
    valid = labels >= 0
    index = np.full((h, w), -1, np.int64)
    count = int(valid.sum())
    index[valid] = np.arange(count)
    first, second = [], []
    for dy, dx in _window_shifts(radius):
        other = _shifted(labels, dy, dx, -1)
        same = valid & (other == labels)
        first.append(index[same])
        second.append(_shifted(index, dy, dx, -1)[same])
    first, second = np.concatenate(first), np.concatenate(second)
    graph = coo_matrix((np.ones(len(first), np.int8), (first, second)), shape=(count, count))
    _, component = connected_components(graph.tocsr(), directed=False)
    # Renumber in the order of each component's first texel (deterministic, row-major).
    _, order, component = np.unique(component, return_index=True, return_inverse=True)
    rank = np.empty(len(order), np.int64)
    rank[np.argsort(order, kind="stable")] = np.arange(len(order))
    clusters = np.full((h, w), -1, np.int64)
    clusters[valid] = rank[component.ravel()]
    cluster_label = np.empty(len(order), labels.dtype)
    cluster_label[clusters[valid]] = labels[valid]
    return clusters, cluster_label


def cluster_colours(clusters: np.ndarray, n: int, radius: int) -> np.ndarray:
    """(n,) int: a colour per cluster of ``clusters`` (H, W, -1 outside; from
    :func:`label_clusters`) such that no two clusters of one colour have texels within
    ``radius`` of each other (greedy, the clusters with most neighbours first)."""
    codes = []
    for dy, dx in _window_shifts(radius):
        other = _shifted(clusters, dy, dx, -1)
        near = (clusters >= 0) & (other >= 0) & (other != clusters)
        codes.append(_pair_codes(clusters[near], other[near], n))
    return greedy_colours(codes, n)


def _pair_codes(a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    """Unordered pairs of clusters ``a``, ``b`` (m,) as unique codes ``min * n + max``."""
    return np.unique(np.minimum(a, b) * n + np.maximum(a, b))


def greedy_colours(codes: list, n: int) -> np.ndarray:
    """(n,) int: a colour per node 0..n-1 of the graph whose edges are ``codes`` (a list of
    arrays of :func:`_pair_codes`), no edge within one colour; greedy, the nodes with most
    neighbours first (deterministic)."""
    codes = np.unique(np.concatenate(codes)) if codes else np.zeros(0, np.int64)
    a, b = codes // n, codes % n
    adjacency = coo_matrix(
        (np.ones(2 * len(a), np.int8), (np.concatenate([a, b]), np.concatenate([b, a]))),
        shape=(n, n),
    ).tocsr()
    degree = np.diff(adjacency.indptr)
    colour = np.full(n, -1, np.int64)
    for c in np.argsort(-degree, kind="stable"):
        taken = colour[adjacency.indices[adjacency.indptr[c] : adjacency.indptr[c + 1]]]
        free = np.ones(len(taken) + 1, bool)
        free[taken[(taken >= 0) & (taken <= len(taken))]] = False
        colour[c] = int(np.argmax(free))
    return colour


def label_groups(labels: np.ndarray, radius: int, only: np.ndarray | None = None):
    """The texels of ``labels`` (H, W; >= 0) in groups that one blur of ``radius`` smooths
    at once (see the module's docstring): each label on its own in its box where those boxes
    add up to less than :data:`GROUPS_FROM` images (the demo's atlases: at most 15; the same
    bits as before the groups), or to less than the groups' boxes; else groups of clusters.

    ``only`` (H, W) bool or None: labels (or clusters) without any such texel are left out
    (a caller that needs the values there alone).

    Yields, per group: ``(box, texels)``: the group's bounding box grown by ``radius`` and
    clipped to the image, ``(y0, y1, x0, x1)``; its texels as flat indices into the box,
    (K,) int32, row-major."""
    h, w = labels.shape
    boxes = _grown_boxes(labels, radius)
    wanted = np.zeros(len(boxes), bool)
    wanted[np.unique(labels[(labels >= 0) if only is None else (labels >= 0) & only])] = True
    areas = (boxes[:, 1] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 2])
    per_label = int(areas[wanted].sum())
    groups = None
    if per_label > GROUPS_FROM * h * w:
        groups = list(_cluster_groups(labels, radius, only))
        if sum((y1 - y0) * (x1 - x0) for (y0, y1, x0, x1), _ in groups) >= per_label:
            groups = None
    if groups is not None:
        yield from groups
        return
    # Each label in its own box: the texels of every label at once, split by label.
    ys, xs = np.nonzero(labels >= 0)
    own = labels[ys, xs]
    order = np.argsort(own, kind="stable")  # row-major within each label
    ys, xs, own = ys[order], xs[order], own[order]
    starts = np.searchsorted(own, np.arange(len(boxes) + 1))
    for label in np.nonzero(wanted)[0]:
        y, x = ys[starts[label] : starts[label + 1]], xs[starts[label] : starts[label + 1]]
        y0, y1, x0, x1 = boxes[label]
        yield (y0, y1, x0, x1), ((y - y0) * (x1 - x0) + (x - x0)).astype(np.int32)


def label_boxes(labels: np.ndarray) -> list:
    """Each label's bounding box, ``(rows, columns)`` slices, indexed by label (``labels``
    (H, W) int; labels < 0 are no texel), from one pass over the image (None for a label
    without texels; a search of the whole image per label was 42 s of CPU per call on the
    palace's lightmap of 10,146 surfaces)."""
    return find_objects(np.where(labels >= 0, labels + 1, 0))


def _grown_boxes(labels: np.ndarray, radius: int) -> np.ndarray:
    """(L, 4) int64: each label's bounding box (y0, y1, x0, x1) grown by ``radius`` and
    clipped to the image (zeros for a label without texels)."""
    h, w = labels.shape
    found = label_boxes(labels)
    boxes = np.zeros((len(found), 4), np.int64)
    for label, box in enumerate(found):
        if box is not None:
            rows, columns = box
            boxes[label] = (max(rows.start - radius, 0), min(rows.stop + radius, h),
                            max(columns.start - radius, 0), min(columns.stop + radius, w))
    return boxes


def _cluster_groups(labels: np.ndarray, radius: int, only):
    """:func:`label_groups`' groups of clusters (one per colour of
    :func:`cluster_colours`)."""
    h, w = labels.shape
    clusters, cluster_label = label_clusters(labels, radius)
    n = len(cluster_label)
    keep = np.ones(n, bool)
    if only is not None:
        keep[:] = False
        keep[clusters[only & (clusters >= 0)]] = True
        clusters = np.where(clusters >= 0, np.where(keep[np.maximum(clusters, 0)],
                                                    clusters, -1), -1)
    if not keep.any():
        return
    colour = cluster_colours(clusters, n, radius)
    texel_colour = np.where(clusters >= 0, colour[np.maximum(clusters, 0)], -1)
    for c in range(int(colour[keep].max()) + 1):
        ys, xs = np.nonzero(texel_colour == c)
        if len(ys) == 0:
            continue
        y0, y1 = max(ys.min() - radius, 0), min(ys.max() + radius + 1, h)
        x0, x1 = max(xs.min() - radius, 0), min(xs.max() + radius + 1, w)
        yield (y0, y1, x0, x1), ((ys - y0) * (x1 - x0) + (xs - x0)).astype(np.int32)


def continuation_fits(labels: np.ndarray, radius: int, rings: int):
    """The fits of :func:`bake.contact.continue_into_buried`: for each surface (visible
    texels ``s >= 0``, buried ones ``-2 - s`` in ``labels`` (H, W)), its buried texels within
    ``rings`` texels (Chebyshev) of a visible texel of it (the *targets*) fitted from its
    visible texels within ``radius``. Each surface on its own in the window its targets span
    (grown by ``radius``), as before issue 20, where those windows add up to less than
    :data:`CONTINUATION_GROUPS_FROM` images or than the groups' boxes; else in groups as
    :func:`label_groups` (clusters of a surface's targets and the visible texels within
    ``radius`` of them, clusters of a colour never within ``radius`` of another's targets).

    Yields, per fit: ``(box, visible, targets)``: the box ``(y0, y1, x0, x1)``; the visible
    texels it reads and the targets, each as flat indices into the box, (K,) int32."""
    h, w = labels.shape
    surface = np.where(labels <= -2, -2 - labels, labels)
    buried = labels <= -2
    target = np.zeros((h, w), bool)
    for dy in range(-rings, rings + 1):
        for dx in range(-rings, rings + 1):
            if dy or dx:
                target |= buried & (_shifted(labels, dy, dx, -1) == surface)
    if not target.any():
        return
    windows = _grown_boxes(np.where(target, surface, -1), radius)  # (L, 4)
    present = np.zeros(len(windows), bool)
    present[np.unique(surface[target])] = True
    areas = (windows[:, 1] - windows[:, 0]) * (windows[:, 3] - windows[:, 2])
    visible = labels >= 0
    per_label = int(areas[present].sum())
    if per_label > CONTINUATION_GROUPS_FROM * h * w:
        groups = list(_continuation_groups(labels, surface, target, radius))
        if sum((b[1] - b[0]) * (b[3] - b[2]) for b, _, _ in groups) < per_label:
            yield from groups
            return
    ty, tx = np.nonzero(target)
    vy, vx = np.nonzero(visible)
    t_own, v_own = surface[ty, tx], labels[vy, vx]
    t_order, v_order = np.argsort(t_own, kind="stable"), np.argsort(v_own, kind="stable")
    ty, tx, t_own = ty[t_order], tx[t_order], t_own[t_order]
    vy, vx, v_own = vy[v_order], vx[v_order], v_own[v_order]
    t_start = np.searchsorted(t_own, np.arange(len(windows) + 1))
    v_start = np.searchsorted(v_own, np.arange(len(windows) + 1))
    for label in np.nonzero(present)[0]:
        y0, y1, x0, x1 = windows[label]
        y, x = vy[v_start[label] : v_start[label + 1]], vx[v_start[label] : v_start[label + 1]]
        inside = (y >= y0) & (y < y1) & (x >= x0) & (x < x1)
        parts = []
        for yy, xx in ((y[inside], x[inside]),
                       (ty[t_start[label] : t_start[label + 1]],
                        tx[t_start[label] : t_start[label + 1]])):
            parts.append(((yy - y0) * (x1 - x0) + (xx - x0)).astype(np.int32))
        yield (y0, y1, x0, x1), parts[0], parts[1]


def _continuation_groups(labels, surface, target, radius: int):
    """:func:`continuation_fits` by groups of clusters (one per colour)."""
    h, w = labels.shape
    visible = labels >= 0
    index = np.full((h, w), -1, np.int64)
    nodes = visible | target
    index[nodes] = np.arange(int(nodes.sum()))
    first, second = [], []
    shifts = [(dy, dx) for dy in range(-radius, radius + 1) for dx in range(-radius, radius + 1)
              if dy or dx]
    for dy, dx in shifts:  # a target and the visible texels of its surface it reads
        reads = target & (_shifted(labels, dy, dx, -1) == surface)
        first.append(index[reads])
        second.append(_shifted(index, dy, dx, -1)[reads])
    first, second = np.concatenate(first), np.concatenate(second)
    count = int(nodes.sum())
    graph = coo_matrix((np.ones(len(first), np.int8), (first, second)), shape=(count, count))
    _, component = connected_components(graph.tocsr(), directed=False)
    member = np.zeros(count, bool)
    member[first] = member[second] = True  # targets and the visible texels they read
    clusters = np.full((h, w), -1, np.int64)
    clusters[nodes] = np.where(member, component, -1)
    n = int(component.max()) + 1
    codes = []
    for dy, dx in shifts:  # a target and another cluster's visible texel within reach
        other = _shifted(np.where(visible, clusters, -1), dy, dx, -1)
        near = target & (other >= 0) & (other != clusters)
        codes.append(_pair_codes(clusters[near], other[near], n))
    colour = greedy_colours(codes, n)
    texel_colour = np.where(clusters >= 0, colour[np.maximum(clusters, 0)], -1)
    for c in np.unique(texel_colour[target]):
        ty, tx = np.nonzero(target & (texel_colour == c))
        y0, y1 = max(ty.min() - radius, 0), min(ty.max() + radius + 1, h)
        x0, x1 = max(tx.min() - radius, 0), min(tx.max() + radius + 1, w)
        read = visible[y0:y1, x0:x1] & (texel_colour[y0:y1, x0:x1] == c)
        vy, vx = np.nonzero(read)
        vy, vx = vy + y0, vx + x0
        yield ((y0, y1, x0, x1), ((vy - y0) * (x1 - x0) + (vx - x0)).astype(np.int32),
               ((ty - y0) * (x1 - x0) + (tx - x0)).astype(np.int32))
