"""The version-3 sky encoding (server/float16.py) against hand-worked binary16 codes and
CPython's own half-float packer (``struct`` format ``e``, C code independent of numpy's), and
the error bound docs/protocol.md states."""

import struct

import numpy as np
import pytest

from server import float16

# Worked by hand: sign | exponent (bias 15) << 10 | fraction; value (1024 + f) 2^(e - 25).
HAND = [
    (1.0, 0x3C00),  # e = 15, f = 0
    (0.5, 0x3800),
    (-2.5, 0xC100),  # 1.25 x 2^1: e = 16, f = 256, sign
    (65504.0, 0x7BFF),  # (1024 + 1023) x 2^(30 - 25): the largest
    (1.0 / 3.0, 0x3555),  # 1.333 x 2^-2: f = 341.33 -> 341
    (2.0**-14, 0x0400),  # the smallest normal
    (2.0**-24, 0x0001),  # the smallest subnormal
    (1.0 + 2.0**-11, 0x3C00),  # a tie: to even (f = 0)
    (1.0 + 3 * 2.0**-11, 0x3C02),  # a tie: to even (f = 2)
]


@pytest.mark.parametrize("value,code", HAND, ids=[f"{c:04x}" for _, c in HAND])
def test_hand_worked_codes(value, code):
    halves, clipped = float16.encode(np.array([[value, 0.0, 0.0]]))
    assert int(halves.view("<u2")[0, 0]) == code
    assert struct.unpack("<H", struct.pack("<e", value))[0] == code
    assert not clipped[0]


def test_encoder_matches_cpythons_half_packer():
    rng = np.random.default_rng(19)
    rgb = 10.0 ** rng.uniform(-9, 4.8, (5000, 3)) * rng.choice([-1.0, 1.0], (5000, 3))
    halves, clipped = float16.encode(rgb)
    want = [struct.unpack("<H", struct.pack("<e", v))[0] for v in rgb.ravel().tolist()]
    assert halves.view("<u2").ravel().tolist() == want
    assert not clipped.any()
    # Decoding: CPython's unpacker gives the same values, and each is a float32.
    back = float16.decode(halves)
    assert back.dtype == np.float32
    assert back.ravel().tolist() == [struct.unpack("<e", struct.pack("<H", c))[0] for c in want]


def test_the_stated_error_bound_holds_and_is_reached():
    rng = np.random.default_rng(21)
    rgb = 10.0 ** rng.uniform(-9, 4.8, (20000, 3))
    got = float16.decode(float16.encode(rgb)[0]).astype(np.float64)
    err = np.abs(got - rgb)
    normal = rgb >= float16.MIN_NORMAL
    assert float16.RELATIVE_ERROR == 2.0**-11 and float16.ABSOLUTE_ERROR == 2.0**-25
    assert (err[normal] / rgb[normal] <= 2.0**-11).all()
    assert (err[~normal] <= 2.0**-25).all()
    assert (err[normal] / rgb[normal]).max() > 0.95 * 2.0**-11  # the bound is tight
    assert err[~normal].max() > 0.95 * 2.0**-25


def test_out_of_range_values_are_clipped_and_reported():
    halves, clipped = float16.encode(np.array([[1e6, 1.0, 0.0], [-1e6, 2.0, 1.0],
                                               [70000.0, 0, 0]]))
    got = float16.decode(halves)
    assert clipped.tolist() == [True, False, True]
    assert got[:, 0].tolist() == [65504.0, -65504.0, 65504.0]
    assert np.isfinite(got).all()
    with pytest.raises(ValueError, match="shape"):
        float16.encode(np.ones((3, 4)))
