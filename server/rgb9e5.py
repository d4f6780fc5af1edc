"""RGB9E5: three 9-bit mantissas sharing one 5-bit exponent in 32 bits, the sky encoding of
light-stream protocol version 3 (docs/protocol.md).

The layout and the rounding are those of OpenGL's ``GL_RGB9_E5`` (EXT_texture_shared_exponent,
"Encoding"): bits 0-8 red, 9-17 green, 18-26 blue, 27-31 the exponent ``e``; a channel's value
is ``mantissa * 2^(e - 24)`` (exponent bias 15, 9 mantissa bits), so every code decodes to a
float32 exactly.

Error (round to nearest, the largest channel's mantissa is at least 256 unless the value is
below 2^-15): every channel is within ``2^-9 * max(r, g, b)`` of its value (0.195 % of the
largest channel), and within ``2^-25`` absolutely when ``max(r, g, b) < 2^-15``. A channel
much smaller than the largest keeps only that absolute accuracy.

Range: 0 to :data:`MAX_VALUE` (65408). Larger values are clipped to it and reported, so the
caller can mark them as lower bounds; negative values are clipped to 0.
"""

from __future__ import annotations

import numpy as np

MANTISSA_BITS = 9
EXPONENT_BIAS = 15
MAX_EXPONENT = 31
MAX_VALUE = (2**MANTISSA_BITS - 1) / 2**MANTISSA_BITS * 2.0 ** (MAX_EXPONENT - EXPONENT_BIAS)
RELATIVE_ERROR = 2.0**-MANTISSA_BITS  # of the largest channel, see the module docstring


def encode(rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pack linear RGB values.

    rgb : (n, 3) finite floats (any non-negative scale; see the range above).
    Returns ``(words, clipped)``: (n,) uint32 codes and (n,) bool, True where a channel was
    above :data:`MAX_VALUE` and was clipped to it. Raises ValueError for NaN or infinity.
    """
    rgb = np.asarray(rgb, dtype=np.float64)
    if rgb.ndim != 2 or rgb.shape[1] != 3:
        raise ValueError(f"rgb must have shape (n, 3), got {rgb.shape}")
    if not np.all(np.isfinite(rgb)):
        raise ValueError("rgb has NaN or infinite values; RGB9E5 cannot carry them")
    clipped = (rgb > MAX_VALUE).any(axis=1)
    c = np.clip(rgb, 0.0, MAX_VALUE)
    max_c = c.max(axis=1)
    # floor(log2(max_c)) from frexp (max_c = m 2^k, 0.5 <= m < 1), at least -B - 1.
    _, k = np.frexp(max_c)
    floor_log2 = np.where(max_c > 0, k - 1, -EXPONENT_BIAS - 1)
    e = np.maximum(-EXPONENT_BIAS - 1, floor_log2) + 1 + EXPONENT_BIAS
    max_m = np.floor(max_c / np.exp2(e - EXPONENT_BIAS - MANTISSA_BITS) + 0.5)
    e = np.where(max_m >= 2**MANTISSA_BITS, e + 1, e)  # rounding carried into a new bit
    m = np.floor(c / np.exp2(e - EXPONENT_BIAS - MANTISSA_BITS)[:, None] + 0.5).astype(np.uint32)
    words = (m[:, 0] | (m[:, 1] << 9) | (m[:, 2] << 18) | (e.astype(np.uint32) << 27))
    return words.astype(np.uint32), clipped


def decode(words: np.ndarray) -> np.ndarray:
    """(n,) uint32 codes -> (n, 3) float32 values (exact: each is a 9-bit integer times a
    power of two)."""
    w = np.asarray(words, dtype=np.uint32)
    scale = np.exp2((w >> 27).astype(np.float64) - EXPONENT_BIAS - MANTISSA_BITS)
    m = np.stack([w & 511, (w >> 9) & 511, (w >> 18) & 511], axis=-1).astype(np.float64)
    return (m * scale[:, None]).astype(np.float32)
