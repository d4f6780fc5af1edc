"""A compact stack's V in int8 with a scale per column (manifest version 5) and in float16
(version 4; docs/compact-assets.md "V in int8", "V in float16").

The int8 file, read here with numpy alone (not the project's reader), is V as the
factorization computed it (float32, in memory) to within half a step of its column's scale;
a float16 file within float16's rounding, 2^-11 of each value; the project's reader (which
the client matches in tests/web/test_web_relight.py) reads the same values; float32 files
(every build before version 4) still read as they are; and the bake takes float16, then
float32, only where its own check finds the type before over the budget and the next better.
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


def test_v_is_written_in_int8_within_half_a_step_of_the_float32_factor(build, tmp_path):
    """The kiosk's O stack compressed as the bake does: its V file holds n x k int8 (a
    quarter of the bytes of float32), whose values times their column's scale are within half
    a step (half the scale) of the factor V the compression computed (float32), each
    column's largest magnitude 127 steps; the reader returns exactly those values; the
    composite stays within the budget on the test skies."""
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
    assert entry["v"]["shape"] == [n, k] and entry["v"]["dtype"] == "int8"
    scales = np.asarray(entry["v"]["scales"], dtype=np.float64)
    assert scales.shape == (k,) and (scales > 0).all()
    path = tmp_path / entry["v"]["path"]
    assert path.stat().st_size == n * k
    steps = np.fromfile(path, dtype=np.int8).reshape(n, k)
    np.testing.assert_array_equal(np.abs(steps).max(axis=0), 127)
    stored = steps.astype(np.float64) * scales
    assert (np.abs(stored - V) <= 0.5 * scales * (1 + 1e-6)).all()
    assert not np.array_equal(stored, V)  # it was rounded
    reader = CompactReader(tmp_path, entry, build.stack("kiosk", "O").shape[:2])
    np.testing.assert_array_equal(reader.V, (steps.astype(np.float32)
                                             * scales.astype(np.float32)))
    assert entry["error"]["max"] <= 0.01


def test_the_demo_builds_v_are_int8_and_its_manifest_version_5(build):
    """Every compact stack of a fresh bake (and its coarse start, if any: the first columns'
    scales) has int8 V, but one over the budget whatever its V (the 40-light draft's
    lightmap: settle_v_dtype keeps the type with the lowest error there), and the manifest,
    version 5, passes its schema."""
    m = build.manifest
    assert m["version"] == 5
    manifest_io.validate(m)
    budget = m["compression"]["budget"]
    int8 = 0
    for owner in m["atlases"] + m["views"]:
        for name, stack in owner["stacks"].items():
            v = stack["compact"]["v"]
            if v["dtype"] != "int8":
                assert stack["compact"]["error"]["max"] > budget, (owner["id"], name)
                continue
            int8 += 1
            assert (build.dir / v["path"]).stat().st_size == v["shape"][0] * v["shape"][1]
            coarse = stack["compact"].get("coarse")
            if coarse:
                assert coarse["v"]["dtype"] == "int8"
                assert coarse["v"]["scales"] == v["scales"][: coarse["v"]["shape"][1]]
                np.testing.assert_array_equal(read_v(build.dir, coarse["v"]),
                                              read_v(build.dir, v)[:, : coarse["v"]["shape"][1]])
    assert int8 >= 5


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
    np.testing.assert_array_equal(got, stored_v(V, "float16-le"))
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
                   **write_v(tmp_path / f"{name}.bin", V, "int8")},
             "error": {}}
    reader = _Reader(read_v(tmp_path, entry["v"]))
    return entry, reader


@pytest.mark.parametrize("float16_error, float32_error, kept", [
    (0.009, None, "float16-le"),  # float16 within: float32 never judged
    (0.012, 0.009, "float32-le"),
    (0.02, 0.02, "int8"),  # neither better: int8 and its errors stay
])
def test_the_next_type_is_kept_only_where_int8_is_over_the_budget_and_it_better(
        tmp_path, float16_error, float32_error, kept):
    """``settle_v_dtype``: a stack whose check with int8 V is over the budget is judged
    again with float16 V, then float32 while still over; the type with the lowest error is
    written (its scale or none), else int8 and its errors stay. Within the budget nothing is
    judged again."""
    V = np.random.default_rng(5).standard_normal((10, 3)).astype(np.float32)
    entry, reader = _stack(tmp_path, "s", V)
    judged = []

    def judge():  # the error the check finds for the type the reader holds
        if np.array_equal(reader.V, V):
            judged.append("float32-le")
            error = float32_error
        elif np.array_equal(reader.V, stored_v(V, "float16-le")):
            judged.append("float16-le")
            error = float16_error
        else:
            error = 0.011
        assert error is not None, "float32 judged after float16 was within the budget"
        entry["error"].update({"encoded": {"sky": error}, "max": error})

    judge()
    rewritten = compress.settle_v_dtype([(entry, V, reader)], tmp_path, 0.01, judge)
    assert entry["v"]["dtype"] == kept and rewritten == (kept != "int8")
    got = read_v(tmp_path, entry["v"])
    np.testing.assert_array_equal(reader.V, got)
    np.testing.assert_array_equal(got, stored_v(V, kept))
    if kept == "float32-le":
        assert not {"scale", "scales"} & set(entry["v"]) and entry["error"]["max"] == 0.009
    elif kept == "float16-le":
        assert "scales" not in entry["v"] and entry["v"]["scale"] == half_scale(V)
        assert entry["error"]["max"] == 0.009 and judged == ["float16-le"]
    else:
        assert entry["error"]["max"] == 0.011 and judged == ["float16-le", "float32-le"]
    within, within_reader = _stack(tmp_path, "t", V)
    within["error"]["max"] = 0.005
    assert not compress.settle_v_dtype([(within, V, within_reader)], tmp_path, 0.01,
                                       lambda: pytest.fail("judged again within the budget"))
    assert within["v"]["dtype"] == "int8"
    json.dumps(entry)  # the entry stays JSON (the manifest)


def test_int8_v_keeps_each_column_to_half_its_own_step(tmp_path):
    """V whose columns differ in magnitude by 1000 times (as a stack's first coefficient's
    and its last's): each column is stored to half a step of its own scale, so a small
    column keeps its relative precision, where one scale for the whole V would round it
    to zero."""
    rng = np.random.default_rng(6)
    V = (rng.standard_normal((50, 4)) * np.array([1.0, 0.1, 0.01, 0.001])).astype(np.float32)
    entry = write_v(tmp_path / "V.bin", V, "int8")
    got = read_v(tmp_path, {"path": "V.bin", "shape": [50, 4], **entry})
    top = np.abs(V).max(axis=0)
    assert (np.abs(got - V) <= 0.5 * top / 127 * (1 + 1e-6)).all()
    one_scale = np.rint(V / (top.max() / 127))
    assert (one_scale[:, 3] == 0).all() and (np.abs(got[:, 3]) > 0).any()
