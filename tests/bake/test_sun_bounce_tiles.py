"""The measure of benchmarks/sun_bounce_tiles.py (a tile-local basis over the sun's path)
against answers it does not produce: a stack made of a known number of products per tile,
and the Eckart-Young error of the best rank-k approximation from numpy's singular values."""

from __future__ import annotations

import numpy as np

from benchmarks.sun_bounce_tiles import codec_errors, tile_errors, tile_groups


def _valid(H: int, W: int) -> np.ndarray:
    valid = np.ones((H, W), dtype=bool)
    valid[:3, :5] = False  # a gutter, so tiles hold different numbers of texels
    return valid


def _products(valid, tile, P, joint, rng):
    """A stack (V, 3, P) of two products per tile: each a texel's RGB times a patch's
    weight, or (``joint``) a texel's weight times a patch's RGB."""
    ys, xs = np.nonzero(valid)
    tile_of = (ys // tile) * (valid.shape[1] // tile) + xs // tile
    X = np.zeros((len(ys), 3, P), np.float32)
    for t in np.unique(tile_of):
        at = tile_of == t
        for _ in range(2):
            texel = rng.random((int(at.sum()), 1 if joint else 3, 1))
            patch = rng.random((1, 3 if joint else 1, P))
            X[at] += (texel * patch).astype(np.float32)
    return X


def test_a_stack_of_two_products_per_tile_is_held_by_two_and_not_by_one():
    rng = np.random.default_rng(5)
    H, W, P, tile = 24, 32, 30, 8
    valid = _valid(H, W)
    for joint in (False, True):
        X = _products(valid, tile, P, joint, rng)
        tiles = tile_groups(valid, tile)
        errors = tile_errors(X, tiles, [1, 2], joint=joint, bits=None)
        assert errors[2].max() < 1e-5
        assert errors[1].min() > 1e-3
        # The other layout of the rows needs more than two: a texel's three channels each
        # with its own weight (per channel) or a patch's three (joint) are three products.
        assert tile_errors(X, tiles, [2], joint=not joint, bits=None)[2].min() > 1e-3
        # One tile over the whole stack: the tiles' products are no longer few.
        assert tile_errors(X, tile_groups(valid, 64), [2], joint=joint, bits=None)[2].min() > 1e-3


def test_one_tile_gives_the_eckart_young_error():
    rng = np.random.default_rng(6)
    H, W, P = 20, 20, 25
    valid = _valid(H, W)
    X = rng.random((int(valid.sum()), 3, P)).astype(np.float32)
    s = np.linalg.svd(X.reshape(-1, P).astype(np.float64), compute_uv=False)
    for k in (1, 4, 10):
        errors = tile_errors(X, tile_groups(valid, 64), [k], joint=False, bits=None)[k]
        total = float((errors**2).sum()) * X.shape[0] * 3
        assert abs(total - float((s[k:] ** 2).sum())) < 1e-6 * float((s**2).sum())


def test_rounded_coefficients_add_an_error_of_their_step():
    rng = np.random.default_rng(7)
    H, W, P = 16, 16, 12
    valid = np.ones((H, W), dtype=bool)
    X = rng.random((H * W, 3, P)).astype(np.float32)
    exact = tile_errors(X, tile_groups(valid, 16), [P], joint=False, bits=None)[P]
    assert exact.max() < 1e-5  # full rank: nothing lost
    coarse = tile_errors(X, tile_groups(valid, 16), [P], joint=False, bits=4)[P]
    fine = tile_errors(X, tile_groups(valid, 16), [P], joint=False, bits=8)[P]
    assert 0 < fine.max() < coarse.max()
    assert coarse.max() < 0.2


def test_coefficients_through_uastc_come_back_where_their_blocks_are_flat(tmp_path):
    # One product per tile whose texel factor is constant over the tile: each tile's only
    # coefficient is one value, +-127 codes, so every 4x4 block is flat and UASTC gives it
    # back exactly; what is left is the rows' float16 rounding. A coefficient read from the
    # wrong channel or texel would be a code of 128 or another tile's.
    rng = np.random.default_rng(8)
    H, W, P, tile = 32, 48, 20, 16
    valid = np.ones((H, W), dtype=bool)
    ys, xs = np.nonzero(valid)
    tile_of = (ys // tile) * (W // tile) + xs // tile
    level = rng.uniform(0.2, 1.0, tile_of.max() + 1)[tile_of]
    X = (level[:, None, None] * rng.uniform(0.1, 1.0, (1, 3, P))).astype(np.float32)
    errors, size = codec_errors(X, valid, tile_groups(valid, tile), 1, tmp_path)
    assert size > 0
    assert errors.max() < 1e-3 * float(np.abs(X).mean())
