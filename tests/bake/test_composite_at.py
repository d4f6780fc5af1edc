"""A compact stack's composite at the valid texels only (``CompactReader.composite(...,
at=)``, issue 20's write stage: the bake's checks read only those): the same values, bit
for bit, as the whole composite taken there, and within float32 rounding of the decoded
layers summed in float64 here."""

from __future__ import annotations

import numpy as np
import pytest

from bake.compact_reader import CompactReader
from daylit.selection import Selection

H, W, N = 23, 37, 9


def _reader(rng, k: int, gain: bool) -> tuple[CompactReader, list, list]:
    """A reader of a stack whose base is k coarse layers and refinements of two of them,
    given as decoded bytes; its gain (T, 3) set as decoded, if any."""
    layers = [{"coefficient": j, "scale": float(rng.uniform(0.1, 2.0)),
               "offset": float(rng.uniform(-1.0, 0.0))} for j in range(k)]
    layers += [{"coefficient": j, "scale": 0.01, "offset": -0.005} for j in (0, k - 1)]
    raw = [rng.integers(0, 256, (H, W, 4), dtype=np.uint8) for _ in layers]
    entry = {"layers": layers, "selected_lights": 0,
             "lights": {"ktx2": [], "scale": [None] * N, "offset": [None] * N}}
    V = rng.normal(size=(N, k)).astype(np.float32)
    reader = CompactReader.decoded("/nonexistent", entry, (H, W), V, raw)
    if gain:
        reader.entry["gain"] = {}
        reader._gain = rng.uniform(0.5, 2.0, (H, W, 3)).astype(np.float32)
    return reader, layers, raw


@pytest.mark.parametrize("k", [1, 5, 21, 33])
@pytest.mark.parametrize("gain", [False, True])
def test_the_composite_at_the_valid_texels_is_the_whole_ones_there(k, gain):
    rng = np.random.default_rng(k)
    reader, layers, raw = _reader(rng, k, gain)
    selection = Selection(np.full(N, 0.1), 0)
    valid = rng.uniform(size=(H, W)) < 0.6
    other = rng.uniform(size=(H, W)) < 0.3
    base64 = np.zeros((k, H, W, 3))
    for layer, texel in zip(layers, raw, strict=True):
        base64[layer["coefficient"]] += (texel[..., :3] / 255.0 * np.float32(layer["scale"])
                                         + np.float32(layer["offset"]))
    for _sky in range(4):
        r = rng.uniform(0.0, 1.0, (N, 3))
        whole = reader.composite(r, selection)  # the base made (again, after a mask)
        for mask in (valid, other, valid):  # a new mask, then the first again
            got = reader.composite(r, selection, at=mask)
            assert got.dtype == np.float32 and got.shape == (int(mask.sum()), 3)
            assert got.tobytes() == whole[mask].tobytes()
        c = reader.V.T.astype(np.float64) @ r
        expected = np.einsum("khwc,kc->hwc", base64, c) * (reader._gain if gain else 1.0)
        scale = np.abs(base64).max() * np.abs(c).sum(axis=0).max() * (2.0 if gain else 1.0)
        np.testing.assert_allclose(got, expected[valid], rtol=0, atol=1e-5 * scale)
