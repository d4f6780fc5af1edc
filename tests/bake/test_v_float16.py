"""A compact stack's V in float16 (manifest version 4, docs/compact-assets.md "V in float16").

The float16 file, read here with numpy alone (not the project's reader), is V as the
factorization computed it (float32, in memory) to within float16's rounding, 2^-11 of each
value; the project's reader (which the client matches in tests/web/test_web_relight.py) reads
the same values; float32 files (every build before version 4) still read as they are; and the
bake keeps float32 only where its own check finds float16 over the budget and float32 better.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from bake import compress, stackkinds
from bake.compact_reader import CompactReader, half_scale, read_v, stored_v, write_v
from bake.evaluate import Build
from daylit import manifest as manifest_io

HALF_ROUNDING = 2.0**-11  # float16 keeps 11 significant bits: round to nearest, half a step


@pytest.fixture(scope="module")
def build(demo_draft_build) -> Build:
    return Build(demo_draft_build)


def _within_half_rounding(stored: np.ndarray, V: np.ndarray, scale: float) -> float:
    """The worst |stored - V| over its float16 bound (normal numbers: 2^-11 |V|; below the
    normal range, half the subnormal step 2^-25, both times ``scale``)."""
    bound = HALF_ROUNDING * np.abs(V) + 2.0**-25 * scale
    return float((np.abs(stored - V) / bound).max())


def test_v_is_written_in_float16_within_its_rounding_of_the_float32_factor(build, tmp_path):
    """The kiosk's O stack compressed as the bake does: its V file holds n x k float16 (half
    the bytes of float32), whose values times the entry's scale (a power of two) are within
    float16 rounding of the factor V the compression computed (float32); the reader returns
    exactly those values; the composite stays within the budget on the test skies."""
    m = build.manifest
    skies, S, S_inv, selection = compress.prepare(
        m["scene"], build.dome_vertices, build.solid_angles, 0,
        selectable=build.selection.selectable,
    )
    result = stackkinds.compress_rms_stack(
        build.stack("kiosk", "O"), "v16.O", tmp_path, skies, S, S_inv, selection,
        compress.Settings(selected_lights=0))
    entry = result.entry
    V = result.factors.V.astype(np.float32)  # (n, k) as factored, before it is written
    n, k = V.shape
    assert entry["v"]["shape"] == [n, k] and entry["v"]["dtype"] == "float16-le"
    scale = entry["v"]["scale"]
    assert scale == 2.0 ** np.round(np.log2(scale))  # a power of two: exact to undo
    path = tmp_path / entry["v"]["path"]
    assert path.stat().st_size == 2 * n * k
    stored = np.fromfile(path, dtype="<f2").reshape(n, k).astype(np.float64) * scale
    assert 2**14 <= np.abs(stored).max() / scale < 2**15  # the range float16 is exact in
    assert _within_half_rounding(stored, V, scale) <= 1.0
    assert not np.array_equal(stored, V)  # it was rounded: a float32 file would fail above
    reader = CompactReader(tmp_path, entry, build.stack("kiosk", "O").shape[:2])
    np.testing.assert_array_equal(reader.V, stored.astype(np.float32))
    assert entry["error"]["max"] <= 0.01


def test_the_demo_builds_v_are_float16_and_its_manifest_version_4(build):
    """Every compact stack of a fresh bake (and its coarse start, if any) has float16 V and
    the manifest, version 4, passes its schema."""
    m = build.manifest
    assert m["version"] == 4
    manifest_io.validate(m)
    for owner in m["atlases"] + m["views"]:
        for name, stack in owner["stacks"].items():
            v = stack["compact"]["v"]
            assert v["dtype"] == "float16-le", (owner["id"], name)
            assert (build.dir / v["path"]).stat().st_size == 2 * v["shape"][0] * v["shape"][1]


def test_v_scale_keeps_small_entries_normal_where_plain_float16_would_not(tmp_path):
    """V of the demo's magnitudes (0.002 down to 1e-6): stored divided by its power-of-two
    scale every entry is within 2^-11 of itself; plain float16 would round the 1e-6 entries
    to the subnormal step (6e-8: 3 % off)."""
    rng = np.random.default_rng(3)
    V = (rng.standard_normal((40, 7)) * np.logspace(-3, -6, 7)).astype(np.float32)
    entry = write_v(tmp_path / "V.bin", V, "float16-le")
    assert entry["scale"] == half_scale(V)
    got = read_v(tmp_path, {"path": "V.bin", "shape": [40, 7], **entry})
    assert np.max(np.abs(got - V) / np.abs(V)) <= HALF_ROUNDING
    np.testing.assert_array_equal(got, stored_v(V, "float16-le", entry["scale"]))
    plain = V.astype(np.float16).astype(np.float32)
    assert np.max(np.abs(plain - V) / np.abs(V)) > 0.01


def test_float32_v_of_older_builds_reads_as_it_is(tmp_path):
    """A float32 file (builds of versions 1-3: no scale) reads back bit for bit."""
    V = np.random.default_rng(4).standard_normal((12, 5)).astype(np.float32)
    V.astype("<f4").tofile(tmp_path / "V.bin")
    for v in ({"path": "V.bin", "shape": [12, 5], "dtype": "float32-le"},
              {"path": "V.bin", "shape": [12, 5]}):
        np.testing.assert_array_equal(read_v(tmp_path, v), V)
    assert write_v(tmp_path / "W.bin", V, "float32-le") == {"dtype": "float32-le"}
    np.testing.assert_array_equal(np.fromfile(tmp_path / "W.bin", "<f4").reshape(12, 5), V)


class _Reader:
    def __init__(self, V):
        self.V = V


def _stack(tmp_path, name, V):
    entry = {"v": {"path": f"{name}.bin", "shape": list(V.shape),
                   **write_v(tmp_path / f"{name}.bin", V, "float16-le")},
             "error": {}}
    reader = _Reader(read_v(tmp_path, entry["v"]))
    return entry, reader


@pytest.mark.parametrize("float32_error, kept", [(0.009, "float32-le"), (0.02, "float16-le")])
def test_float32_is_kept_only_where_float16_is_over_the_budget_and_float32_better(
        tmp_path, float32_error, kept):
    """``settle_v_dtype``: a stack whose check with float16 V is over the budget is judged
    again with float32 V; float32 is written (no scale) if its error is lower, else float16
    and its errors stay. Within the budget nothing is judged again."""
    V = np.random.default_rng(5).standard_normal((10, 3)).astype(np.float32)
    entry, reader = _stack(tmp_path, "s", V)

    def judge():  # the error the check finds: float16's rounding over the budget
        half = not np.array_equal(reader.V, V)
        error = 0.011 if half else float32_error
        entry["error"].update({"encoded": {"sky": error}, "max": error})

    judge()
    rewritten = compress.settle_v_dtype([(entry, V, reader)], tmp_path, 0.01, judge)
    assert entry["v"]["dtype"] == kept and rewritten == (kept == "float32-le")
    got = read_v(tmp_path, entry["v"])
    if kept == "float32-le":
        assert "scale" not in entry["v"] and entry["error"]["max"] == float32_error
        np.testing.assert_array_equal(got, V)
    else:
        assert entry["error"]["max"] == 0.011
        np.testing.assert_array_equal(reader.V, got)
    within, within_reader = _stack(tmp_path, "t", V)
    within["error"]["max"] = 0.005
    assert not compress.settle_v_dtype([(within, V, within_reader)], tmp_path, 0.01,
                                       lambda: pytest.fail("judged again within the budget"))
    assert within["v"]["dtype"] == "float16-le"
    json.dumps(entry)  # the entry stays JSON (the manifest)
