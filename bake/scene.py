"""Reading and checking a site description, ``scenes/<site>/scene.toml``.

The format is documented in ``docs/scene-format.md``, and checked against its JSON Schema
(bake/scene_schema.py, which also holds every default); what no one key's schema can say is
checked here. Every problem raises :class:`SceneError` naming the file, the key and what is
wrong, before anything is written. Geometry comes out in
the world frame of docs/architecture.md (metres, +Y up, +X east, -Z north).
"""

from __future__ import annotations

import math
import tomllib
import zoneinfo
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from bake.dome import MAX_LIGHTS, MIN_LIGHTS
from bake.scene_schema import QUALITY_DEFAULTS, SCHEMA, first_problem

# The quality levels (bake_rays etc.) are documented with the rest of the format in the
# schema: direct_rays are visibility rays per point over the whole sky (each light gets
# max(2, ceil(direct_rays / lights)) of them, spread over its patch, so a finer dome costs
# about the same for the same shadow quality); bounce_rays cosine-weighted gather rays per
# texel; cache_spacing_m the spacing of the bounce cache points; texel_scale and view_scale
# multiply every texel size and fixed-view resolution.


class SceneError(ValueError):
    """A mistake in a site description: which file, which key, what is wrong."""

    def __init__(self, path: Path | str, key: str, message: str):
        self.path = str(path)
        self.key = key
        self.message = message
        super().__init__(f"{self.path}: {key}: {message}" if key else f"{self.path}: {message}")


@dataclass
class Part:
    """One piece of the scene's geometry in the world frame.

    Attributes
    ----------
    name : str
        ``object`` or ``object/node`` for a part of a split virtual object.
    object_name : str
        The ``[[virtual]]`` or ``[[real]]`` entry it came from.
    mesh : trimesh.Trimesh
        Triangles in world coordinates, metres.
    albedo : (F, 3) float
        Linear diffuse reflectance of each face.
    """

    name: str
    object_name: str
    mesh: trimesh.Trimesh
    albedo: np.ndarray


@dataclass
class RealProxy:
    """A real-world object standing in for what the camera sees (building, wall, tree)."""

    name: str
    part: Part
    receiver: bool


@dataclass
class View:
    """A fixed, calibrated viewpoint (Sato's Camera A): pinhole intrinsics and pose.

    ``world_from_camera`` maps camera coordinates (OpenCV convention: +X right, +Y down, +Z
    forward) to world coordinates.
    """

    name: str
    width: int
    height: int
    K: np.ndarray  # (3, 3) pixels
    world_from_camera: np.ndarray  # (4, 4)


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
# Key checking


class _Table:
    """A table of a scene.toml already checked against its schema (bake/scene_schema.py), with
    the path of keys that led to it for messages; absent keys read as the schema's default
    (None where there is none: an optional key)."""

    def __init__(self, file: Path, prefix: str, data: dict, schema: dict):
        self.file = file
        self.prefix = prefix
        self.data = data
        self.schema = schema

    def key(self, name: str) -> str:
        return f"{self.prefix}.{name}" if self.prefix else name

    def has(self, name: str) -> bool:
        return name in self.data

    def raw(self, name: str) -> Any:
        prop = self.schema["properties"][name]
        return self.data.get(name, prop.get("default"))

    def number(self, name: str) -> float | int | None:
        value = self.raw(name)
        if value is None:
            return None
        return int(value) if self.schema["properties"][name]["type"] == "integer" else float(value)

    def vector(self, name: str) -> np.ndarray | None:
        value = self.raw(name)
        return None if value is None else np.array([float(x) for x in value])

    def string(self, name: str) -> str | None:
        return self.raw(name)

    def boolean(self, name: str) -> bool:
        return self.raw(name)

    def table(self, name: str) -> _Table:
        return _Table(self.file, self.key(name), self.data.get(name, {}),
                      self.schema["properties"][name])

    def tables(self, name: str) -> list[_Table]:
        items = self.schema["properties"][name]["items"]
        return [_Table(self.file, f"{self.key(name)}[{i}]", v, items)
                for i, v in enumerate(self.data.get(name, []))]


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
    root = _Table(scene_file, "", data, SCHEMA)
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
    world_from_scene = _rotation_y(north_deg)

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
    ground.part = _ground_part(ground)

    virtual: list[Part] = []
    names: set[str] = set()
    for t in root.tables("virtual"):
        obj = t.string("name")
        _unique(names, obj, t, scene_file)
        model = _model_path(t, scene_dir)
        sources.append(model)
        parts_mode = t.string("parts")
        albedo = t.vector("albedo")
        transform = world_from_scene @ _object_transform(t)
        virtual += _load_model_parts(model, obj, transform, albedo, parts_mode, t)
    if not virtual:
        raise SceneError(scene_file, "virtual", "the site needs at least one [[virtual]] model")

    real: list[RealProxy] = []
    for t in root.tables("real"):
        obj = t.string("name")
        _unique(names, obj, t, scene_file)
        albedo = t.vector("albedo")
        receiver = t.boolean("receiver")
        box = t.vector("box_m")
        transform = world_from_scene @ _object_transform(t)
        if box is not None and t.has("model"):
            raise SceneError(scene_file, t.key("model"), "give either box_m or model, not both")
        if box is not None:
            mesh = trimesh.creation.box(extents=box)
            mesh.apply_translation([0.0, box[1] / 2.0, 0.0])  # base on the ground
            mesh.apply_transform(transform)
            part = Part(obj, obj, mesh, np.tile(albedo, (len(mesh.faces), 1)))
        elif t.has("model"):
            model = _model_path(t, scene_dir)
            sources.append(model)
            parts = _load_model_parts(model, obj, transform, albedo, "whole", t)
            part = parts[0]
        else:
            raise SceneError(scene_file, t.key("box_m"), "a [[real]] proxy needs box_m or model")
        real.append(RealProxy(obj, part, receiver))

    views = []
    for t in root.tables("view"):
        views.append(_load_view(t, scene_file, world_from_scene, settings.view_scale))
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


def _load_settings(root: _Table, file: Path, lights: int | None, quality: str | None) -> Settings:
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


def _unique(names: set[str], name: str, t: _Table, file: Path) -> None:
    if name in names:
        raise SceneError(file, t.key("name"), f"the name {name!r} is used twice")
    names.add(name)


def _model_path(t: _Table, scene_dir: Path) -> Path:
    rel = t.string("model")
    path = (scene_dir / rel).resolve()
    if not path.is_file():
        raise SceneError(t.file, t.key("model"), f"model file {rel!r} not found (looked at {path})")
    if path.suffix.lower() not in (".glb", ".gltf", ".obj"):
        raise SceneError(t.file, t.key("model"), f"{rel!r}: models must be .glb, .gltf or .obj")
    return path


def _rotation_y(angle_deg: float) -> np.ndarray:
    """4x4 right-handed rotation about +Y (counter-clockwise seen from above)."""
    a = np.radians(angle_deg)
    m = np.eye(4)
    m[0, 0], m[0, 2], m[2, 0], m[2, 2] = np.cos(a), np.sin(a), -np.sin(a), np.cos(a)
    return m


def _object_transform(t: _Table) -> np.ndarray:
    """scene_from_object: scale, then yaw about +Y, then translation."""
    translation = t.vector("translation_m")
    yaw = t.number("yaw_deg")
    scale = t.number("scale")
    m = _rotation_y(yaw)
    m[:3, :3] *= scale
    m[:3, 3] = translation
    return m


def _load_model_parts(
    path: Path, obj: str, transform: np.ndarray, albedo_override, mode: str, t: _Table
) -> list[Part]:
    """Meshes of a model file in world coordinates, one part per node (or one in all)."""
    try:
        loaded = trimesh.load(str(path), force="scene", process=False)
    except Exception as exc:  # trimesh raises many kinds for broken files
        raise SceneError(t.file, t.key("model"), f"cannot read {path.name}: {exc}") from None
    parts: list[Part] = []
    for node in loaded.graph.nodes_geometry:
        node_transform, geom_name = loaded.graph[node]
        geom = loaded.geometry[geom_name]
        if not isinstance(geom, trimesh.Trimesh) or len(geom.faces) == 0:
            continue
        mesh = trimesh.Trimesh(
            vertices=np.asarray(geom.vertices, dtype=float),
            faces=np.asarray(geom.faces),
            process=False,
        )
        mesh.apply_transform(transform @ node_transform)
        if not np.all(np.isfinite(mesh.vertices)):
            raise SceneError(
                t.file, t.key("model"), f"{path.name}: node {node!r} has non-finite vertices"
            )
        albedo = albedo_override if albedo_override is not None else _material_albedo(geom)
        if albedo is None:
            raise SceneError(
                t.file,
                t.key("albedo"),
                f"{path.name}: node {node!r} has no base colour; give albedo = [r, g, b]",
            )
        keep = mesh.area_faces > 1e-10
        mesh.update_faces(keep)
        mesh.remove_unreferenced_vertices()
        parts.append(Part(f"{obj}/{node}", obj, mesh, np.tile(albedo, (len(mesh.faces), 1))))
    if not parts or sum(p.mesh.area for p in parts) < 1e-8:
        raise SceneError(t.file, t.key("model"), f"{path.name}: degenerate mesh (no area)")
    for p in parts:
        if len(p.mesh.faces) == 0:
            raise SceneError(t.file, t.key("model"), f"{path.name}: node {p.name!r} is degenerate")
    if mode == "whole" and len(parts) > 1:
        mesh = trimesh.util.concatenate([p.mesh for p in parts])
        return [Part(obj, obj, mesh, np.concatenate([p.albedo for p in parts]))]
    return parts


def _material_albedo(geom: trimesh.Trimesh) -> np.ndarray | None:
    """Linear base colour of a mesh's material, or ``None`` if it has none."""
    visual = geom.visual
    material = getattr(visual, "material", None)
    if material is None:
        return None
    factor = getattr(material, "baseColorFactor", None)
    if factor is not None:
        return np.asarray(factor[:3], dtype=float) / 255.0
    diffuse = getattr(material, "diffuse", None)
    if diffuse is not None:
        return np.asarray(diffuse[:3], dtype=float) / 255.0
    return None


def _ground_part(ground: Ground) -> Part:
    cx, cz = ground.center_m
    sx, sz = ground.size_m
    x0, x1, z0, z1 = cx - sx / 2, cx + sx / 2, cz - sz / 2, cz + sz / 2
    vertices = np.array([[x0, 0, z0], [x1, 0, z0], [x1, 0, z1], [x0, 0, z1]], dtype=float)
    faces = np.array([[0, 2, 1], [0, 3, 2]])  # counter-clockwise from above: normal +Y
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
    return Part("ground", "ground", mesh, np.tile(ground.albedo, (2, 1)))


def _load_view(t: _Table, file: Path, world_from_scene: np.ndarray, view_scale: float) -> View:
    name = t.string("name")
    width = t.number("width")
    height = t.number("height")
    position = t.vector("position_m")
    look_at = t.vector("look_at_m")
    fov = t.number("fov_y_deg")
    intr = t.raw("intrinsics")
    if (fov is None) == (intr is None):
        raise SceneError(file, t.key("fov_y_deg"), "give exactly one of fov_y_deg or intrinsics")
    if intr is not None:
        it = t.table("intrinsics")
        fx, fy, cx, cy = (it.number(k) for k in ("fx", "fy", "cx", "cy"))
        for name, value, limit in (("cx", cx, width), ("cy", cy, height)):
            if value > limit:
                raise SceneError(file, it.key(name), f"must be at most {limit}, got {value}")
    else:
        fy = fx = 0.5 * height / math.tan(math.radians(fov) / 2.0)
        cx, cy = width / 2.0, height / 2.0
    forward = look_at - position
    if np.linalg.norm(forward) < 1e-6:
        raise SceneError(file, t.key("look_at_m"), "must differ from position_m")
    forward /= np.linalg.norm(forward)
    if abs(forward[1]) > 0.999:
        raise SceneError(file, t.key("look_at_m"), "the view may not look straight up or down")
    right = np.cross(forward, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    scene_from_camera = np.eye(4)
    scene_from_camera[:3, 0], scene_from_camera[:3, 1], scene_from_camera[:3, 2] = (
        right,
        down,
        forward,
    )
    scene_from_camera[:3, 3] = position
    # Resolution scaled by the quality level, intrinsics with it.
    s = view_scale
    w, h = max(16, round(width * s)), max(16, round(height * s))
    K = np.array(
        [[fx * w / width, 0, cx * w / width], [0, fy * h / height, cy * h / height], [0, 0, 1]]
    )
    return View(name, w, h, K, world_from_scene @ scene_from_camera)
