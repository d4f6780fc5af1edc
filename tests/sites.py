"""Tiny site descriptions for tests: written to a temporary folder, baked in seconds."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import trimesh

BASE_SCENE = """
[site]
id = "{site_id}"
name = "test site"
latitude_deg = 34.47
longitude_deg = 135.82
elevation_m = 100.0
timezone = "Asia/Tokyo"

[dome]
lights = {lights}

[quality]
default = "draft"
bounces = {bounces}

[quality.draft]
direct_rays = {direct_rays}
bounce_rays = {bounce_rays}
cache_spacing_m = 1.0
texel_scale = 1.0
view_scale = 1.0

[bake]
seed = 7

[ground]
center_m = [0.0, 0.0]
size_m = [{ground_m}, {ground_m}]
albedo = {ground_albedo}

[shadowing]
texel_m = {ground_texel_m}
hull_texel_m = {hull_texel_m}
min_sun_elevation_deg = 20.0

[lightmap]
texel_m = {lightmap_texel_m}
"""


def write_obj(path: Path, mesh: trimesh.Trimesh) -> None:
    path.write_text(
        trimesh.exchange.obj.export_obj(mesh, include_normals=False, include_texture=False)
    )


def make_site(
    root: Path,
    *,
    virtual: list[tuple[str, trimesh.Trimesh, tuple]] | None = None,
    real: str = "",
    views: str = "",
    lights: int = 40,
    direct_rays: int = 160,
    bounce_rays: int = 16,
    bounces: int = 1,
    ground_m: float = 40.0,
    ground_albedo=(0.2, 0.2, 0.2),
    ground_texel_m: float = 1.0,
    hull_texel_m: float = 0.5,
    lightmap_texel_m: float = 0.5,
    extra: str = "",
    site_id: str = "test",
) -> Path:
    """Write ``root/scene.toml`` and OBJ models; returns the scene folder.

    ``virtual`` lists (name, mesh in world coordinates, albedo); by default a 2 m box.
    ``bounces`` is 1 here (the known answers of most tests are one bounce's), not the
    format's default.
    """
    root.mkdir(parents=True, exist_ok=True)
    (root / "models").mkdir(exist_ok=True)
    if virtual is None:
        box = trimesh.creation.box(extents=[2.0, 2.0, 2.0])
        box.apply_translation([0.0, 1.0, 0.0])
        virtual = [("box", box, (0.5, 0.5, 0.5))]
    text = BASE_SCENE.format(
        site_id=site_id,
        lights=lights,
        direct_rays=direct_rays,
        bounce_rays=bounce_rays,
        bounces=bounces,
        ground_m=ground_m,
        ground_albedo=list(ground_albedo),
        ground_texel_m=ground_texel_m,
        hull_texel_m=hull_texel_m,
        lightmap_texel_m=lightmap_texel_m,
    )
    for name, mesh, albedo in virtual:
        write_obj(root / "models" / f"{name}.obj", mesh)
        text += textwrap.dedent(f"""
            [[virtual]]
            name = "{name}"
            model = "models/{name}.obj"
            albedo = {list(albedo)}
            """)
    text += textwrap.dedent(real) + textwrap.dedent(views) + textwrap.dedent(extra)
    (root / "scene.toml").write_text(text)
    return root


def real_box(name: str, box_m, translation_m, albedo=(0.5, 0.5, 0.5)) -> str:
    """The scene.toml table of a real proxy box (docs/scene-format.md), for ``make_site``'s
    ``real``."""
    return textwrap.dedent(f"""
        [[real]]
        name = "{name}"
        box_m = {list(map(float, box_m))}
        translation_m = {list(map(float, translation_m))}
        albedo = {list(map(float, albedo))}
        """)


def sphere(radius: float, center) -> trimesh.Trimesh:
    m = trimesh.creation.icosphere(subdivisions=4, radius=radius)
    m.apply_translation(np.asarray(center, dtype=float))
    return m


def box(size, base_center) -> trimesh.Trimesh:
    m = trimesh.creation.box(extents=size)
    m.apply_translation([base_center[0], base_center[1] + size[1] / 2, base_center[2]])
    return m


def scene_estimate_site(folder: Path) -> Path:
    """The scene estimate's test site in ``folder`` (the scene folder, returned): a real
    building (8 x 5 x 6 m, albedo 0.55/0.45/0.35) and wall, a small virtual box out of the way,
    a kiosk view from the north, ground albedo 0.22/0.20/0.18 (tests/server/conftest.py
    ``scene_build``, the phone estimate's tests and benchmark)."""
    return make_site(
        folder,
        virtual=[("sign", box([1.0, 1.0, 1.0], [10.0, 0.0, 12.0]), (0.5, 0.5, 0.5))],
        real=real_box("building", (8.0, 5.0, 6.0), (0.0, 0.0, 0.0), (0.55, 0.45, 0.35))
        + real_box("wall", (0.4, 2.0, 9.0), (-8.0, 0.0, -6.0), (0.40, 0.42, 0.45)),
        views="""
            [[view]]
            name = "kiosk"
            width = 320
            height = 180
            fov_y_deg = 45.0
            position_m = [3.0, 7.0, -24.0]
            look_at_m = [0.0, 0.5, -3.0]
            """,
        ground_m=60.0,
        ground_albedo=(0.22, 0.20, 0.18),
    )
