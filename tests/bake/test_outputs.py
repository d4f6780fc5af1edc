"""Round trips of everything the baker writes: GLB, EXR masters, manifest."""

from __future__ import annotations

import errno
import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
import trimesh

from bake.gltf import read_site_glb
from daylit import manifest as manifest_io
from daylit import stackio
from daylit.stackio import read_stack_exr, write_stack_exr

REPO = Path(__file__).resolve().parents[2]


def test_exr_stack_reads_back_exactly(tmp_path):
    rng = np.random.default_rng(0)
    stack = rng.normal(size=(12, 9, 41, 3)).astype(np.float32) * 1e3
    stack[0, 0, 0] = [np.float32(1e-30), np.float32(3.4e38), -0.0]
    write_stack_exr(tmp_path / "s.exr", stack)
    back = read_stack_exr(tmp_path / "s.exr")
    assert back.dtype == np.float32
    assert np.array_equal(back.view(np.uint32), stack.view(np.uint32))  # bit for bit


def test_a_full_disk_while_writing_an_exr_leaves_nothing_and_says_so(tmp_path, monkeypatch):
    """OpenEXR reports a full disk as a RuntimeError after writing part of the file: the
    partial file goes, and callers get the OSError (ENOSPC) they can handle."""
    class FullDisk:
        def __init__(self, header, channels):
            pass

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def write(self, path):
            Path(path).write_bytes(b"half an EXR")
            raise RuntimeError(f'Failed to write pixel data to image file "{path}". '
                               "No space left on device.")

    monkeypatch.setattr(stackio.OpenEXR, "File", FullDisk)
    with pytest.raises(OSError) as caught:
        write_stack_exr(tmp_path / "s.exr", np.zeros((4, 4, 2, 3), np.float32))
    assert caught.value.errno == errno.ENOSPC
    assert list(tmp_path.iterdir()) == []


def test_manifest_validates_and_lists_every_file(demo_draft_build):
    manifest = manifest_io.load(demo_draft_build, check_files=True)
    listed = {f["path"] for f in manifest["files"]}
    on_disk = {
        p.relative_to(demo_draft_build).as_posix()
        for p in demo_draft_build.rglob("*")
        if p.is_file()
    } - {"manifest.json"}
    assert listed == on_disk
    schema_file = REPO / "daylit" / "schemas" / "manifest.schema.json"
    assert json.loads(schema_file.read_text())["title"].startswith("daylit build manifest")


def test_manifest_rejects_a_tampered_file(demo_draft_build, tmp_path):
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(demo_draft_build, copy)
    glb = copy / "site.glb"
    glb.write_bytes(glb.read_bytes()[:-4] + b"\0\0\0\0")
    with pytest.raises(manifest_io.ManifestError, match="checksum"):
        manifest_io.load(copy, check_files=True)


def test_stacks_have_the_dome_size_and_the_atlas_size(demo_draft_build):
    manifest = manifest_io.load(demo_draft_build)
    n = manifest["dome"]["count"]
    for atlas in manifest["atlases"]:
        for stack in atlas["stacks"].values():
            data = read_stack_exr(demo_draft_build / stack["master"])
            assert data.shape == (atlas["height"], atlas["width"], n, 3)
            assert np.all(np.isfinite(data))
            # Below 0 only in a texel whose centre is buried under a wall and whose value is
            # its chord extended there (bake.contact, docs/manifest.md): ground and lightmap
            # texels along contact lines, a few in a hundred; never on hull planes.
            negative = data.min(axis=(2, 3)) < 0.0
            limit = 0.0 if atlas["id"] == "hull" else 0.03
            assert negative.mean() <= limit, (stack["master"], negative.mean())
    for view in manifest["views"]:
        for stack in view["stacks"].values():
            data = read_stack_exr(demo_draft_build / stack["master"])
            assert data.shape == (view["height"], view["width"], n, 3)


def test_glb_reloads_with_trimesh_and_matches_the_manifest(demo_draft_build):
    manifest = manifest_io.load(demo_draft_build)
    scene = trimesh.load(demo_draft_build / "site.glb", force="scene")
    names = {n["name"] for n in manifest["model"]["nodes"]}
    assert set(scene.graph.nodes_geometry) == names
    roles = {n["role"] for n in manifest["model"]["nodes"]}
    assert roles == {"virtual", "real", "ground", "shadowing-plane"}
    nodes = read_site_glb(demo_draft_build / "site.glb")
    atlases = {a["id"] for a in manifest["atlases"]}
    for node in nodes.values():
        if node["uv"] is not None:
            assert node["extras"]["atlas"] in atlases
            assert node["uv"].min() >= 0.0 and node["uv"].max() <= 1.0
        assert len(node["faces"]) > 0
        assert np.all(np.isfinite(node["vertices"]))
    # Virtual parts keep the albedo of the demo's models (vermilion columns).
    columns = nodes["virtual/hall/columns"]["albedo"]
    assert np.allclose(columns, [0.55, 0.11, 0.06], atol=2 / 255)


def test_glb_passes_the_khronos_validator(demo_draft_build):
    result = subprocess.run(
        ["node", str(REPO / "tools" / "validate_gltf.mjs"), str(demo_draft_build / "site.glb")],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=120,
    )
    report = json.loads(result.stdout)
    assert report["issues"]["numErrors"] == 0, report["issues"]["messages"][:5]
    assert report["issues"]["numWarnings"] == 0, report["issues"]["messages"][:5]
    assert result.returncode == 0


def test_view_mask_marks_the_virtual_pixels(demo_draft_build):
    import cv2

    manifest = manifest_io.load(demo_draft_build)
    view = manifest["views"][0]
    mask = cv2.imread(str(demo_draft_build / view["mask"]), cv2.IMREAD_UNCHANGED)
    assert mask.shape == (view["height"], view["width"])
    assert set(np.unique(mask)) == {0, 128, 255}  # real, sky, virtual
    assert 0.05 < (mask == 255).mean() < 0.8
    assert 0.05 < (mask == 128).mean() < 0.8
    O = read_stack_exr(demo_draft_build / view["stacks"]["O"]["master"]).sum(axis=2)
    S = read_stack_exr(demo_draft_build / view["stacks"]["S"]["master"]).sum(axis=2)
    sky = mask == 128
    assert np.all(O[sky] == 0) and np.all(S[sky] == 0)  # the client draws the sky itself
    assert np.all(O[~sky].sum(-1) > 0)  # every other pixel sees a lit surface
    # Behind a virtual roof there may be sky, so S is zero there; elsewhere S sees surfaces.
    assert np.all(S[mask == 0].sum(-1) > 0)
    # A virtual pixel shows the virtual surface in O and what is behind it in S.
    virtual = mask == 255
    assert np.mean(np.abs(O[virtual] - S[virtual]).sum(-1) > 1e-4) > 0.95
