"""Generate a large site at the scale of a palace reconstruction (issue 20, "A large site").

    python scenes/palace/make_site.py OUT_DIR [--halls 12] [--roof-cells 100]

writes ``OUT_DIR/scene.toml`` and ``OUT_DIR/models/*.glb``, a site `daylit bake OUT_DIR` takes:
a walled palace compound of ``--halls`` halls on podiums in rows either side of a central
court (each hall the demo's, with 16-sided columns and a tiled roof), a roofed gallery around
the compound with a gate in its south side, and today's site around it (modern buildings as
boxes, trees). The models are not checked in (tens of megabytes); the output is
deterministic, so every machine bakes the same site.

The two knobs scale different costs of a bake, so that a benchmark can tell them apart:
- ``--halls`` adds buildings: surface area, so receiver texels, hull planes and parts;
- ``--roof-cells`` is the roofs' tiling (cells along each slope's eaves; rows in proportion):
  triangles with almost no more area (a tiled roof is a corrugated surface, 2 triangles a cell).
At the defaults: 358,000 triangles in 78 virtual parts.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import trimesh

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "demo"))
import make_models as demo  # noqa: E402  (the demo's parts and colours, shared)

HALL_SPACING_M = (44.0, 34.0)  # centre to centre across and along the compound
COLUMN_SECTIONS = 16
TILE_PITCH_M = 0.3  # one corrugation (a row of round tiles) across the slope
TILE_DEPTH_M = 0.06


def column(radius: float, y0: float, y1: float, x: float, z: float) -> trimesh.Trimesh:
    """A standing cylinder with ``COLUMN_SECTIONS`` sides, base at ``y0``, top at ``y1``."""
    m = trimesh.creation.cylinder(radius=radius, height=y1 - y0, sections=COLUMN_SECTIONS)
    m.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))
    m.apply_translation([x, (y0 + y1) / 2, z])
    return m


def tiled_slope(eave_a, eave_b, ridge_a, ridge_b, cells_u: int) -> trimesh.Trimesh:
    """One roof slope as a corrugated quad (eave edge a-b, ridge edge a-b; (3,) metres each):
    ``cells_u`` cells along the eaves, rows up the slope in proportion, the surface raised by
    rows of round tiles (``TILE_PITCH_M`` apart, ``TILE_DEPTH_M`` deep) along the fall line.
    Open surface, faces toward the sky."""
    eave_a, eave_b, ridge_a, ridge_b = (np.asarray(p, float) for p in (eave_a, eave_b,
                                                                       ridge_a, ridge_b))
    length = np.linalg.norm(eave_b - eave_a)
    fall = np.linalg.norm((ridge_a + ridge_b) / 2 - (eave_a + eave_b) / 2)
    cells_v = max(2, round(cells_u * fall / max(length, 1e-9)))
    u = np.linspace(0.0, 1.0, cells_u + 1)
    v = np.linspace(0.0, 1.0, cells_v + 1)
    uu, vv = np.meshgrid(u, v, indexing="xy")  # (cells_v + 1, cells_u + 1)
    eave = eave_a + uu[..., None] * (eave_b - eave_a)
    ridge = ridge_a + uu[..., None] * (ridge_b - ridge_a)
    points = eave + vv[..., None] * (ridge - eave)
    # the slope's upward normal, for the tiles' relief
    normal = np.cross(eave_b - eave_a, (ridge_a + ridge_b) / 2 - (eave_a + eave_b) / 2)
    normal /= np.linalg.norm(normal)
    if normal[1] < 0:
        normal = -normal
    across_m = uu * length
    points = points + (TILE_DEPTH_M * np.abs(np.sin(np.pi * across_m / TILE_PITCH_M)))[
        ..., None] * normal
    index = np.arange(points.shape[0] * points.shape[1]).reshape(points.shape[:2])
    a, b = index[:-1, :-1].ravel(), index[:-1, 1:].ravel()
    c, d = index[1:, 1:].ravel(), index[1:, :-1].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    mesh = trimesh.Trimesh(points.reshape(-1, 3), faces, process=False)
    mesh.update_faces(mesh.nondegenerate_faces())  # a hip's cells close to a point at its top
    mesh.remove_unreferenced_vertices()
    if np.mean(mesh.face_normals[:, 1]) < 0:
        mesh.invert()
    return mesh


def tiled_hipped_roof(width, depth, ridge, y0, y1, center, cells_u) -> trimesh.Trimesh:
    """The demo's hipped roof (eaves ``width`` x ``depth`` at ``y0``, a ridge of length
    ``ridge`` at ``y1``) with tiled slopes and hips, and its soffit."""
    cx, cz = center
    w, d, r = width / 2, depth / 2, ridge / 2
    e = [np.array(p, float) for p in ([cx - w, y0, cz - d], [cx + w, y0, cz - d],
                                      [cx + w, y0, cz + d], [cx - w, y0, cz + d])]
    ra, rb = np.array([cx - r, y1, cz]), np.array([cx + r, y1, cz])
    hips_u = max(2, round(cells_u * depth / width))
    slopes = [
        tiled_slope(e[3], e[2], ra, rb, cells_u),  # south
        tiled_slope(e[1], e[0], rb, ra, cells_u),  # north
        tiled_slope(e[2], e[1], rb, rb, hips_u),  # east hip
        tiled_slope(e[0], e[3], ra, ra, hips_u),  # west hip
    ]
    soffit = trimesh.Trimesh(np.array(e), [[0, 1, 2], [0, 2, 3]], process=False)
    if soffit.face_normals[0][1] > 0:
        soffit.invert()
    return trimesh.util.concatenate(slopes + [soffit])


def hall(center, cells_u: int) -> dict:
    """The demo's hall (podium, steps, columns, walls, frame, roof) at ``center`` (x, z)
    metres, with round columns and a tiled roof."""
    cx, cz = center
    podium_top = 1.5
    columns = [column(0.35, podium_top, 7.0, cx + x, cz + z)
               for x in np.arange(-12.0, 12.01, 4.0) for z in (-6.0, 6.0)]
    columns += [column(0.35, podium_top, 7.0, cx + x, cz + z)
                for z in (-2.0, 2.0) for x in (-12.0, 12.0)]
    walls = [
        demo.box([24.0, 5.0, 0.3], [cx, podium_top + 2.5, cz - 6.0]),
        demo.box([0.3, 5.0, 8.0], [cx - 12.0, podium_top + 2.5, cz - 2.0]),
        demo.box([0.3, 5.0, 8.0], [cx + 12.0, podium_top + 2.5, cz - 2.0]),
    ]
    return {
        "podium": (demo.box([32.0, podium_top, 20.0], [cx, podium_top / 2, cz]), demo.STONE),
        "steps": (demo.box([8.0, podium_top / 2, 2.4], [cx, podium_top / 4, cz + 11.2]),
                  demo.STONE),
        "columns": (trimesh.util.concatenate(columns), demo.VERMILION),
        "walls": (trimesh.util.concatenate(walls), demo.PLASTER),
        "frame": (demo.box([25.2, 0.8, 13.2], [cx, 7.4, cz]), demo.TIMBER),
        "roof": (tiled_hipped_roof(31.0, 19.0, 14.0, 7.8, 13.0, (cx, cz), cells_u), demo.TILE),
    }


def hall_centres(halls: int) -> list[tuple[float, float]]:
    """Two rows facing a central court (x = +-HALL_SPACING_M/2), front to back along -z."""
    per_row = -(-halls // 2)
    centres = []
    for i in range(halls):
        side = -1.0 if i % 2 == 0 else 1.0
        row = i // 2
        centres.append((side * HALL_SPACING_M[0] / 2, -row * HALL_SPACING_M[1]
                        + (per_row - 1) * HALL_SPACING_M[1] / 2))
    return centres


def gallery(extent_x: float, z_front: float, z_back: float, cells_u: int) -> dict:
    """A roofed gallery (kairo) round the compound: posts every 4 m, a tiled gable roof on
    each side, a gap for the gate in the middle of the front (z_front) side."""
    posts, roofs = [], []
    sides = [  # (start, end) of each run along its axis, and where it stands
        ("x", -extent_x, -5.0, z_front), ("x", 5.0, extent_x, z_front),
        ("x", -extent_x, extent_x, z_back),
        ("z", z_back, z_front, -extent_x), ("z", z_back, z_front, extent_x),
    ]
    for axis, a, b, at in sides:
        for t in np.arange(a, b + 0.01, 4.0):
            for off in (-1.5, 1.5):
                x, z = (t, at + off) if axis == "x" else (at + off, t)
                posts.append(column(0.2, 0.0, 3.2, x, z))
        run = b - a + 3.0
        if axis == "x":
            e0, e1 = (a - 1.5, 3.2, at + 2.0), (b + 1.5, 3.2, at + 2.0)
            r0, r1 = (a - 1.5, 4.6, at), (b + 1.5, 4.6, at)
            f0, f1 = (b + 1.5, 3.2, at - 2.0), (a - 1.5, 3.2, at - 2.0)
        else:
            e0, e1 = (at - 2.0, 3.2, a - 1.5), (at - 2.0, 3.2, b + 1.5)
            r0, r1 = (at, 4.6, a - 1.5), (at, 4.6, b + 1.5)
            f0, f1 = (at + 2.0, 3.2, b + 1.5), (at + 2.0, 3.2, a - 1.5)
        cells = max(4, round(cells_u * run / 31.0))
        roofs += [tiled_slope(e0, e1, r0, r1, cells), tiled_slope(f0, f1, r1, r0, cells)]
    return {"posts": (trimesh.util.concatenate(posts), demo.VERMILION),
            "roof": (trimesh.util.concatenate(roofs), demo.TILE)}


SCENE = """# A large generated site (scenes/palace/make_site.py; issue 20, "A large site"): {halls}
# halls in a walled compound, a gallery round it, today's buildings and trees around it.
# Format: docs/scene-format.md.

[site]
id = "palace"
name = "Generated palace compound ({halls} halls)"
latitude_deg = 34.4716
longitude_deg = 135.8206
elevation_m = 105.0
timezone = "Asia/Tokyo"
north_deg = 0.0

[dome]
lights = 400

[quality]
default = "final"

[bake]
seed = 1

[ground]
center_m = [0.0, {ground_z:.1f}]
size_m = [{ground_x:.1f}, {ground_zs:.1f}]
albedo = [0.26, 0.25, 0.20]

[shadowing]
texel_m = 0.5
hull_texel_m = 0.25
hull_offset_m = 0.03
min_sun_elevation_deg = 10.0

[lightmap]
texel_m = 0.2
{parts}
[[view]]
name = "kiosk"
width = 640
height = 360
fov_y_deg = 50.0
position_m = [0.0, 6.0, {kiosk_z:.1f}]
look_at_m = [0.0, 4.0, {look_z:.1f}]
"""


def write_site(out: Path, halls: int, cells_u: int) -> dict:
    """Write the site into ``out``; returns {model file: triangles}."""
    models = out / "models"
    models.mkdir(parents=True, exist_ok=True)
    triangles = {}
    parts = []

    def export(name: str, nodes: dict) -> None:
        (models / f"{name}.glb").write_bytes(_scene_of(nodes).export(file_type="glb"))
        triangles[f"{name}.glb"] = sum(len(m.faces) for m, _ in nodes.values())
        parts.append(f'\n[[virtual]]\nname = "{name}"\nmodel = "models/{name}.glb"\n')

    centres = hall_centres(halls)
    for i, centre in enumerate(centres):
        export(f"hall_{i:02d}", hall(centre, cells_u))
    xs = [abs(c[0]) for c in centres]
    zs = [c[1] for c in centres]
    extent_x = max(xs) + 22.0
    z_front, z_back = max(zs) + 22.0, min(zs) - 18.0
    export("gallery", gallery(extent_x, z_front, z_back, cells_u))
    gate = demo.gate()
    for mesh, _ in gate.values():
        mesh.apply_translation([0.0, 0.0, z_front - 30.0])
    export("gate", gate)
    # today's site: modern buildings (boxes) and trees outside the compound
    for i, x in enumerate((-extent_x - 30.0, extent_x + 30.0)):
        parts.append(
            f'\n[[real]]\nname = "building_{i}"\nbox_m = [18.0, 7.0, 12.0]\n'
            f"translation_m = [{x:.1f}, 0.0, {z_front - 10.0:.1f}]\nyaw_deg = {5.0 + 10 * i}\n"
            "albedo = [0.55, 0.55, 0.53]\n"
        )
    trees = demo.tree()
    (models / "tree.glb").write_bytes(_scene_of(trees).export(file_type="glb"))
    triangles["tree.glb"] = sum(len(m.faces) for m, _ in trees.values())
    for i, x in enumerate(np.linspace(-extent_x, extent_x, 6)):
        parts.append(
            f'\n[[real]]\nname = "tree_{i}"\nmodel = "models/tree.glb"\n'
            f"translation_m = [{x:.1f}, 0.0, {z_front + 14.0:.1f}]\n"
            "albedo = [0.10, 0.17, 0.06]\nreceiver = false\n"
        )
    span_x = 2 * extent_x + 100.0
    span_z = (z_front - z_back) + 100.0
    (out / "scene.toml").write_text(SCENE.format(
        halls=halls, ground_z=(z_front + z_back) / 2, ground_x=span_x, ground_zs=span_z,
        parts="".join(parts), kiosk_z=z_front + 30.0, look_z=(z_front + z_back) / 2,
    ))
    return triangles


def _scene_of(nodes: dict) -> trimesh.Scene:
    scene = trimesh.Scene()
    for node, (mesh, albedo) in nodes.items():
        scene.add_geometry(demo._coloured(mesh, albedo), node_name=node, geom_name=node)
    return scene


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="folder to write scene.toml and models/ into")
    ap.add_argument("--halls", type=int, default=12, help="halls in the compound (default 12)")
    ap.add_argument("--roof-cells", type=int, default=100,
                    help="roof tiling: cells along each slope's eaves (default 100)")
    args = ap.parse_args(argv)
    if args.halls < 1 or args.roof_cells < 2:
        ap.error("--halls must be at least 1 and --roof-cells at least 2")
    triangles = write_site(args.out, args.halls, args.roof_cells)
    for name, n in triangles.items():
        print(f"  {name}: {n} triangles")
    print(f"{args.out / 'scene.toml'}: {sum(triangles.values())} triangles in "
          f"{len(triangles)} models")


if __name__ == "__main__":
    main()
