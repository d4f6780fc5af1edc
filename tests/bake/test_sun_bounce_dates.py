"""``daylit bake --sun-bounce-dates``: sun-bounce images only for the patches the sun crosses
on the dates asked for (bake/sundates.py), and ``daylit sun-bounce``: made again for other
dates from the masters (bake/sunremake.py; docs/sun.md "The sun's bounce for the dates
served"). The patches are found here from pvlib's ephemeris sun (not the SPA the baker uses)
and a point-in-triangle test on the manifest's dome written here."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pvlib
import pytest

from tests.conftest import SUN_SHED, SUN_WALL_SIZE_M

DATES = ("2026-06-20", "2026-06-22")


def patches_crossed(manifest: dict, first: str, last: str) -> set[int]:
    """The dome patches holding the sun while it is up (apparent elevation > 0), every
    minute of the local dates ``first`` to ``last``: pvlib's ephemeris sun, each direction
    inside a patch when it is on the inner side of the patch's three great-circle edges (the
    vertices are counter-clockwise seen from outside)."""
    scene = manifest["scene"]
    times = pd.date_range(pd.Timestamp(first), pd.Timestamp(last) + pd.Timedelta(days=1),
                          freq="1min", inclusive="left", tz=scene["timezone"])
    sun = pvlib.solarposition.get_solarposition(
        times, scene["latitude_deg"], scene["longitude_deg"], altitude=scene["elevation_m"],
        method="ephemeris")
    up = sun["apparent_elevation"].to_numpy() > 0.0
    az = np.radians(sun["azimuth"].to_numpy()[up])
    el = np.radians(sun["apparent_elevation"].to_numpy()[up])
    # Site frame: x east, y up, z south.
    d = np.stack([np.cos(el) * np.sin(az), np.sin(el), -np.cos(el) * np.cos(az)], axis=1)
    tri = np.array([light["vertices"] for light in manifest["dome"]["lights"]])  # (n, 3, 3)
    inside = np.ones((len(d), len(tri)), dtype=bool)
    for a, b in ((0, 1), (1, 2), (2, 0)):
        normal = np.cross(tri[:, a], tri[:, b])  # (n, 3)
        inside &= d @ normal.T >= -1e-9
    return {int(p) for p in np.nonzero(inside.any(axis=0))[0]}


def lights_with_files(manifest: dict) -> dict[str, set[int]]:
    """{sun-bounce stack: the lights whose scale entry is not null}."""
    out = {}
    for atlas in manifest["atlases"] + manifest.get("views", []):
        for stack, entry in atlas.get("sun_bounce", {}).items():
            scale = entry["compact"]["lights"]["scale"]
            out[f"{atlas['id']}.{stack}"] = {i for i, s in enumerate(scale) if s is not None}
    return out


@pytest.fixture(scope="module")
def dated_build(tmp_path_factory) -> Path:
    """The sun's test site (tests/conftest.py) baked by the command line with
    ``--sun-bounce-dates`` of three June days."""
    from tests.sites import box, make_site, real_box

    root = tmp_path_factory.mktemp("sundates")
    scene = make_site(
        root / "scene",
        virtual=[("wall", box(list(SUN_WALL_SIZE_M), [0.0, 0.0, 0.0]), (0.5, 0.5, 0.5))],
        real=real_box(**SUN_SHED),
        ground_m=60.0,
    )
    done = subprocess.run(
        [sys.executable, "-m", "daylit.cli", "bake", str(scene), "-o", str(root / "build"),
         "--no-progress", "--sun-bounce-dates", "..".join(DATES)],
        capture_output=True, text=True, timeout=900,
    )
    assert done.returncode == 0, done.stderr
    assert "the sun's bounce from 2026-06-20 to 2026-06-22" in done.stderr
    return root / "build"


def test_only_the_patches_the_sun_crosses_then_get_images(dated_build, sun_site_build):
    manifest = json.loads((dated_build / "manifest.json").read_text())
    assert manifest["compression"]["sun_bounce_dates"] == list(DATES)
    expected = patches_crossed(manifest, *DATES)
    year = set(manifest["compression"]["selectable_lights"])
    assert expected and expected < year  # three days: a part of the year's path
    stacks = lights_with_files(manifest)
    assert stacks
    for stack, lights in stacks.items():
        assert lights == expected, stack
    # The same site baked for the whole year has images for more of its patches, and
    # records no dates.
    whole = json.loads((sun_site_build / "manifest.json").read_text())
    assert whole["compression"]["sun_bounce_dates"] is None
    assert all(len(lights) > len(expected) for lights in lights_with_files(whole).values())


def test_the_listed_files_are_those_lights_and_nothing_else(dated_build):
    manifest = json.loads((dated_build / "manifest.json").read_text())
    listed = {f["path"] for f in manifest["files"] if ".sun_bounce." in f["path"]
              and f["path"].endswith(".ktx2")}
    on_disk = {p.relative_to(dated_build).as_posix()
               for p in (dated_build / "ktx2").glob("*.sun_bounce.*.ktx2")}
    assert listed == on_disk
    wanted = set()
    for atlas in manifest["atlases"]:
        for entry in atlas.get("sun_bounce", {}).values():
            table = entry["compact"]["lights"]
            for p, scale in enumerate(table["scale"]):
                if scale is not None:
                    wanted |= {pattern.format(index=p) for pattern in table["ktx2"][: len(scale)]}
    assert wanted == listed
    # Every master keeps every sun-path column: the images of other dates can be made from it.
    for atlas in manifest["atlases"]:
        for entry in atlas.get("sun_bounce", {}).values():
            assert (dated_build / entry["master"]).is_file()


def test_dates_when_the_sun_never_rises_are_refused_before_any_work(tmp_path):
    from bake.errors import BakeError
    from bake.pipeline import bake
    from bake.sundates import SunBounceDates
    from tests.sites import make_site

    scene = make_site(tmp_path / "scene")
    toml = scene / "scene.toml"
    text = toml.read_text().replace("latitude_deg = 34.47", "latitude_deg = 78.22")
    toml.write_text(text.replace('timezone = "Asia/Tokyo"', 'timezone = "Arctic/Longyearbyen"'))
    out = tmp_path / "build"
    with pytest.raises(BakeError, match="the sun is never up at this site from 2026-12-10"):
        bake(scene, out, progress=False, log=lambda msg: None,
             sun_bounce_dates=SunBounceDates.parse("2026-12-10..2026-12-20"))
    assert not out.exists() and not (tmp_path / ".build.partial").exists()


@pytest.mark.parametrize("text, says", [
    ("2026-08-31..2026-06-01", "before the first"),
    ("2026-06-01..2027-06-02", "more than a year"),
    ("June", "ISO dates"),
    ("2026-06-01..", "FIRST..LAST"),
])
def test_the_command_line_says_what_is_wrong_with_the_dates(tmp_path, text, says):
    done = subprocess.run(
        [sys.executable, "-m", "daylit.cli", "bake", "scenes/demo", "-o", str(tmp_path / "b"),
         "--sun-bounce-dates", text],
        capture_output=True, text=True, cwd=Path(__file__).resolve().parents[2], timeout=120,
    )
    assert done.returncode == 2
    assert "--sun-bounce-dates" in done.stderr and says in done.stderr
    assert not (tmp_path / "b").exists()


WINTER = ("2026-12-20", "2026-12-22")


def test_made_again_for_other_dates_from_the_masters(dated_build, tmp_path):
    """``daylit sun-bounce`` on a copy of the June build, for three December days: the
    December patches get images and nothing else does, the June-only files are gone, every
    listed file has its size and hash, and each patch's image is its own master column's
    (decoded as the client decodes it: nearer its own column than any other patch's)."""
    import shutil

    from bake.evaluate import Build
    from daylit import manifest as manifest_io
    from tests.bake.test_sun_bounce import column_error

    build = tmp_path / "build"
    shutil.copytree(dated_build, build)
    before = json.loads((build / "manifest.json").read_text())
    done = subprocess.run(
        [sys.executable, "-m", "daylit.cli", "sun-bounce", str(dated_build.parent / "scene"),
         str(build), "--no-progress", "--dates", "..".join(WINTER)],
        capture_output=True, text=True, timeout=900,
    )
    assert done.returncode == 0, done.stderr
    assert "Restart the server" in done.stderr
    manifest = manifest_io.load(build, check_files=True)  # every listed file: size, SHA-256
    assert manifest["compression"]["sun_bounce_dates"] == list(WINTER)
    expected = patches_crossed(manifest, *WINTER)
    assert expected and expected != patches_crossed(manifest, *DATES)
    for stack, lights in lights_with_files(manifest).items():
        assert lights == expected, stack
    # Only the sun-bounce images changed: every other listed file is the same entry.
    others = [f for f in manifest["files"] if ".sun_bounce." not in f["path"]
              or not f["path"].endswith(".ktx2")]
    assert others == [f for f in before["files"] if ".sun_bounce." not in f["path"]
                      or not f["path"].endswith(".ktx2")]
    on_disk = {p.relative_to(build).as_posix()
               for p in (build / "ktx2").glob("*.sun_bounce.*.ktx2")}
    listed = {f["path"] for f in manifest["files"] if f["path"] in on_disk}
    assert on_disk == listed and all(".2026-12-20_2026-12-22.L" in p for p in on_disk)
    reader_build = Build(build)
    master = reader_build.sun_bounce_stack("lightmap", "I")
    reader = reader_build.sun_bounce_compact("lightmap", "I")
    lights = sorted(expected)
    decoded = reader.lights(lights)
    for p in lights:
        own = column_error(decoded[p], master, p)
        assert own < 0.3, (p, own)
        assert all(own < column_error(decoded[p], master, q) for q in lights if q != p), p


def test_a_scene_it_was_not_baked_from_is_refused_and_the_build_kept(dated_build, tmp_path):
    import shutil

    from tests.sites import make_site

    build = tmp_path / "build"
    shutil.copytree(dated_build, build)
    before = (build / "manifest.json").read_bytes()
    other = make_site(tmp_path / "other", site_id="elsewhere")
    done = subprocess.run(
        [sys.executable, "-m", "daylit.cli", "sun-bounce", str(other), str(build),
         "--dates", "..".join(WINTER)],
        capture_output=True, text=True, timeout=300,
    )
    assert done.returncode == 2
    assert "baked from the site 'test', not 'elsewhere'" in done.stderr
    assert (build / "manifest.json").read_bytes() == before
    assert not list(tmp_path.glob(".build.sun-bounce.partial"))


def test_a_patch_of_the_dates_brings_its_whole_sharing_group():
    """A group's image is made from all its members' columns and judged on each: a date
    window that reaches one member gets the group whole; groups it misses get nothing."""
    from bake.sundates import lights_for_dates
    from bake.sunshare import SharedImages

    shared = SharedImages({3: [3, 4, 9], 5: [5, 6], 7: [7]}, np.ones(12), "icosahedral", 2)
    selectable = np.array([3, 4, 5, 6, 7, 9])
    assert lights_for_dates(selectable, [4], shared).tolist() == [3, 4, 9]
    assert lights_for_dates(selectable, [4, 7, 11], shared).tolist() == [3, 4, 7, 9]
    # Without groups: the dates' patches on the sun's path, nothing else.
    assert lights_for_dates(selectable, [4, 7, 11]).tolist() == [4, 7]


def test_the_days_left_count_the_sites_local_dates():
    from server.sunbouncedates import coverage, warning

    manifest = {"scene": {"timezone": "Asia/Tokyo"},
                "compression": {"sun_bounce_dates": ["2026-12-01", "2026-12-10"]}}

    def at(text):  # a local time in Tokyo (UTC+9), as seconds since the epoch
        return pd.Timestamp(text, tz="Asia/Tokyo").timestamp()

    assert coverage(manifest, at("2026-12-08 12:00"))["days_left"] == 3  # the 8th, 9th, 10th
    assert coverage(manifest, at("2026-12-10 23:59"))["days_left"] == 1
    # 2026-12-10 20:00 UTC is already the 11th in Tokyo: past the last date.
    assert coverage(manifest, pd.Timestamp("2026-12-10 20:00", tz="UTC").timestamp()) == {
        "dates": ["2026-12-01", "2026-12-10"], "days_left": 0}
    assert coverage(manifest, at("2026-11-30 23:00"))["days_left"] == 0
    assert coverage(manifest, at("2026-12-01 00:00"))["days_left"] == 10
    assert warning(manifest, at("2026-12-01 00:00")) is None  # 10 days: no warning yet
    assert "3 days left" in warning(manifest, at("2026-12-08 12:00"))
    assert "today is not among them" in warning(manifest, at("2026-12-11 00:01"))
    whole = {"scene": {"timezone": "Asia/Tokyo"}, "compression": {"sun_bounce_dates": None}}
    assert coverage(whole, at("2026-12-08 12:00")) == {"dates": None, "days_left": None}
    assert warning(whole, at("2026-12-08 12:00")) is None


async def test_the_server_tells_the_operator_the_dates_it_serves(dated_build, aiohttp_client,
                                                                 tmp_path, caplog):
    """The real server on the June build (the tests run after June 2026): a warning at
    start that names the dates and the command, and ``/api/status`` says so."""
    import logging

    from server.app import create_app
    from tests.server.helpers import ManualSource, settings_for

    caplog.set_level(logging.WARNING, logger="daylit.server")
    client = await aiohttp_client(create_app(dated_build, settings_for(tmp_path),
                                             sky_source=ManualSource()))
    said = [r.getMessage() for r in caplog.records if "sun-bounce images" in r.getMessage()]
    assert len(said) == 1 and "2026-06-20 to 2026-06-22" in said[0]
    assert "daylit sun-bounce" in said[0]
    status = await (await client.get("/api/status")).json()
    assert status["sun_bounce"] == {"dates": list(DATES), "days_left": 0}


def test_what_the_dates_do_not_read_is_dropped(tmp_path):
    """Group {3, 4, 9} shares light 3's image but 9 has its own (split out); light 5 alone
    has a refinement. Dates that reach patches 4 and 5: 4 keeps reading 3's file, 5 keeps
    both its levels; 3 and 9 lose their tables and 9's own file goes; 3's file stays (4 reads
    it)."""
    from bake.compress import CompactStack
    from bake.sundates import keep_patches

    (tmp_path / "ktx2").mkdir()
    patterns = ["ktx2/s.L{index:04d}.ktx2", "ktx2/s.L{index:04d}r.ktx2"]
    names = ["ktx2/s.L0003.ktx2", "ktx2/s.L0009.ktx2", "ktx2/s.L0005.ktx2",
             "ktx2/s.L0005r.ktx2"]
    for k, name in enumerate(names):
        (tmp_path / name).write_bytes(bytes(10 + k))
    one, two = [[1.0, 1.0, 1.0]], [[1.0, 1.0, 1.0], [0.1, 0.1, 0.1]]
    scale = [None] * 10
    scale[3], scale[4], scale[9], scale[5] = one, one, one, two
    image = [None] * 10
    image[3], image[4], image[9], image[5] = 3, 3, 9, 5
    entry = {"k": 0, "lights": {"ktx2": patterns, "scale": scale, "offset": list(scale),
                                "image": image},
             "error": {}, "shared": {"images": 3, "lights": 4}}
    result = CompactStack(entry, [tmp_path / n for n in names], light_bytes=1)
    kept = keep_patches(result, {4, 5, 7}, tmp_path)
    table = entry["lights"]
    assert [i for i, s in enumerate(table["scale"]) if s is not None] == [4, 5]
    assert table["image"][4] == 3 and table["image"][3] is None and table["image"][9] is None
    assert table["offset"][9] is None
    left = sorted(p.relative_to(tmp_path).as_posix() for p in (tmp_path / "ktx2").iterdir())
    assert left == ["ktx2/s.L0003.ktx2", "ktx2/s.L0005.ktx2", "ktx2/s.L0005r.ktx2"]
    assert sorted(p.name for p in result.files) == ["s.L0003.ktx2", "s.L0005.ktx2",
                                                    "s.L0005r.ktx2"]
    assert result.light_bytes == 10 + 12 + 13
    assert kept == 2  # the images of 3 (read by 4) and of 5
    assert entry["shared"] == {"images": 2, "lights": 2}
