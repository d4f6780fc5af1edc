"""The exact minimum of a binary grid energy by one s-t min cut, on the nodes left undecided.

For labels ``x`` (1 person, 0 background) of an (h, w) grid::

    E(x) = sum_p cost_person_p x_p + cost_background_p (1 - x_p)
           + sum_(p, q) w_pq [x_p != x_q]            (4-neighbours, w_pq >= 0)

is submodular, and one s-t min cut (PyMaxflow, Boykov-Kolmogorov) gives its exact minimum.
Most nodes need no cut: a node whose preference for one label, counting the edges to
neighbours already decided, is larger than the sum of its edges to the undecided ones takes
that label in *every* minimum (flipping it would cost more than any neighbour can give
back). Deciding such a node adds its edges to its neighbours' costs, which may decide them in
turn (the persistency of roof duality, here by a work list: each node is looked at again
only when a neighbour is decided). On the occlusion's regions this decides most of the
nodes (the standard sequence through H.264 at 1024x512, its last 35 frames: 17 % of 16 000
nodes a region left); the
graph is built over the rest only, its edges to decided neighbours as unary costs, and the
cut's labels are those of the whole graph's cut wherever the minimum is unique (ties aside,
the same labels: ``tests/server/occlusion/test_occlusion_segment.py``).

Building the graph in numpy and PyMaxflow took about twice the max-flow itself; the
decisions and the graph's arrays are made here in one compiled pass (Numba).
"""

from __future__ import annotations

import maxflow
import numba
import numpy as np

# Compiled code is cached next to this file (``__pycache__``), as bake/tracing_loops.py's.
_jit = numba.njit(cache=True, nogil=True, fastmath=False)

_LIVE, _BACKGROUND, _PERSON = 2, 0, 1


@_jit
def _decide(cost_person, cost_background, w_right, w_down, free, state, a, b, settle):
    """Decide the nodes whose label is the same in every minimum; fill ``state`` (h, w)
    int8 (0 background, 1 person, 2 undecided) and ``a``, ``b`` (h, w) float64, the costs
    of person and of background of the undecided nodes with their edges to decided
    neighbours included. ``settle`` False decides nothing but the non-free pixels (all
    background). Returns how many are undecided."""
    h, w = cost_person.shape
    s = np.zeros((h, w))  # sum of edges to undecided neighbours
    queued = np.zeros((h, w), dtype=np.bool_)
    stack = np.empty(h * w, dtype=np.int64)
    top = 0
    for y in range(h):
        for x in range(w):
            if free[y, x]:
                state[y, x] = _LIVE
                a[y, x] = cost_person[y, x]
                b[y, x] = cost_background[y, x]
            else:
                state[y, x] = _BACKGROUND
    for y in range(h):  # edges to fixed background: cut when the node is a person
        for x in range(w):
            if not free[y, x]:
                continue
            if x + 1 < w:
                if free[y, x + 1]:
                    s[y, x] += w_right[y, x]
                else:
                    a[y, x] += w_right[y, x]
            if x > 0:
                if free[y, x - 1]:
                    s[y, x] += w_right[y, x - 1]
                else:
                    a[y, x] += w_right[y, x - 1]
            if y + 1 < h:
                if free[y + 1, x]:
                    s[y, x] += w_down[y, x]
                else:
                    a[y, x] += w_down[y, x]
            if y > 0:
                if free[y - 1, x]:
                    s[y, x] += w_down[y - 1, x]
                else:
                    a[y, x] += w_down[y - 1, x]
            stack[top] = y * w + x
            top += 1
            queued[y, x] = True
    live = top
    if not settle:
        return live
    while top > 0:
        top -= 1
        k = stack[top]
        y, x = k // w, k % w
        queued[y, x] = False
        if state[y, x] != _LIVE:
            continue
        d = a[y, x] - b[y, x]
        if d > s[y, x]:
            label = _BACKGROUND
        elif -d > s[y, x]:
            label = _PERSON
        else:
            continue
        state[y, x] = label
        live -= 1
        for j in range(4):  # its edges to undecided neighbours become their unary costs
            if j == 0:
                ny, nx, wt = y, x + 1, w_right[y, x] if x + 1 < w else 0.0
            elif j == 1:
                ny, nx, wt = y, x - 1, w_right[y, x - 1] if x > 0 else 0.0
            elif j == 2:
                ny, nx, wt = y + 1, x, w_down[y, x] if y + 1 < h else 0.0
            else:
                ny, nx, wt = y - 1, x, w_down[y - 1, x] if y > 0 else 0.0
            if ny < 0 or ny >= h or nx < 0 or nx >= w or state[ny, nx] != _LIVE:
                continue
            s[ny, nx] -= wt
            if label == _BACKGROUND:
                a[ny, nx] += wt  # the neighbour pays the edge if it is a person
            else:
                b[ny, nx] += wt
            if not queued[ny, nx]:
                queued[ny, nx] = True
                stack[top] = ny * w + nx
                top += 1
    return live


@_jit
def _labels(state, index, cut):
    """(h, w) bool: person where decided so, or where the cut (n,) put an undecided node."""
    h, w = state.shape
    out = np.zeros((h, w), dtype=np.bool_)
    for y in range(h):
        for x in range(w):
            i = index[y, x]
            out[y, x] = cut[i] if i >= 0 else state[y, x] == _PERSON
    return out


@_jit
def _graph(state, a, b, w_right, w_down, n):
    """The undecided nodes' graph: ``(index (h, w) int32, -1 if decided; source and sink
    capacities (n,); edge ends i, j (m,) and capacities (m,))``. Edges to decided
    neighbours are already in ``a`` and ``b``."""
    h, w = state.shape
    index = np.full((h, w), -1, dtype=np.int32)
    k = 0
    m = 0
    for y in range(h):
        for x in range(w):
            if state[y, x] == _LIVE:
                index[y, x] = k
                k += 1
                if x + 1 < w and state[y, x + 1] == _LIVE:
                    m += 1
                if y + 1 < h and state[y + 1, x] == _LIVE:
                    m += 1
    source = np.empty(n)
    sink = np.empty(n)
    ei = np.empty(m, dtype=np.int32)
    ej = np.empty(m, dtype=np.int32)
    cap = np.empty(m)
    e = 0
    for y in range(h):
        for x in range(w):
            i = index[y, x]
            if i < 0:
                continue
            low = min(a[y, x], b[y, x])
            source[i] = a[y, x] - low  # paid when the node ends in the sink: a person
            sink[i] = b[y, x] - low
            if x + 1 < w and index[y, x + 1] >= 0:
                ei[e] = i
                ej[e] = index[y, x + 1]
                cap[e] = w_right[y, x]
                e += 1
            if y + 1 < h and index[y + 1, x] >= 0:
                ei[e] = i
                ej[e] = index[y + 1, x]
                cap[e] = w_down[y, x]
                e += 1
    return index, source, sink, ei, ej, cap


def graph_cut(
    cost_person: np.ndarray,
    cost_background: np.ndarray,
    w_right: np.ndarray,
    w_down: np.ndarray,
    free: np.ndarray | None = None,
    decide: bool = True,
) -> np.ndarray:
    """Exact minimum of the grid energy above: (h, w) bool, True where person is chosen.

    ``cost_*`` (h, w) unary costs of each label; ``w_right``/``w_down`` (h, w) costs of a
    label change to the right / lower neighbour (last column / row ignored). ``free`` (h, w)
    bool: only these pixels may be people, all others are background (their edges to free
    pixels become unary costs); None: all. ``decide`` False builds the graph over every free
    pixel (the plain cut, for tests).
    """
    h, w = cost_person.shape
    if free is None:
        free = np.ones((h, w), dtype=bool)
    # Any float type and memory layout (the sums are float64 inside). Numba compiles for each
    # combination of layouts: the segmenter loads the two its cuts bring when it is made
    # (segment.Segmenter), since one met first in a frame stalled it by a 1.5 s compile;
    # contiguous copies instead cost 1-2 ms a frame.
    free = np.asarray(free, dtype=bool)
    state = np.empty((h, w), dtype=np.int8)
    a = np.empty((h, w))
    b = np.empty((h, w))
    n = _decide(cost_person, cost_background, w_right, w_down, free, state, a, b, decide)
    if n == 0:
        return state == _PERSON
    index, source, sink, ei, ej, cap = _graph(state, a, b, w_right, w_down, n)
    g = maxflow.GraphFloat(n, len(ei))
    nodes = g.add_nodes(n)
    g.add_edges(ei, ej, cap, cap)
    g.add_grid_tedges(nodes, source, sink)
    g.maxflow()
    return _labels(state, index, g.get_grid_segments(nodes))
