"""The coarse start (bake/coarse.py): each cut array holds exactly the full array's first
layers, decoded by three.js's Basis transcoder (an independent KTX2 reader), V its first
columns, and the manifest lists the new files with their true size and SHA-256. `daylit bake`
writes it itself, inside the staging folder: an interrupted bake publishes none of it and
the resumed bake has all of it."""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np
import pytest

import bake.coarse
from bake import ktx2decoder
from bake.coarse import CoarseError, add_coarse, coarse_count, read_ktx2_level
from bake.compact_reader import read_v
from bake.pipeline import bake as run_bake
from daylit import manifest as manifest_io
from tests.coarsebuild import coarse_copy
from tests.sites import make_site


@pytest.fixture(scope="module")
def build(request, tmp_path_factory):
    existing = os.environ.get("DAYLIT_WEB_BUILD")
    source = Path(existing) if existing else request.getfixturevalue("demo_draft_build")
    return coarse_copy(source, tmp_path_factory.mktemp("coarse") / "build", 60_000)


def test_cut_arrays_hold_the_first_layers_texel_for_texel(build):
    manifest = json.loads((build / "manifest.json").read_text())
    stacks = [s["compact"] for a in manifest["atlases"] for s in a["stacks"].values()]
    assert stacks and all("coarse" in c for c in stacks)
    files = [build / p for c in stacks for p in (c["ktx2"], c["coarse"]["ktx2"])]
    try:
        decoded = ktx2decoder.decode(files)  # three.js's transcoder, in Node
    finally:
        ktx2decoder.close_decoders()
    for i, compact in enumerate(stacks):
        full, cut = decoded[2 * i], decoded[2 * i + 1]
        n = compact["coarse"]["layers"]
        assert cut.shape == (n, *full.shape[1:]), compact["ktx2"]
        assert 1 <= n <= coarse_count(compact["layers"])
        np.testing.assert_array_equal(cut, full[:n], err_msg=compact["ktx2"])
        V = read_v(build, compact["v"])
        kc = compact["coarse"]["v"]["shape"][1]
        assert kc == 1 + max(layer["coefficient"] for layer in compact["layers"][:n])
        # The coarse V is the first kc columns, in the stack's own type (int8 since v5).
        assert compact["coarse"]["v"]["dtype"] == compact["v"]["dtype"]
        Vc = read_v(build, compact["coarse"]["v"])
        np.testing.assert_array_equal(Vc, V[:, :kc])
        # Within the budget (60 kB here), unless one layer alone is more.
        size = (build / compact["coarse"]["ktx2"]).stat().st_size
        assert size <= 60_000 or n == 1, (compact["ktx2"], size, n)


def test_manifest_lists_the_new_files_truly(build):
    manifest = json.loads((build / "manifest.json").read_text())
    manifest_io.validate(manifest)
    listed = {f["path"]: f for f in manifest["files"]}
    coarse = sorted(p.relative_to(build).as_posix() for p in (build / "coarse").iterdir())
    assert coarse and all(p.startswith("coarse/") for p in coarse)
    for path in coarse:
        data = (build / path).read_bytes()
        assert listed[path]["bytes"] == len(data)
        assert listed[path]["sha256"] == hashlib.sha256(data).hexdigest()
    # Nothing else changed in the list.
    source = [f for f in manifest["files"] if not f["path"].startswith("coarse/")]
    assert len(source) == len(manifest["files"]) - len(coarse)


def test_a_file_that_is_not_a_uastc_array_is_refused_clearly(tmp_path, build):
    with pytest.raises(CoarseError, match="not a KTX2"):
        read_ktx2_level(b"PNG...", "x.ktx2")
    manifest = json.loads((build / "manifest.json").read_text())
    gain = next(s["compact"]["gain"]["ktx2"] for a in manifest["atlases"]
                for s in a["stacks"].values() if "gain" in s["compact"])
    data = bytearray((build / gain).read_bytes())
    data[44:48] = (0).to_bytes(4, "little")  # supercompression: none
    with pytest.raises(CoarseError, match="Zstandard"):
        read_ktx2_level(bytes(data), gain)
    # A build left as it was when a stack cannot be cut: the manifest is not rewritten.
    broken = tmp_path / "broken"
    broken.mkdir()
    m = {"atlases": [{"id": "a", "stacks": {"I": {"compact": {"ktx2": "x.ktx2"}}}}]}
    (broken / "x.ktx2").write_bytes(b"not a texture")
    (broken / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(CoarseError):
        add_coarse(broken)
    assert json.loads((broken / "manifest.json").read_text()) == m


def _check_listed(build: Path) -> dict:
    """Every file of ``build`` listed once with its size and SHA-256 (hashlib here), and every
    atlas stack's coarse files among them; returns the manifest."""
    manifest = json.loads((build / "manifest.json").read_text())
    manifest_io.validate(manifest)
    on_disk = {p.relative_to(build).as_posix(): p for p in build.rglob("*")
               if p.is_file() and p.name != "manifest.json"}
    listed = {f["path"]: f for f in manifest["files"]}
    assert listed.keys() == on_disk.keys()
    stacks = [s["compact"] for a in manifest["atlases"] for s in a["stacks"].values()]
    assert stacks and all("coarse" in c for c in stacks)
    coarse = {p for c in stacks for p in (c["coarse"]["ktx2"], c["coarse"]["v"]["path"])}
    assert coarse == {p for p in on_disk if p.startswith("coarse/")}
    for path in coarse:
        data = on_disk[path].read_bytes()
        assert listed[path]["bytes"] == len(data) > 0
        assert listed[path]["sha256"] == hashlib.sha256(data).hexdigest()
    return manifest


@pytest.fixture(scope="module")
def fresh_demo(request):
    """The demo baked by `bake()` in this session (DAYLIT_WEB_BUILD: one baked by this code
    earlier, to iterate quickly; a build from before 2026-11-25 has no coarse start)."""
    existing = os.environ.get("DAYLIT_WEB_BUILD")
    return Path(existing) if existing else request.getfixturevalue("demo_draft_build")


def test_a_fresh_bake_writes_its_coarse_start(fresh_demo):
    """No separate step: every atlas stack has a coarse start, its files exist and are
    listed truly, within the default budget (or one layer)."""
    demo_draft_build = fresh_demo
    manifest = _check_listed(demo_draft_build)
    for atlas in manifest["atlases"]:
        for stack in atlas["stacks"].values():
            c = stack["compact"]
            assert 1 <= c["coarse"]["layers"] <= coarse_count(c["layers"])
            size = (demo_draft_build / c["coarse"]["ktx2"]).stat().st_size
            assert size <= bake.coarse.DEFAULT_BUDGET_BYTES or c["coarse"]["layers"] == 1


def test_an_interrupted_bake_publishes_no_coarse_files_and_resumes(tmp_path, monkeypatch):
    scene = make_site(tmp_path / "scene")
    out = tmp_path / "build"
    real = bake.coarse.write_coarse_stack
    written = []

    def interrupted(build_dir, key, compact, budget_bytes=bake.coarse.DEFAULT_BUDGET_BYTES):
        if written:  # the second stack: Ctrl-C while the coarse start is being written
            raise KeyboardInterrupt
        written.append(real(build_dir, key, compact, budget_bytes))
        return written[-1]

    monkeypatch.setattr(bake.coarse, "write_coarse_stack", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run_bake(scene, out, progress=False, log=lambda msg: None)
    assert written  # it was interrupted half-way through the coarse start
    assert not out.exists()  # nothing published, coarse files or others
    partial = tmp_path / ".build.partial"
    assert partial.is_dir()  # the traced chunks are kept for the resumed bake
    # The one written coarse file was removed with its stack's siblings (all or nothing).
    assert not list((partial / "build").rglob("coarse/*"))

    monkeypatch.setattr(bake.coarse, "write_coarse_stack", real)
    run_bake(scene, out, progress=False, log=lambda msg: None)
    _check_listed(out)
    assert not partial.exists()
