"""Generate the demo site's models: a reconstructed ancient palace hall and its surroundings.

Run from anywhere: ``python scenes/demo/make_models.py``. The output is deterministic (no
randomness without a fixed seed), small (a few thousand triangles) and checked in, so the demo
bakes the same way on every machine; rerun this script only to change the models.

Virtual (the reconstruction, in the style of a 7th-century Asuka palace):
- ``hall.glb``: a stone podium with steps, vermilion columns, white plaster walls, a timber
  frame and a hipped tiled roof. One node per part, so the baker can wrap each in its own
  convex hull (Kakuta's shadowing planes).
- ``gate.glb``: a small roofed gate on its own base.
- ``fence.glb``: a roofed earthen wall (tsuiji-bei) either side of the gate.

Real-world proxies (what stands on the site today):
- ``tree.glb``: a tree, trunk and crown. (The modern visitor centre is a box in scene.toml.)
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
from trimesh.visual.material import PBRMaterial

HERE = Path(__file__).resolve().parent
MODELS = HERE / "models"

# Linear albedos.
STONE = (0.50, 0.47, 0.42)
VERMILION = (0.55, 0.11, 0.06)
PLASTER = (0.80, 0.78, 0.72)
TIMBER = (0.30, 0.17, 0.10)
TILE = (0.16, 0.17, 0.19)
EARTH_WALL = (0.62, 0.52, 0.38)
BARK = (0.22, 0.15, 0.10)
LEAVES = (0.10, 0.18, 0.06)


def _coloured(mesh: trimesh.Trimesh, albedo) -> trimesh.Trimesh:
    rgba = [float(c) for c in albedo] + [1.0]
    mesh.visual = trimesh.visual.TextureVisuals(
        material=PBRMaterial(baseColorFactor=rgba, metallicFactor=0.0, roughnessFactor=1.0)
    )
    return mesh


def box(size, center) -> trimesh.Trimesh:
    m = trimesh.creation.box(extents=size)
    m.apply_translation(center)
    return m


def octagonal_column(radius: float, y0: float, y1: float, x: float, z: float) -> trimesh.Trimesh:
    m = trimesh.creation.cylinder(radius=radius, height=y1 - y0, sections=8)
    # trimesh cylinders run along Z; stand them up along Y.
    m.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))
    m.apply_translation([x, (y0 + y1) / 2, z])
    return m


def hipped_roof(
    width: float, depth: float, ridge: float, y0: float, y1: float, center
) -> trimesh.Trimesh:
    """A closed hipped roof: rectangular eaves at ``y0``, a ridge of length ``ridge`` at ``y1``."""
    cx, cz = center
    w, d, r = width / 2, depth / 2, ridge / 2
    v = np.array(
        [
            [cx - w, y0, cz - d],
            [cx + w, y0, cz - d],
            [cx + w, y0, cz + d],
            [cx - w, y0, cz + d],
            [cx - r, y1, cz],
            [cx + r, y1, cz],
        ]
    )
    f = np.array(
        [
            [0, 1, 2],
            [0, 2, 3],  # soffit (facing down)
            [3, 2, 5],
            [3, 5, 4],  # south slope
            [1, 0, 4],
            [1, 4, 5],  # north slope
            [2, 1, 5],  # east hip
            [0, 3, 4],  # west hip
        ]
    )
    m = trimesh.Trimesh(v, f, process=True)
    trimesh.repair.fix_normals(m)
    return m


def gable_cap(
    length: float, width: float, y0: float, y1: float, center, along_x=True
) -> trimesh.Trimesh:
    """A triangular prism roof along x (or z)."""
    cx, cz = center
    half_l, w = length / 2, width / 2
    v = np.array(
        [
            [-half_l, y0, -w],
            [-half_l, y0, w],
            [-half_l, y1, 0],
            [half_l, y0, -w],
            [half_l, y0, w],
            [half_l, y1, 0],
        ],
        dtype=float,
    )
    if not along_x:
        v = v[:, [2, 1, 0]]
    v[:, 0] += cx
    v[:, 2] += cz
    f = np.array(
        [[0, 1, 2], [3, 5, 4], [0, 3, 4], [0, 4, 1], [1, 4, 5], [1, 5, 2], [0, 2, 5], [0, 5, 3]]
    )
    m = trimesh.Trimesh(v, f, process=True)
    trimesh.repair.fix_normals(m)
    return m


def export(path: Path, nodes: dict[str, tuple[trimesh.Trimesh, tuple]]) -> None:
    scene = trimesh.Scene()
    for name, (mesh, albedo) in nodes.items():
        scene.add_geometry(_coloured(mesh, albedo), node_name=name, geom_name=name)
    path.write_bytes(scene.export(file_type="glb"))
    print(f"{path.relative_to(HERE)}: {sum(len(m.faces) for m, _ in nodes.values())} triangles")


def hall() -> dict:
    podium_top = 1.5
    columns = []
    xs = np.arange(-12.0, 12.01, 4.0)
    for x in xs:
        for z in (-6.0, 6.0):
            columns.append(octagonal_column(0.35, podium_top, 7.0, x, z))
    for z in (-2.0, 2.0):
        for x in (-12.0, 12.0):
            columns.append(octagonal_column(0.35, podium_top, 7.0, x, z))
    walls = [
        box([24.0, 5.0, 0.3], [0.0, podium_top + 2.5, -6.0]),  # north wall
        box([0.3, 5.0, 8.0], [-12.0, podium_top + 2.5, -2.0]),  # west wall
        box([0.3, 5.0, 8.0], [12.0, podium_top + 2.5, -2.0]),  # east wall
    ]
    return {
        "podium": (box([32.0, podium_top, 20.0], [0.0, podium_top / 2, 0.0]), STONE),
        "steps": (box([8.0, podium_top / 2, 2.4], [0.0, podium_top / 4, 11.2]), STONE),
        "columns": (trimesh.util.concatenate(columns), VERMILION),
        "walls": (trimesh.util.concatenate(walls), PLASTER),
        "frame": (box([25.2, 0.8, 13.2], [0.0, 7.4, 0.0]), TIMBER),
        "roof": (hipped_roof(31.0, 19.0, 14.0, 7.8, 13.0, (0.0, 0.0)), TILE),
    }


def gate() -> dict:
    base_top = 0.6
    posts = [octagonal_column(0.28, base_top, 4.4, x, z) for x in (-2.5, 2.5) for z in (-1.5, 1.5)]
    return {
        "base": (box([8.0, base_top, 5.0], [0.0, base_top / 2, 30.0]), STONE),
        "posts": (
            trimesh.util.concatenate([p.apply_translation([0, 0, 30.0]) for p in posts]),
            VERMILION,
        ),
        "beam": (box([6.0, 0.5, 3.6], [0.0, 4.65, 30.0]), TIMBER),
        "roof": (hipped_roof(9.0, 6.0, 4.0, 4.9, 7.0, (0.0, 30.0)), TILE),
    }


def fence() -> dict:
    """Roofed earthen walls from the gate out to east and west, 2.2 m high."""
    nodes = {}
    for side, sign in (("west", -1.0), ("east", 1.0)):
        x_center = sign * 19.0
        wall = box([30.0, 2.2, 0.8], [x_center, 1.1, 30.0])
        cap = gable_cap(30.6, 1.6, 2.2, 2.8, (x_center, 30.0))
        nodes[f"wall_{side}"] = (wall, EARTH_WALL)
        nodes[f"cap_{side}"] = (cap, TILE)
    return nodes


def tree() -> dict:
    trunk = trimesh.creation.cylinder(radius=0.3, height=3.4, sections=8)
    trunk.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))
    trunk.apply_translation([0.0, 1.7, 0.0])
    crown = trimesh.creation.icosphere(subdivisions=2, radius=3.2)
    # A lumpy, slightly flattened crown; deterministic bumps from the vertex directions.
    d = crown.vertices / np.linalg.norm(crown.vertices, axis=1, keepdims=True)
    bumps = (
        1.0 + 0.12 * np.sin(5.0 * d[:, 0]) * np.cos(4.0 * d[:, 2]) + 0.08 * np.sin(7.0 * d[:, 1])
    )
    crown.vertices = d * (3.2 * bumps)[:, None] * np.array([1.0, 0.8, 1.0])
    crown.apply_translation([0.0, 5.6, 0.0])
    return {"trunk": (trunk, BARK), "crown": (crown, LEAVES)}


def main() -> None:
    MODELS.mkdir(exist_ok=True)
    export(MODELS / "hall.glb", hall())
    export(MODELS / "gate.glb", gate())
    export(MODELS / "fence.glb", fence())
    export(MODELS / "tree.glb", tree())


if __name__ == "__main__":
    main()
