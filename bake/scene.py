"""Reading and checking a site description, ``scenes/<site>/scene.toml``.

The format is documented in ``docs/scene-format.md``, and checked against its JSON Schema
(bake/scene_schema.py, which also holds every default); what no one key's schema can say is
checked here. Every problem raises :class:`SceneError` naming the file, the key and what is
wrong, before anything is written. Geometry comes out in
the world frame of docs/architecture.md (metres, +Y up, +X east, -Z north).
"""

from __future__ import annotations

import tomllib
import zoneinfo
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bake.dome import MAX_LIGHTS, MIN_LIGHTS
from bake.scene_schema import QUALITY_DEFAULTS, SCHEMA, first_problem
from bake.scenegeometry import (
    Part,
    View,
    box_part,
    ground_part,
    load_model_parts,
    load_view,
    model_path,
    object_transform,
    rotation_y,
)
from bake.scenetable import SceneError, SceneTable

__all__ = ["Ground", "Part", "RealProxy", "SceneError", "Settings", "Site", "View", "load_site"]

# The quality levels (bake_rays etc.) are documented with the rest of the format in the
# schema: direct_rays are visibility rays per point over the whole sky (each light gets
# max(2, ceil(direct_rays / lights)) of them, spread over its patch, so a finer dome costs
# about the same for the same shadow quality); bounce_rays cosine-weighted gather rays per
# texel; cache_spacing_m the spacing of the bounce cache points; texel_scale and view_scale
# multiply every texel size and fixed-view resolution.


@dataclass
class RealProxy:
    """A real-world object standing in for what the camera sees (building, wall, tree)."""

    name: str
    part: Part
    receiver: bool


@dataclass
class Ground:
    """The real ground: a horizontal rectangle at y = 0 in the world frame."""

    center_m: tuple[float, float]  # (x, z)
    size_m: tuple[float, float]  # (along x, along z)
    albedo: np.ndarray  # (3,)
    part: Part | None = None


@dataclass
class Settings:
    lights: int
    quality: str
    direct_rays: int
    bounce_rays: int
    bounces: int
    cache_spacing_m: float
    texel_scale: float
    view_scale: float
    seed: int
    shadow_texel_m: float
    hull_texel_m: float
    hull_offset_m: float
    min_sun_elevation_deg: float
    min_plane_area_m2: float
    max_planes_per_part: int
    max_atlas_size: int
    lightmap_texel_m: float
    compression: dict = field(default_factory=dict)


@dataclass
class Site:
    """A whole site description, checked and in world coordinates."""

    scene_dir: Path
    scene_file: Path
    scene_id: str
    name: str
    latitude_deg: float
    longitude_deg: float
    elevation_m: float
    timezone: str
    north_deg: float
    ground: Ground
    virtual: list[Part]
    real: list[RealProxy]
    views: list[View]
    settings: Settings
    source_files: list[Path]


# --------------------------------------------------------------------------------------------
# Loading


def load_site(
    scene_dir: Path | str,
    lights: int | None = None,
    quality: str | None = None,
    budget: float | None = None,
) -> Site:
    """Read and check ``scene_dir/scene.toml`` and every model it names.

    ``lights``, ``quality`` and ``budget`` override the file's ``dome.lights``,
    ``quality.default`` and ``compression.budget``.
    Raises :class:`SceneError` on the first problem found.
    """
    scene_dir = Path(scene_dir)
    scene_file = scene_dir / "scene.toml" if scene_dir.is_dir() else scene_dir
    if scene_file.name != "scene.toml" and scene_dir.is_dir():
        scene_file = scene_dir / "scene.toml"
    if not scene_file.is_file():
        raise SceneError(scene_file, "", "no such file; a site is a folder with a scene.toml")
    scene_dir = scene_file.parent
    try:
        data = tomllib.loads(scene_file.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(scene_file, "", f"not valid TOML: {exc}") from None
    except UnicodeDecodeError:
        raise SceneError(scene_file, "", "not UTF-8 text") from None

    problem = first_problem(data)
    if problem is not None:
        raise SceneError(scene_file, *problem)
    root = SceneTable(scene_file, "", data, SCHEMA)
    site_t = root.table("site")
    name = site_t.string("name")
    latitude = site_t.number("latitude_deg")
    longitude = site_t.number("longitude_deg")
    elevation = site_t.number("elevation_m")
    timezone = site_t.string("timezone")
    try:
        zoneinfo.ZoneInfo(timezone)
    except (zoneinfo.ZoneInfoNotFoundError, ValueError):
        raise SceneError(
            scene_file,
            site_t.key("timezone"),
            f"unknown time zone {timezone!r} (use an IANA name such as 'Asia/Tokyo')",
        ) from None
    north_deg = site_t.number("north_deg")
    site_id = site_t.string("id") or scene_dir.resolve().name
    if not all(c.isalnum() or c in "-_" for c in site_id):
        raise SceneError(scene_file, site_t.key("id"), "may hold only letters, digits, - and _")
    world_from_scene = rotation_y(north_deg)

    settings = _load_settings(root, scene_file, lights, quality)
    if budget is not None:
        if not 1e-5 <= budget <= 0.5:
            raise SceneError(
                "--budget", "", f"must be within [1e-05, 0.5] (0.001% to 50%), got {budget:g}"
            )
        settings.compression["budget"] = budget
    sources = [scene_file]

    ground_t = root.table("ground")
    ground = Ground(
        center_m=tuple(ground_t.vector("center_m")),
        size_m=tuple(ground_t.vector("size_m")),
        albedo=ground_t.vector("albedo"),
    )
    ground.part = ground_part(ground.center_m, ground.size_m, ground.albedo)

    virtual: list[Part] = []
    names: set[str] = set()
    for t in root.tables("virtual"):
        obj = t.string("name")
        _unique(names, obj, t, scene_file)
        model = model_path(t, scene_dir)
        sources.append(model)
        parts_mode = t.string("parts")
        albedo = t.vector("albedo")
        transform = world_from_scene @ object_transform(t)
        virtual += load_model_parts(model, obj, transform, albedo, parts_mode, t)
    if not virtual:
        raise SceneError(scene_file, "virtual", "the site needs at least one [[virtual]] model")

    real: list[RealProxy] = []
    for t in root.tables("real"):
        obj = t.string("name")
        _unique(names, obj, t, scene_file)
        albedo = t.vector("albedo")
        receiver = t.boolean("receiver")
        box = t.vector("box_m")
        transform = world_from_scene @ object_transform(t)
        if box is not None and t.has("model"):
            raise SceneError(scene_file, t.key("model"), "give either box_m or model, not both")
        if box is not None:
            part = box_part(obj, box, transform, albedo)
        elif t.has("model"):
            model = model_path(t, scene_dir)
            sources.append(model)
            parts = load_model_parts(model, obj, transform, albedo, "whole", t)
            part = parts[0]
        else:
            raise SceneError(scene_file, t.key("box_m"), "a [[real]] proxy needs box_m or model")
        real.append(RealProxy(obj, part, receiver))

    views = []
    for t in root.tables("view"):
        views.append(load_view(t, scene_file, world_from_scene, settings.view_scale))
        _unique(names, views[-1].name, t, scene_file)
    return Site(
        scene_dir=scene_dir,
        scene_file=scene_file,
        scene_id=site_id,
        name=name,
        latitude_deg=latitude,
        longitude_deg=longitude,
        elevation_m=elevation,
        timezone=timezone,
        north_deg=north_deg,
        ground=ground,
        virtual=virtual,
        real=real,
        views=views,
        settings=settings,
        source_files=sources,
    )


def _load_settings(
    root: SceneTable, file: Path, lights: int | None, quality: str | None
) -> Settings:
    dome_t = root.table("dome")
    file_lights = dome_t.number("lights")
    if lights is not None and not MIN_LIGHTS <= lights <= MAX_LIGHTS:
        raise SceneError("--lights", "", f"must be between {MIN_LIGHTS} and {MAX_LIGHTS}")

    quality_t = root.table("quality")
    default_quality = quality_t.string("default")
    bounces = quality_t.number("bounces")
    chosen = quality or default_quality
    if chosen not in QUALITY_DEFAULTS:
        raise SceneError("--quality", "", f"must be one of {', '.join(QUALITY_DEFAULTS)}")
    levels = {}
    for level, defaults in QUALITY_DEFAULTS.items():
        t = quality_t.table(level)
        levels[level] = {name: t.number(name) for name in defaults}

    bake_t = root.table("bake")
    seed = bake_t.number("seed")

    shadow_t = root.table("shadowing")
    shadow_texel = shadow_t.number("texel_m")
    hull_texel = shadow_t.number("hull_texel_m")
    hull_offset = shadow_t.number("hull_offset_m")
    min_elev = shadow_t.number("min_sun_elevation_deg")
    min_area = shadow_t.number("min_plane_area_m2")
    max_planes = shadow_t.number("max_planes_per_part")
    max_atlas = shadow_t.number("max_atlas_size")

    lightmap_t = root.table("lightmap")
    lightmap_texel = lightmap_t.number("texel_m")

    compression_t = root.table("compression")
    compression = {
        "budget": compression_t.number("budget"),
        "max_rank": compression_t.number("max_rank"),
        "encoding": compression_t.string("encoding"),
        "selected_lights": compression_t.number("selected_lights"),
        "sun_bounce_budget": compression_t.number("sun_bounce_budget"),
        "sun_bounce_lights": compression_t.number("sun_bounce_lights"),
        "sun_bounce_encoding": compression_t.string("sun_bounce_encoding"),
        "sun_bounce_sharing": compression_t.string("sun_bounce_sharing"),
    }

    q = levels[chosen]
    return Settings(
        lights=lights if lights is not None else file_lights,
        quality=chosen,
        direct_rays=q["direct_rays"],
        bounce_rays=q["bounce_rays"],
        bounces=bounces,
        cache_spacing_m=q["cache_spacing_m"],
        texel_scale=q["texel_scale"],
        view_scale=q["view_scale"],
        seed=seed,
        shadow_texel_m=shadow_texel,
        hull_texel_m=hull_texel,
        hull_offset_m=hull_offset,
        min_sun_elevation_deg=min_elev,
        min_plane_area_m2=min_area,
        max_planes_per_part=max_planes,
        max_atlas_size=max_atlas,
        lightmap_texel_m=lightmap_texel,
        compression=compression,
    )


def _unique(names: set[str], name: str, t: SceneTable, file: Path) -> None:
    if name in names:
        raise SceneError(file, t.key("name"), f"the name {name!r} is used twice")
    names.add(name)


