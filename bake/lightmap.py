"""The lightmap atlas: the virtual objects' and the real proxies' own surfaces unwrapped with
xatlas into one atlas, and the points and normals of its texels (the receivers' texel
convention: bake.receivers). Faces that rest face-down on the ground (a podium's underside)
are hidden from every viewpoint: they get no texels and are left out of the model.
"""

from __future__ import annotations

import cv2
import numpy as np
import trimesh
import xatlas

from bake.denoise import surface_labels
from bake.receivers import BLOCK, Atlas, Receiver, round_up
from daylit.spherical import normalize


def lightmap_atlas(parts, texel_m: float, max_size: int) -> Atlas:
    """Unwrap every part with xatlas into one lightmap atlas and sample its texels.

    When the parts do not fit in ``max_size`` squared, the texel size grows by 25% until
    they do.
    """
    # Unwrapped faces per part: all but those resting on the ground (15 % of the demo's
    # texels were the undersides of its podium, walls and proxies, traced, factored and
    # encoded for nothing).
    kept = []  # (F,) bool per part; xatlas returns the faces it is given in their order
    for part in parts:
        resting = faces_resting_on_ground(part.mesh)
        kept.append(~resting if not resting.all() else np.ones_like(resting))
    while True:
        atlas = xatlas.Atlas()
        for part, keep in zip(parts, kept, strict=True):
            atlas.add_mesh(
                part.mesh.vertices.astype(np.float32), part.mesh.faces[keep].astype(np.uint32)
            )
        pack_options = xatlas.PackOptions()
        pack_options.texels_per_unit = 1.0 / texel_m
        pack_options.padding = 2
        pack_options.bilinear = True
        pack_options.blockAlign = True
        pack_options.resolution = 0
        atlas.generate(xatlas.ChartOptions(), pack_options)
        if atlas.atlas_count == 1 and max(atlas.width, atlas.height) <= max_size:
            break
        texel_m *= 1.25
    width, height = round_up(atlas.width, BLOCK), round_up(atlas.height, BLOCK)
    owner = np.full((height, width), -1, dtype=np.int32)  # global triangle id per texel
    receivers, all_tris, all_uv, all_normals, all_parts = [], [], [], [], []
    base = 0
    for i, part in enumerate(parts):
        vmap, faces, uv = atlas.get_mesh(i)
        vertices = part.mesh.vertices[vmap]
        texel_uv = uv * np.array([atlas.width, atlas.height])
        face_normals = part.mesh.face_normals[kept[i]]
        # Vertex normals per unwrapped vertex: flat shading, faces are split at seams anyway.
        normals = np.zeros_like(vertices)
        np.add.at(normals, faces.ravel(), np.repeat(face_normals, 3, axis=0))
        normals = normalize(normals + 1e-12)
        tri_uv = texel_uv[faces]
        for k, t in enumerate(tri_uv):
            polygon = np.round((t - 0.5) * 16).astype(np.int32)  # texel centres, 4-bit subpixel
            cv2.fillPoly(owner, [polygon], int(base + k), lineType=cv2.LINE_8, shift=4)
        all_tris.append(vertices[faces])
        all_uv.append(tri_uv)
        all_normals.append(face_normals)
        all_parts.append(np.full(len(faces), i))
        x0, y0 = np.floor(texel_uv.min(axis=0)).astype(int)
        x1, y1 = np.ceil(texel_uv.max(axis=0)).astype(int)
        receivers.append(
            Receiver(
                name=part.name,
                kind="surface",
                object=part.object_name,
                size=(x1 - x0, y1 - y0),
                vertices=vertices,
                faces=faces,
                normals=normals,
                texel_uv=texel_uv - [x0, y0],
                rect=(int(x0), int(y0), int(x1 - x0), int(y1 - y0)),
            )
        )
        base += len(faces)
    tris = np.concatenate(all_tris)
    tri_uv = np.concatenate(all_uv)
    face_normals = np.concatenate(all_normals)
    ys, xs = np.nonzero(owner >= 0)
    tri = owner[ys, xs]
    centre = np.stack([xs + 0.5, ys + 0.5], axis=1)
    bary = _barycentric_clamped(centre, tri_uv[tri])
    points = np.einsum("mk,mkj->mj", bary, tris[tri])
    result = Atlas("lightmap", "lightmap", {"I": "all"}, texel_m, receivers, None, width, height)
    result.texels = np.stack([xs, ys], axis=1)
    result.points = points
    result.normals = face_normals[tri]
    result.labels = surface_labels(np.concatenate(all_parts)[tri], result.normals)
    return result


def faces_resting_on_ground(mesh: trimesh.Trimesh, tolerance_m: float = 0.01) -> np.ndarray:
    """(F,) bool: faces facing straight down with every vertex on or below the ground plane
    (y = 0, within ``tolerance_m``), which no viewpoint above the ground can see."""
    top_y = mesh.vertices[mesh.faces][:, :, 1].max(axis=1)
    return (mesh.face_normals[:, 1] < -0.99) & (top_y <= tolerance_m)


def _barycentric_clamped(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Barycentric coordinates (m, 3) of 2D points (m, 2) in triangles (m, 3, 2), clamped
    into the triangle so texels along chart borders sample the surface, not beside it."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    v0, v1, v2 = b - a, c - a, p - a
    d00 = np.einsum("ij,ij->i", v0, v0)
    d01 = np.einsum("ij,ij->i", v0, v1)
    d11 = np.einsum("ij,ij->i", v1, v1)
    d20 = np.einsum("ij,ij->i", v2, v0)
    d21 = np.einsum("ij,ij->i", v2, v1)
    denom = d00 * d11 - d01 * d01
    denom = np.where(np.abs(denom) > 1e-20, denom, 1e-20)
    v = (d11 * d20 - d01 * d21) / denom
    w = (d00 * d21 - d01 * d20) / denom
    bary = np.clip(np.stack([1.0 - v - w, v, w], axis=1), 0.0, 1.0)
    return bary / bary.sum(axis=1, keepdims=True)
