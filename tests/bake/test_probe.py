"""``daylit probe`` end to end: points file, EXR sky map, the sun, known answers, bad input.

The build is the sun's test site (tests/conftest.py): a virtual wall 8 x 5 x 1 m at the
origin and a real shed 12 m east of it. Known answers: a uniform sky of radiance L gives
pi L on open ground; the sun adds DNI * sin(elevation) on open ground and nothing in a shadow.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

from daylit.cli import attach_negative_values, main
from daylit.envmap import write_equirect_exr

L_W_M2_SR = 2.0
OPEN_GROUND = "-20,0,15"  # 25 m from the wall, 32 m from the shed
BEHIND_WALL = "0,0,-5"  # in the wall's shadow for a sun from the south at 40 degrees
BEHIND_SHED = "12,0,-5"  # in the real shed's shadow
HULL_TOP = "0,5.03,0,0,1,0"  # the hull plane on top of the wall, facing up
SUN_DIRECT_W_M2 = 800.0 * np.sin(np.radians(40.0))


@pytest.fixture
def site(sun_site_build, tmp_path, monkeypatch):
    """A working directory holding points.csv and sky.exr; the build as a relative path."""
    (tmp_path / "points.csv").write_text(
        "# x,y,z[,nx,ny,nz] in metres\n"
        f"{OPEN_GROUND}\n\n{BEHIND_WALL}\n{BEHIND_SHED}\n{HULL_TOP}\n"
    )
    write_equirect_exr(tmp_path / "sky.exr", np.full((64, 128, 3), L_W_M2_SR))
    monkeypatch.chdir(tmp_path)
    return os.path.relpath(sun_site_build, tmp_path)


def probe_json(capsys, *args) -> list[dict]:
    capsys.readouterr()
    assert main(["probe", *args, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_sky_map_and_sun_give_the_known_answers(site, capsys):
    results = probe_json(capsys, site, "--points", "points.csv", "--env", "sky.exr")
    assert len(results) == 4
    open_ground, behind_wall, behind_shed, hull_top = results
    assert open_ground["receiver"]["kind"] == "ground"
    assert hull_top["receiver"]["kind"] == "hull"
    # The bake's own tolerance for open receivers (test_physics): 1 %.
    for r in (open_ground, hull_top):
        assert np.allclose(r["irradiance_W_m2"], np.pi * L_W_M2_SR, rtol=0.01)
        assert r["sun_W_m2"] is None and r["sun_visible_fraction"] is None
    assert np.all(np.array(behind_wall["sky_W_m2"]) < np.pi * L_W_M2_SR)

    with_sun = probe_json(
        capsys, site, "--points", "points.csv", "--env", "sky.exr", "--sun", "180,40,800"
    )
    for before, after in zip(results, with_sun, strict=True):
        assert after["sky_W_m2"] == before["sky_W_m2"]
        assert before["sun_bounce_W_m2"] is None
        # The parts add up: sky + sun direct + sun bounce (each rounded, then summed).
        for parts in (after, after["without_virtual_objects"]):
            total = (
                np.array(parts["sky_W_m2"])
                + np.array(parts["sun_W_m2"])
                + np.array(parts["sun_bounce_W_m2"])
            )
            assert np.allclose(parts["irradiance_W_m2"], total, atol=2e-6)
            assert np.all(np.array(parts["sun_bounce_W_m2"]) >= 0.0)
    open_ground, behind_wall, behind_shed, hull_top = with_sun
    for r in (open_ground, hull_top):
        assert np.allclose(r["sun_W_m2"], SUN_DIRECT_W_M2, rtol=1e-6)
        assert r["sun_visible_fraction"] == 1.0
    assert np.allclose(
        open_ground["irradiance_W_m2"], np.pi * L_W_M2_SR + SUN_DIRECT_W_M2, rtol=0.01
    )
    # Facing up, 25 m from the wall: almost no sunlit surface below its horizon; the hull's
    # top sees none.
    assert np.all(np.array(open_ground["sun_bounce_W_m2"]) < 0.005 * SUN_DIRECT_W_M2)
    assert hull_top["sun_bounce_W_m2"] == [0.0] * 3
    # The virtual wall's shadow: the sky's part and the sun's bounce (off the sunlit ground
    # and the shed); without the wall the sun is back.
    assert behind_wall["sun_W_m2"] == [0.0] * 3
    total = np.array(behind_wall["sky_W_m2"]) + np.array(behind_wall["sun_bounce_W_m2"])
    assert np.allclose(behind_wall["irradiance_W_m2"], total, atol=2e-6)
    without = behind_wall["without_virtual_objects"]
    assert np.allclose(without["sun_W_m2"], SUN_DIRECT_W_M2, rtol=1e-6)
    assert without["sun_visible_fraction"] == 1.0
    # The real shed's shadow is there with and without the virtual objects.
    assert behind_shed["sun_W_m2"] == [0.0] * 3
    assert behind_shed["without_virtual_objects"]["sun_W_m2"] == [0.0] * 3


def test_readable_table(site, capsys):
    capsys.readouterr()
    args = ["probe", site, "--points", "points.csv", "--env", "sky.exr", "--sun", "180,40,800"]
    assert main(args) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 5
    assert lines[0].split()[:3] == ["point_m", "normal", "receiver"]
    assert lines[1].startswith("-20,0,15") and "(ground)" in lines[1]
    assert "(hull)" in lines[4]


def test_negative_numbers_after_options(site, capsys):
    spaced = probe_json(capsys, site, "--point", "-8,0,0", "--sun", "90,-2,0")
    joined = probe_json(capsys, site, "--point=-8,0,0", "--sun=90,-2,0")
    assert spaced == joined
    assert spaced[0]["point_m"] == [-8.0, 0.0, 0.0]
    assert spaced[0]["sun_W_m2"] == [0.0] * 3  # DNI 0 (and below the horizon)
    # The single-point form with its normal and a named sky, as before.
    facing = probe_json(
        capsys, site, "--point", "-4.03,2,0", "--normal", "-1,0,0", "--sky", "uniform:1"
    )
    assert facing[0]["receiver"]["kind"] == "hull"
    assert attach_negative_values(["--point", "-8,0,0", "--json", "x", "--sun", "-.5,1,2"]) == [
        "--point=-8,0,0",
        "--json",
        "x",
        "--sun=-.5,1,2",
    ]


def _exr(path, channels):
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, channels) as f:
        f.write(str(path))


BAD_INPUTS = [
    ("no build", ["nowhere", "--point", "0,0,0"], "no manifest"),
    ("no points file", ["{build}", "--points", "missing.csv"], "missing.csv: no such points"),
    ("bad line", ["{build}", "--points", "bad.csv"], "bad.csv line 3: expected x,y,z"),
    ("on no receiver", ["{build}", "--points", "air.csv"], "air.csv line 1: no receiver"),
    ("map not 2:1", ["{build}", "--point", "0,0,-5", "--env", "square.exr"], "twice as wide"),
    ("map not RGB", ["{build}", "--point", "0,0,-5", "--env", "grey.exr"], "R, G and B"),
    ("no map", ["{build}", "--point", "0,0,-5", "--env", "none.exr"], "none.exr: no such file"),
    ("sun", ["{build}", "--point", "0,0,-5", "--sun", "180,40"], "--sun AZ_DEG,EL_DEG,DNI"),
    ("sun low", ["{build}", "--point", "0,0,-5", "--sun", "0,-95,1"], "within [-90, 90]"),
    ("point", ["{build}", "--point", "-8,0"], "--point X,Y,Z must be 3"),
]


@pytest.mark.parametrize(("label", "args", "words"), BAD_INPUTS, ids=[c[0] for c in BAD_INPUTS])
def test_bad_input_exits_2_and_says_what_to_do(site, capsys, label, args, words):
    with open("bad.csv", "w") as f:
        f.write("1,2,3\n# fine\n1,2\n")
    with open("air.csv", "w") as f:
        f.write("0,30,0\n")
    _exr("square.exr", {c: np.ones((8, 8), np.float32) for c in "RGB"})
    _exr("grey.exr", {"Y": np.ones((8, 16), np.float32)})
    capsys.readouterr()
    assert main(["probe", *[a.format(build=site) for a in args]]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and words in err, err


def test_help_describes_the_interface(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["probe", "--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    for words in ("--points", "--env", "--sun", "AZ_DEG,EL_DEG,DNI_W_M2", "row 0 at the zenith"):
        assert words in out


def test_compact_answers_agree_with_the_masters(site, capsys):
    args = [site, "--points", "points.csv", "--env", "sky.exr", "--sun", "180,40,800"]
    master = probe_json(capsys, *args)
    compact = probe_json(capsys, *args, "--compact")
    for m, c in zip(master, compact, strict=True):
        assert c["sun_W_m2"] == m["sun_W_m2"]
        # atol 0.5 W/m^2: a coarse image alone (no refinement where it does not show as
        # displayed, docs/compact-assets.md) loses bounces of a few tenths of a W/m^2.
        assert np.allclose(c["sun_bounce_W_m2"], m["sun_bounce_W_m2"], rtol=0.05, atol=0.5)
        assert np.allclose(c["sky_W_m2"], m["sky_W_m2"], rtol=0.05)


def test_compact_decodes_once_whatever_the_number_of_points(site, capsys, monkeypatch):
    """``--compact`` decodes each stack's textures and sums its composite once per run, then
    samples every point from it (it once recomputed the whole atlas per point)."""
    from bake import compact_reader

    calls = {"decode": 0, "composite": 0}
    decode, composite = compact_reader.decode, compact_reader.CompactReader.composite

    def counted_decode(files):
        calls["decode"] += 1
        return decode(files)

    def counted_composite(self, r, selection, **kwargs):
        calls["composite"] += 1
        return composite(self, r, selection, **kwargs)

    monkeypatch.setattr(compact_reader, "decode", counted_decode)
    monkeypatch.setattr(compact_reader.CompactReader, "composite", counted_composite)
    # Twelve points on the ground, around three known ones (the working directory is the
    # fixture's tmp_path).
    ground = [
        f"{x + dx},0,{z}" for x, z in ((-20, 15), (0, -5), (12, -5)) for dx in (0, 0.2, 0.4, 0.6)
    ]
    Path("many.csv").write_text("\n".join(ground) + "\n")
    Path("one.csv").write_text(ground[0] + "\n")
    counts = {}
    for name in ("one.csv", "many.csv"):
        calls.update(decode=0, composite=0)
        results = probe_json(capsys, site, "--points", name, "--sky", "overcast:30", "--compact")
        assert all(r["receiver"]["atlas"] == "ground" for r in results)
        counts[name] = dict(calls)
    assert len(results) == 12
    assert counts["one.csv"]["decode"] >= 1
    assert counts["many.csv"] == counts["one.csv"]
