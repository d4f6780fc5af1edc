"""The geometry a site description names, in the world frame (docs/architecture.md: metres,
+Y up, +X east, -Z north): model files split into parts, box proxies, the ground plane and
the fixed views' cameras. Problems raise :class:`bake.scenetable.SceneError` naming the key.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from bake.scenetable import SceneError, SceneTable


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


def model_path(t: SceneTable, scene_dir: Path) -> Path:
    rel = t.string("model")
    path = (scene_dir / rel).resolve()
    if not path.is_file():
        raise SceneError(t.file, t.key("model"), f"model file {rel!r} not found (looked at {path})")
    if path.suffix.lower() not in (".glb", ".gltf", ".obj"):
        raise SceneError(t.file, t.key("model"), f"{rel!r}: models must be .glb, .gltf or .obj")
    return path


def rotation_y(angle_deg: float) -> np.ndarray:
    """4x4 right-handed rotation about +Y (counter-clockwise seen from above)."""
    a = np.radians(angle_deg)
    m = np.eye(4)
    m[0, 0], m[0, 2], m[2, 0], m[2, 2] = np.cos(a), np.sin(a), -np.sin(a), np.cos(a)
    return m


def object_transform(t: SceneTable) -> np.ndarray:
    """scene_from_object: scale, then yaw about +Y, then translation."""
    translation = t.vector("translation_m")
    yaw = t.number("yaw_deg")
    scale = t.number("scale")
    m = rotation_y(yaw)
    m[:3, :3] *= scale
    m[:3, 3] = translation
    return m


def load_model_parts(
    path: Path, obj: str, transform: np.ndarray, albedo_override, mode: str, t: SceneTable
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
        albedo = albedo_override if albedo_override is not None else material_albedo(geom)
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


def material_albedo(geom: trimesh.Trimesh) -> np.ndarray | None:
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


def box_part(name: str, box_m: np.ndarray, transform: np.ndarray, albedo: np.ndarray) -> Part:
    """A box proxy of extents ``box_m`` (3,), its base on the ground, placed by ``transform``
    (4, 4 world_from_object), one ``albedo`` (3,) for every face."""
    mesh = trimesh.creation.box(extents=box_m)
    mesh.apply_translation([0.0, box_m[1] / 2.0, 0.0])  # base on the ground
    mesh.apply_transform(transform)
    return Part(name, name, mesh, np.tile(albedo, (len(mesh.faces), 1)))


def ground_part(center_m: tuple[float, float], size_m: tuple[float, float],
                albedo: np.ndarray) -> Part:
    """The real ground: a rectangle at y = 0 centred on ``center_m`` (x, z) of ``size_m``
    (along x, along z), facing +Y."""
    cx, cz = center_m
    sx, sz = size_m
    x0, x1, z0, z1 = cx - sx / 2, cx + sx / 2, cz - sz / 2, cz + sz / 2
    vertices = np.array([[x0, 0, z0], [x1, 0, z0], [x1, 0, z1], [x0, 0, z1]], dtype=float)
    faces = np.array([[0, 2, 1], [0, 3, 2]])  # counter-clockwise from above: normal +Y
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
    return Part("ground", "ground", mesh, np.tile(albedo, (2, 1)))


def load_view(t: SceneTable, file: Path, world_from_scene: np.ndarray, view_scale: float) -> View:
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
