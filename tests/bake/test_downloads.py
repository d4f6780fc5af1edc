"""What a client downloads (bake/downloads.py): sums of the right files, and the lights a
visit selects."""

from __future__ import annotations

import gzip
import json

import numpy as np
import pandas as pd

from bake import downloads, testskies
from bake.evaluate import Build
from daylit import sky as skies
from daylit.spherical import PatchLookup


def _stack(name: str, gain: bool = False) -> dict:
    compact = {"ktx2": f"ktx2/{name}.base.ktx2", "v": {"path": f"v/{name}.V.bin"}}
    if gain:
        compact["gain"] = {"ktx2": f"ktx2/{name.split('.')[0]}.d.gain.ktx2"}
    return {"compact": compact}


def test_download_bytes_sums_what_each_client_fetches(tmp_path):
    """A made-up build with round file sizes: each figure is the sum it should be."""
    sizes = {
        "site.glb": 1000,
        "ktx2/ground.I.base.ktx2": 200, "v/ground.I.V.bin": 10,
        "ktx2/ground.d.base.ktx2": 100, "v/ground.d.V.bin": 10,
        "ktx2/ground.d.gain.ktx2": 50,  # shared by the pair: counted once
        "ktx2/hull.I.base.ktx2": 300, "v/hull.I.V.bin": 20,
        "ktx2/hull.d.base.ktx2": 30, "v/hull.d.V.bin": 20,
        "ktx2/hull.d.gain.ktx2": 5,
        "ktx2/kiosk.O.base.ktx2": 70, "v/kiosk.O.V.bin": 1,
        "ktx2/ground.I.L0001.ktx2": 4000,  # light images: counted by their average
        "exr/ground.I.exr": 10**9,  # masters are never downloaded
    }
    per_light = {"ground.I": 7, "ground.d": 3, "hull.I": 11, "hull.d": 2, "kiosk.O": 5}
    manifest = {
        "model": {"path": "site.glb"},
        "files": [{"path": p, "bytes": b} for p, b in sizes.items()],
        "compression": {
            "selected_lights": 4,
            "report": [{"stack": s, "light_bytes_per_light": b} for s, b in per_light.items()],
        },
        "atlases": [
            {"id": "ground", "stacks": {"I": _stack("ground.I", True),
                                        "d": _stack("ground.d", True)}},
            {"id": "hull", "stacks": {"I": _stack("hull.I", True), "d": _stack("hull.d", True)}},
        ],
        "views": [{"id": "kiosk", "stacks": {"O": _stack("kiosk.O")}}],
    }
    (tmp_path / "manifest.json").write_text(json.dumps(manifest))
    sent = len(gzip.compress((tmp_path / "manifest.json").read_bytes(), 6))
    got = downloads.download_bytes(manifest, tmp_path, visit_lights=9, day_lights=30)
    ground = 200 + 10 + 100 + 10 + 50
    assert got["phone"] == sent + 1000 + ground + 4 * (7 + 3)
    assert got["phone_visit"] == sent + 1000 + ground + 9 * (7 + 3)
    assert got["phone_hull"] == got["phone"] + 300 + 20 + 30 + 20 + 5 + 4 * (11 + 2)
    assert got["kiosk"] == sent + 1000 + 70 + 1 + 4 * 5  # the GLB: the sun's shadows
    assert got["kiosk_day"] == sent + 1000 + 70 + 1 + 30 * 5
    assert got["all"] == sent + sum(b for p, b in sizes.items() if not p.startswith("exr/"))
    assert (got["visit_lights"], got["day_lights"]) == (9, 30)


def test_a_visit_selects_the_suns_patches_and_a_day_more(demo_draft_build):
    """With the sun in its patch and one selected light (a version-1 light vector; what
    ``[compression] selected_lights = 1`` would fetch) every 10 minutes of the visit the
    sun's patch is among the lights selected (a clear sky), all of them selectable; a whole
    day selects at least as many. The build's stacks select none."""
    build = Build(demo_draft_build)
    manifest = build.manifest
    assert downloads.lights_selected_over(manifest, *downloads.VISIT) == []
    m = testskies.SUN_PATH_SELECTED_LIGHTS
    visit = downloads.lights_selected_over(manifest, *downloads.VISIT, m=m)
    day = downloads.lights_selected_over(manifest, *downloads.KIOSK_DAY, m=m)
    assert set(visit) <= set(day) <= set(build.selection.selectable.tolist())
    assert len(day) > len(visit) >= 1
    site = manifest["scene"]
    times = pd.date_range(*downloads.VISIT, freq=downloads.STEP, tz=site["timezone"])
    az, el = skies.sun_positions(
        site["latitude_deg"], site["longitude_deg"], site["elevation_m"], times
    )
    sun = PatchLookup(build.dome_vertices)(skies.direction_from_azimuth_elevation(az, el))
    assert set(np.asarray(sun).tolist()) <= set(visit)


def test_the_suns_bounce_is_one_lights_images_per_stack_per_patch(tmp_path):
    """The sun's bounce: light p's files (its levels: light 0 has its coarse file alone,
    light 1 a refinement too) of each sun-bounce stack for each patch p the sun is in; the
    hull's only in hull-plane mode; a light without files counts nothing; the kiosk's, of
    its view's O and S, apart."""
    pattern = "ktx2/{atlas}.sun_bounce.{stack}.L{{index:04d}}{suffix}.ktx2"

    def sun_stack(atlas: str, stack: str) -> dict:
        files = [pattern.format(atlas=atlas, stack=stack, suffix=s) for s in ("", "r")]
        levels = [[1.0, 1.0, 1.0], [0.1, 0.1, 0.1]]
        return {"compact": {"k": 0, "lights": {
            "ktx2": files, "scale": [levels[:1], levels, None],
            "offset": [levels[:1], levels, None],
        }}}

    sizes = {"site.glb": 1000}
    for atlas, stack, base in (("ground", "I", 100), ("ground", "d", 200), ("hull", "I", 300),
                               ("kiosk", "O", 400), ("kiosk", "S", 500)):
        for p in (0, 1):
            for suffix, extra in (("", 0), ("r", 5)):
                name = pattern.format(atlas=atlas, stack=stack, suffix=suffix).format(index=p)
                sizes[name] = base + 10 * p + extra
    manifest = {
        "model": {"path": "site.glb"},
        "files": [{"path": p, "bytes": b} for p, b in sizes.items()],
        "compression": {"selected_lights": 1, "report": []},
        "atlases": [
            {"id": "ground", "stacks": {},
             "sun_bounce": {"I": sun_stack("ground", "I"), "d": sun_stack("ground", "d")}},
            {"id": "hull", "stacks": {}, "sun_bounce": {"I": sun_stack("hull", "I")}},
        ],
        "views": [{"id": "kiosk", "stacks": {},
                   "sun_bounce": {"O": sun_stack("kiosk", "O"), "S": sun_stack("kiosk", "S")}}],
    }
    (tmp_path / "manifest.json").write_text(json.dumps(manifest))
    got = downloads.download_bytes(manifest, tmp_path, visit_lights=0, day_lights=0,
                                   visit_sun=[1, 0], day_sun=[1, 0, 2])
    # light 0: the coarse files alone (base + 10 p); light 1: and the refinements (+ 5)
    kiosk = {0: 400 + 500, 1: 410 * 2 + 5 + 510 * 2 + 5}
    assert got["kiosk_sun_bounce_start"] == kiosk[1]  # sunrise's patch
    assert got["kiosk_sun_bounce_day"] == kiosk[0] + kiosk[1]
    one = {0: 100 + 200, 1: 110 * 2 + 5 + 210 * 2 + 5}
    assert got["sun_bounce_start"] == one[1]  # the sun's patch at the visit's start
    assert got["sun_bounce_visit"] == one[0] + one[1]
    assert got["sun_bounce_day"] == one[0] + one[1]  # light 2 has no files
    assert got["sun_bounce_hull_visit"] == 300 + (310 * 2 + 5)
    assert (got["visit_sun_patches"], got["day_sun_patches"]) == (2, 3)


def test_stacks_that_select_no_light_cost_only_their_base(tmp_path):
    """Since the sun is drawn apart, the atlases select no light (their entries say
    ``selected_lights`` 0) and the views one: a phone fetches the atlases' base, gain and V
    and nothing more, however long its visit; the kiosk still fetches its light images. The
    number of lights a visit selects is 0."""
    sizes = {
        "site.glb": 1000,
        "ktx2/ground.I.base.ktx2": 200, "v/ground.I.V.bin": 10,
        "ktx2/ground.d.base.ktx2": 100, "v/ground.d.V.bin": 10,
        "ktx2/ground.d.gain.ktx2": 50,
        "ktx2/hull.I.base.ktx2": 300, "v/hull.I.V.bin": 20,
        "ktx2/kiosk.O.base.ktx2": 70, "v/kiosk.O.V.bin": 1,
    }
    per_light = {"ground.I": 7, "ground.d": 3, "hull.I": 11, "kiosk.O": 5}

    def stack(name, m, gain=False):
        entry = _stack(name, gain)
        entry["compact"]["selected_lights"] = m
        return entry

    manifest = {
        "model": {"path": "site.glb"},
        "files": [{"path": p, "bytes": b} for p, b in sizes.items()],
        "compression": {
            "selected_lights": 0,
            "report": [{"stack": s, "light_bytes_per_light": b} for s, b in per_light.items()],
        },
        "atlases": [
            {"id": "ground", "stacks": {"I": stack("ground.I", 0, True),
                                        "d": stack("ground.d", 0, True)}},
            {"id": "hull", "stacks": {"I": stack("hull.I", 0)}},
        ],
        "views": [{"id": "kiosk", "stacks": {"O": stack("kiosk.O", 1)}}],
    }
    (tmp_path / "manifest.json").write_text(json.dumps(manifest))
    sent = len(gzip.compress((tmp_path / "manifest.json").read_bytes(), 6))
    # The visit's count is not given: with no atlas selecting a light it is 0, uncomputed
    # (this manifest has no dome to compute it from).
    got = downloads.download_bytes(manifest, tmp_path, day_lights=30, visit_sun=[], day_sun=[])
    ground = 200 + 10 + 100 + 10 + 50
    assert got["phone"] == got["phone_visit"] == sent + 1000 + ground
    assert got["visit_lights"] == 0
    assert got["phone_hull"] == got["phone"] + 300 + 20
    assert got["kiosk"] == sent + 1000 + 70 + 1 + 1 * 5
    assert got["kiosk_day"] == sent + 1000 + 70 + 1 + 30 * 5
    assert got["day_lights"] == 30

