"""The generated large site (scenes/palace/make_site.py; issue 20's "A large site"): the same
bytes on every run, the triangle counts it states as an independent glTF parser (pygltflib)
reads them, its two knobs scaling what they say (``--roof-cells`` triangles with nearly the
same area, ``--halls`` area), and a scene the baker's loader takes."""

from __future__ import annotations

import hashlib
import importlib.util
from pathlib import Path

import numpy as np
import pygltflib
import trimesh

REPO = Path(__file__).resolve().parents[2]


def make_site():
    spec = importlib.util.spec_from_file_location(
        "palace_make_site", REPO / "scenes" / "palace" / "make_site.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def digest(folder: Path) -> dict:
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def gltf_triangles(path: Path, mesh_name: str | None = None) -> int:
    """Triangles of every mesh primitive (of the mesh ``mesh_name`` alone if given), counted
    from the accessors (pygltflib)."""
    gltf = pygltflib.GLTF2().load(str(path))
    total = 0
    for mesh in gltf.meshes:
        if mesh_name is not None and mesh.name != mesh_name:
            continue
        for primitive in mesh.primitives:
            assert primitive.mode in (None, pygltflib.TRIANGLES)
            total += gltf.accessors[primitive.indices].count // 3
    return total


def area_m2(path: Path) -> float:
    return float(trimesh.load(path, force="scene").to_geometry().area)


def test_the_site_is_the_same_every_run_and_counts_its_triangles(tmp_path):
    site = make_site()
    first = site.write_site(tmp_path / "a", halls=2, cells_u=12)
    site.write_site(tmp_path / "b", halls=2, cells_u=12)
    assert digest(tmp_path / "a") == digest(tmp_path / "b")
    for name, triangles in first.items():
        assert gltf_triangles(tmp_path / "a" / "models" / name) == triangles, name


def test_roof_cells_add_triangles_and_halls_add_area(tmp_path):
    site = make_site()
    coarse = site.write_site(tmp_path / "coarse", halls=2, cells_u=12)
    site.write_site(tmp_path / "fine", halls=2, cells_u=48)
    hall = "hall_00.glb"
    # 4x the cells along the eaves and up the slope: the roof's triangles about 16x
    roof = [gltf_triangles(tmp_path / size / "models" / hall, "roof")
            for size in ("coarse", "fine")]
    assert 12 * roof[0] < roof[1] < 20 * roof[0]
    coarse_area = area_m2(tmp_path / "coarse" / "models" / hall)
    fine_area = area_m2(tmp_path / "fine" / "models" / hall)
    assert abs(fine_area / coarse_area - 1) < 0.05
    more = site.write_site(tmp_path / "more", halls=4, cells_u=12)
    areas = [sum(area_m2(tmp_path / size / "models" / name) for name in models)
             for size, models in (("coarse", coarse), ("more", more))]
    assert areas[1] > 1.6 * areas[0]  # twice the halls, a longer gallery round them


def test_the_baker_loads_it(tmp_path):
    from bake.scene import load_site

    site = make_site()
    site.write_site(tmp_path, halls=3, cells_u=8)
    loaded = load_site(tmp_path / "scene.toml")
    # each hall six parts (podium, steps, columns, walls, frame, roof), the gallery two, the
    # demo's gate four
    assert len(loaded.virtual) == 3 * 6 + 2 + 4
    assert loaded.views and loaded.views[0].name == "kiosk"
    tops = [float(np.max(p.mesh.vertices[:, 1])) for p in loaded.virtual]
    assert max(tops) > 12.0  # the halls' ridges stand 13 m up
