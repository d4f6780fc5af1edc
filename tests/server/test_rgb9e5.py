"""RGB9E5 (server/rgb9e5.py) against hand-worked codes, a scalar transcription of the
EXT_texture_shared_exponent pseudo-code written here, and the stated error bound."""

import math

import numpy as np
import pytest

from server import rgb9e5


def spec_encode(r: float, g: float, b: float) -> int:
    """EXT_texture_shared_exponent, "Encoding", transcribed with math.log2 and plain floats."""
    n, bias, emax = 9, 15, 31
    sharedexp_max = (2**n - 1) / 2**n * 2 ** (emax - bias)
    rc, gc, bc = (max(0.0, min(sharedexp_max, x)) for x in (r, g, b))
    maxrgb = max(rc, gc, bc)
    exp_p = max(-bias - 1, math.floor(math.log2(maxrgb)) if maxrgb > 0 else -bias - 1) + 1 + bias
    maxm = math.floor(maxrgb / 2 ** (exp_p - bias - n) + 0.5)
    exp_shared = exp_p + 1 if maxm == 2**n else exp_p
    denom = 2 ** (exp_shared - bias - n)
    rs, gs, bs = (math.floor(x / denom + 0.5) for x in (rc, gc, bc))
    return rs | gs << 9 | bs << 18 | exp_shared << 27


# Worked by hand: value = mantissa * 2^(e - 24); word = r | g << 9 | b << 18 | e << 27.
HAND = [
    # (1, 0.5, 0.25): max 1 = 2^0, e = 0 + 1 + 15 = 16, step 2^-8: mantissas 256, 128, 64.
    ((1.0, 0.5, 0.25), 0x81010100),
    # (0, 0, 0): e = 0, all zero.
    ((0.0, 0.0, 0.0), 0x00000000),
    # (100, 50, 3): floor(log2 100) = 6, e = 22, step 2^-2: 400, 200, 12.
    # 400 | 200 << 9 | 12 << 18 | 22 << 27 = 0x190 + 0x19000 + 0x300000 + 0xB0000000.
    ((100.0, 50.0, 3.0), 0xB0319190),
    # 65408 = 511 * 2^7 (the largest value): e = 31, red 511.
    ((65408.0, 0.0, 0.0), 0xF80001FF),
    # 1.999: floor(log2) = 0, e = 16, 1.999 * 256 = 511.74 rounds to 512: carry, e = 17,
    # step 2^-7: red 256 (2.0), green 0.
    ((1.999, 0.0, 0.0), 0x88000100),
]


@pytest.mark.parametrize("rgb,word", HAND, ids=[f"{w:08x}" for _, w in HAND])
def test_hand_worked_codes(rgb, word):
    words, clipped = rgb9e5.encode(np.array([rgb]))
    assert int(words[0]) == word == spec_encode(*rgb)
    assert not clipped[0]


def test_encoder_matches_the_spec_transcription_and_decodes_exactly():
    rng = np.random.default_rng(19)
    # Sky-like: six decades of brightness, channels within a factor of ten of each other,
    # plus exact powers of two, tiny values and rounding-carry cases.
    scale = 10.0 ** rng.uniform(-4, 4, 4000)
    rgb = scale[:, None] * rng.uniform(0.1, 1.0, (4000, 3))
    edge = np.array([[2.0**-15, 0, 0], [2.0**-16, 2.0**-20, 0], [511.9, 3, 0.001],
                     [0.5, 0.5, 0.5], [65407.0, 65000.0, 1.0], [1e-30, 0, 0]])
    rgb = np.vstack([rgb, edge])
    words, clipped = rgb9e5.encode(rgb)
    assert [int(w) for w in words] == [spec_encode(*row) for row in rgb.tolist()]
    assert not clipped.any()
    # Decoding: mantissa * 2^(e - 24), computed here from the bits.
    w = words.astype(np.int64)
    mantissas = np.stack([w & 511, (w >> 9) & 511, (w >> 18) & 511], 1)
    want = mantissas * np.exp2((w >> 27) - 24.0)[:, None]
    got = rgb9e5.decode(words)
    assert got.dtype == np.float32 and np.array_equal(got.astype(np.float64), want)


def test_the_stated_error_bound_holds_and_is_reached():
    rng = np.random.default_rng(21)
    rgb = 10.0 ** rng.uniform(-4, 4, (20000, 1)) * rng.uniform(0.01, 1.0, (20000, 3))
    got = rgb9e5.decode(rgb9e5.encode(rgb)[0]).astype(np.float64)
    max_c = rgb.max(axis=1, keepdims=True)
    bound = np.where(max_c >= 2.0**-15, rgb9e5.RELATIVE_ERROR * max_c, 2.0**-25)
    err = np.abs(got - rgb)
    assert (err <= bound * (1 + 1e-12)).all()
    assert rgb9e5.RELATIVE_ERROR == 2.0**-9
    # The bound is tight: some channel comes within 5 % of it.
    assert (err / bound).max() > 0.95
    # Relative to its own value the largest channel is off by at most 2^-9 as well.
    k = rgb.argmax(axis=1)
    rows = np.arange(len(rgb))
    assert (np.abs(got[rows, k] - rgb[rows, k]) / rgb[rows, k] <= 2.0**-9).all()


def test_out_of_range_values_are_clipped_and_reported_and_nan_refused():
    words, clipped = rgb9e5.encode(np.array([[1e6, 1.0, 0.0], [-3.0, 2.0, 1.0]]))
    got = rgb9e5.decode(words)
    assert clipped.tolist() == [True, False]
    assert got[0, 0] == rgb9e5.MAX_VALUE == 65408.0
    assert got[1].tolist() == [0.0, 2.0, 1.0]
    with pytest.raises(ValueError, match="NaN"):
        rgb9e5.encode(np.array([[np.nan, 1.0, 1.0]]))
    with pytest.raises(ValueError, match="shape"):
        rgb9e5.encode(np.ones((3, 4)))
