"""The shadow ratio's layer rule makes each move from the sky's lit values only
(``RatioRefinement.move``, docs/benchmarks.md "The ratio rule's moves at the lit values"):
the same values, bit for bit, as the product over the whole (T, 3) loss gathered at the lit
texels, ordered by channel; and the same layers as the rule stated with those moves."""

import numpy as np
import pytest

from bake import lowrank, refinement
from tests.bake.test_compact import _ratio_layers_as_stated


def _moves_over_whole_loss(rule, losses, V, j, s):
    """Layer j's move on sky s as the rule made it before, over the whole (T, 3) loss, then
    put in the order ``move`` gives (the lit values by channel, each in the texels' order)."""
    lit = rule.lit[s]
    change = (losses[j] * (V[:, j] @ rule.rests[s]).astype(np.float32))[lit]
    D, X = rule.d[s], rule.delta[s]
    moves = change / D if rule.role == "delta" else -X * change / D**2
    channel = np.nonzero(lit)[1]  # the mask's order
    return moves[np.argsort(channel, kind="stable")]


def _case(rng, role, T=60, skies=4, n=6, k=7, dtype=np.float32, low=-0.1):
    lit = [rng.uniform(size=(T, 3)) < p for p in np.linspace(0.0, 1.0, skies)]
    rule = refinement.RatioRefinement(
        role, [rng.uniform(0.0, 1.0, (n, 3)) for _ in range(skies)], lit,
        [np.maximum(rng.uniform(low, 2.0, int(m.sum())), 1e-12).astype(dtype) for m in lit],
        [rng.uniform(0.0, 1.0, int(m.sum())).astype(dtype) for m in lit],
        [1.0] * skies, tolerance=0.02)
    f = lowrank.Factors(k, np.zeros((T, 3, k), np.float32),
                        rng.uniform(-1.0, 1.0, (n, k)).astype(np.float32), {})
    losses = (rng.normal(size=(k, T, 3)) * rng.uniform(0.0005, 0.006, (k, 1, 1))
              ).astype(np.float32)
    return rule, f, losses


@pytest.mark.parametrize("role", ["d", "delta"])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_moves_equal_the_whole_loss_products_bit_for_bit(role, dtype):
    """Every layer's move on every sky (one sky with nothing lit, one with everything) equals
    the product over the whole loss gathered at the lit texels, in value and dtype."""
    rng = np.random.default_rng(11)
    rule, f, losses = _case(rng, role, dtype=dtype)
    for s in range(len(rule.rests)):
        for j in range(f.k):
            got = rule.move(losses, f.V, j, s)
            expected = _moves_over_whole_loss(rule, losses, f.V, j, s)
            assert got.dtype == expected.dtype
            assert got.tobytes() == expected.tobytes(), (s, j)


@pytest.mark.parametrize("kept_bytes", [0, 1000])
def test_skies_past_the_kept_bytes_make_their_moves_as_before(kept_bytes, monkeypatch):
    """Past ``KEPT_TERMS_BYTES`` (none kept, or the first sky only) a sky's moves are made
    as before, over the whole loss, in the mask's order, every time; the kept skies' as
    above; and the layers are those of the whole-loss moves."""
    monkeypatch.setattr(refinement, "KEPT_TERMS_BYTES", kept_bytes)
    rng = np.random.default_rng(12)
    rule, f, losses = _case(rng, "d", low=0.5)
    for s in range(4):
        rule.terms(s)  # as the rule's first pass: each sky's terms made, kept if they fit
    for _ in range(2):
        for s in range(4):
            for j in range(f.k):
                got = rule.move(losses, f.V, j, s)
                expected = _moves_over_whole_loss(rule, losses, f.V, j, s)
                if s not in rule._kept:
                    lit, D, X = rule.lit[s], rule.d[s], rule.delta[s]
                    expected = -X * (losses[j] * (f.V[:, j] @ rule.rests[s]).astype(
                        np.float32))[lit] / D**2
                assert got.tobytes() == expected.tobytes(), (s, j)
    # Kept: the sky with nothing lit (no bytes), and with 1000 bytes the next (about 60
    # lit values, 12 bytes each); the others are made as before.
    assert sorted(rule._kept) == ([0] if kept_bytes == 0 else [0, 1])


@pytest.mark.parametrize("kept_bytes", [refinement.KEPT_TERMS_BYTES, 1000])
def test_layers_are_those_of_the_whole_loss_moves(kept_bytes, monkeypatch):
    """``layers`` against the rule stated with every move made over the whole loss (the
    code before): the same layers for many random pairs whose choices differ, with every
    sky's terms kept or some skies' moves made as before."""
    monkeypatch.setattr(refinement, "KEPT_TERMS_BYTES", kept_bytes)
    rng = np.random.default_rng(13)
    seen = set()
    for case in range(30):
        rule, f, losses = _case(rng, "delta" if case % 2 else "d", low=0.5)
        losses *= {3: 0.05, 7: 20.0}.get(case % 10, 1.0)
        expected = _ratio_layers_as_stated(
            rule, losses, f,
            lambda losses, V, j, s, rule=rule: _moves_over_whole_loss(rule, losses, V, j, s))
        assert rule.layers(losses, f) == expected, case
        seen.add(tuple(expected))
    assert len(seen) >= 5

