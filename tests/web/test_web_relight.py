"""The relight pass in headless Chromium equals the numpy reference.

For several light vectors (uniform, CIE overcast, clear, a random partly cloudy sky; without
the sun's disc, which the client draws apart, in the visit and at the kiosk) every
stack's render target is read back and compared with ``Build.composite`` on the compact data
(the same KTX2 files decoded by the same Basis transcoder, summed as docs/compact-assets.md
says) and, more loosely, with the EXR masters. The build's V are int8 with a scale per
column (manifest version 5, read by the client's ``Assets.matrix`` and
``bake.compact_reader.read_v`` each their own way); a version-4 copy with float16 V and a
version-3 copy with float32 V check that the client still reads those.

Tolerances, per texel and channel: against the compact reference
|gpu - ref| <= 2e-3 |ref| + 2e-3 mean|ref| (half float keeps 11 bits: 4.9e-4 relative, plus
float32 sums in another order; for I = D - X the relative part is of |D| + |X|, the two
rounded values it comes from); against the
masters the RMS error over the mean stays within 2 % (the compression budget is 1 % on its
test skies).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from tests.web.harness import StubServer, decode_floats

pytestmark = [pytest.mark.browser]

COMPACT_REL = 2e-3
COMPACT_OF_MEAN = 2e-3
MASTER_RMS = 0.02


def skies(ref):
    from bake.evaluate import parse_sky
    from daylit.sky import patch_mean_radiance

    def vector(name):
        return patch_mean_radiance(parse_sky(name), ref.dome_vertices, include_sun=False)

    n = ref.light_count
    rng = np.random.default_rng(5)
    clear = vector("clear:200,30")
    overcast = ref.light_vector("overcast")
    cloudy = np.where((rng.random(n) < 0.45)[:, None], 1.6 * overcast, clear)
    cloudy *= rng.uniform(0.8, 1.2, size=(n, 1))
    return {
        "uniform": ref.light_vector("uniform:1"),
        "overcast": overcast,
        "clear": vector("clear:135,40"),
        "partly-cloudy": cloudy,
    }


def relight(page, r, seq):
    flat = np.asarray(r, dtype=np.float32).ravel().tolist()
    return page.page.evaluate("([r, s]) => window.daylit.debug.relight(r, s)", [flat, seq])


def read(page, key):
    return decode_floats(page.page.evaluate("(k) => window.daylit.debug.read(k)", key))[..., :3]


def check(name, gpu, want, master=None, magnitude=None):
    """``magnitude``: the size of the half-float values ``gpu`` was computed from (for
    I = D - X, |D| + |X|: each carries its own rounding)."""
    err = np.abs(gpu - want)
    magnitude = np.abs(want) if magnitude is None else magnitude
    bound = COMPACT_REL * magnitude + COMPACT_OF_MEAN * np.abs(want).mean()
    worst = float((err / bound).max())
    assert worst <= 1.0, f"{name}: {worst:.2f} x the tolerance, max error {err.max():.4g}"
    if master is not None:
        rms = float(np.sqrt(np.mean((gpu - master) ** 2)) / max(np.abs(master).mean(), 1e-9))
        assert rms <= MASTER_RMS, f"{name}: RMS {rms:.4f} of the mean against the masters"
        return worst, rms
    return worst, None


def v_copy(build: Path, out: Path, dtype: str, version: int) -> Path:
    """A copy of ``build`` (files hard-linked) as a build of ``version`` whose every V (and
    coarse V) is of type ``dtype``, as builds of that version were (float32 before version 4,
    float16 in 4), written by the baker's own ``write_v`` from the values the int8 files
    decode to; the manifest's sizes and checksums updated."""
    from bake.compact_reader import read_v, write_v

    shutil.copytree(build, out, copy_function=os.link)
    manifest = json.loads((build / "manifest.json").read_text())
    changed = {}
    for owner in manifest["atlases"] + manifest["views"]:
        for stack in owner["stacks"].values():
            compact = stack["compact"]
            for v in (compact["v"], compact.get("coarse", {}).get("v")):
                if v is None:
                    continue
                values = read_v(build, v)
                (out / v["path"]).unlink()  # a hard link: never write through it
                for key in ("scale", "scales"):
                    v.pop(key, None)
                v.update(write_v(out / v["path"], values, dtype))
                changed[v["path"]] = (out / v["path"]).read_bytes()
    for f in manifest["files"]:
        if f["path"] in changed:
            data = changed[f["path"]]
            f["bytes"], f["sha256"] = len(data), hashlib.sha256(data).hexdigest()
    manifest["version"] = version
    (out / "manifest.json").unlink()
    (out / "manifest.json").write_text(json.dumps(manifest))
    return out


OLDER_V = {"float16-le": 4, "float32-le": 3}  # the builds the client still reads, by V type


@pytest.mark.parametrize("mode, v_type", [("visit", "int8"), ("kiosk", "int8"),
                                          ("visit", "float16-le"), ("visit", "float32-le")])
def test_relight_targets_equal_the_numpy_reference(new_page, web_build, reference, mode, v_type,
                                                   tmp_path):
    """``v_type``: the build's V as baked (int8 with a scale per column since manifest
    version 5) or, for the older builds the client still reads, float16 in a version-4 copy
    and float32 in a version-3 one."""
    from bake.evaluate import Build

    if v_type in OLDER_V:
        web_build = v_copy(web_build, tmp_path / "older", v_type, OLDER_V[v_type])
        reference = Build(web_build)
    ref = reference
    assert ref.manifest["version"] == OLDER_V.get(v_type, 5)
    dtypes = {s["compact"]["v"]["dtype"] for o in ref.manifest["atlases"] + ref.manifest["views"]
              for s in o["stacks"].values()}
    # As baked, a stack over the budget whatever its V keeps the type with the lowest error
    # (the 40-light draft's lightmap: float16), the others int8.
    assert v_type in dtypes and (v_type == "int8" or dtypes == {v_type}), dtypes
    entries = ref.manifest["atlases"] if mode == "visit" else ref.manifest["views"]
    report = {}
    with StubServer(web_build) as server:
        # shading=hull: the hull planes load at start, so every atlas is relit.
        page = new_page().open(f"{server.url}/?mode={mode}&test&shading=hull")
        for seq, (sky, r) in enumerate(skies(ref).items(), start=1):
            applied = relight(page, r, seq)
            assert applied["exact"] and applied["sequence"] == seq
            assert applied["selected"] == ref.selection(r).tolist()
            for entry in entries:
                aid = entry["id"]
                compact = {name: ref.compact(aid, name).composite(r, ref.selection)
                           for name in entry["stacks"]}
                for stack, spec in entry["stacks"].items():
                    gpu = read(page, f"{aid}.{stack}")
                    if spec["compact"].get("encodes") == "d - I":
                        # The target holds X = sum r (d - I); the picture uses I = D - X.
                        report[(sky, f"{aid}.X")] = check(f"{sky} {aid}.X", gpu, compact[stack])
                        D = read(page, f"{aid}.d")
                        report[(sky, f"{aid}.I")] = check(
                            f"{sky} {aid}.I", D - gpu, compact["d"] - compact[stack],
                            ref.composite(aid, "I", r, "master"), np.abs(D) + np.abs(gpu))
                    else:
                        report[(sky, f"{aid}.{stack}")] = check(
                            f"{sky} {aid}.{stack}", gpu, compact[stack],
                            ref.composite(aid, stack, r, "master"))
        assert not page.errors, page.errors
    worst = max(v[0] for v in report.values())
    rms = max(v[1] for v in report.values() if v[1] is not None)
    print(f"\n{mode}: worst {worst:.3f} of the compact tolerance, master RMS {rms:.4f}")
