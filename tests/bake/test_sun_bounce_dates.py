"""``daylit bake --sun-bounce-dates``: sun-bounce images only for the patches the sun crosses
on the dates asked for (bake/sundates.py, docs/sun.md "The sun's bounce for the dates
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
