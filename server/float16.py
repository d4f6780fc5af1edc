"""IEEE 754 binary16 ("half float") for the sky values of light-stream protocol version 3
(docs/protocol.md): one sign bit, 5 exponent bits (bias 15), 10 fraction bits, rounded to
nearest, ties to even (numpy's ``astype(float16)``). Each decodes to a float32 exactly.

Error of each channel on its own: at most ``2^-11`` of its value (0.049 %) for magnitudes from
2^-14 (6.1e-5) to :data:`MAX_VALUE` (65504); below 2^-14 (subnormal) at most ``2^-25``
(3.0e-8) absolutely. Larger values are clipped to 65504 and reported, so the caller can mark
them as lower bounds (they would otherwise become infinity); NaN stays NaN as in float32.
"""

from __future__ import annotations

import numpy as np

MAX_VALUE = 65504.0
MIN_NORMAL = 2.0**-14
RELATIVE_ERROR = 2.0**-11  # of the value, between MIN_NORMAL and MAX_VALUE
ABSOLUTE_ERROR = 2.0**-25  # below MIN_NORMAL


def encode(rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """rgb : (n, 3) floats -> ``(halves, clipped)``: (n, 3) little-endian float16 and (n,)
    bool, True where a channel was above :data:`MAX_VALUE` and was clipped to it (values below
    -65504 are clipped to -65504 too)."""
    rgb = np.asarray(rgb, dtype=np.float64)
    if rgb.ndim != 2 or rgb.shape[1] != 3:
        raise ValueError(f"rgb must have shape (n, 3), got {rgb.shape}")
    clipped = (rgb > MAX_VALUE).any(axis=1)
    # float64 -> float16 directly: through float32 first could round twice.
    halves = np.clip(rgb, -MAX_VALUE, MAX_VALUE).astype("<f2")
    return halves, clipped


def decode(halves: np.ndarray) -> np.ndarray:
    """(n, 3) float16 -> (n, 3) float32 (exact)."""
    return np.asarray(halves, dtype="<f2").astype(np.float32)
