"""Receivers: the surfaces whose texels get basis values, packed into atlases.

Three atlases per site:

- ``hull`` — Kakuta's shadowing planes on the convex hull of each virtual part (objects are
  split into parts by their glTF nodes first), offset slightly outward. ``I`` is irradiance
  with everything present, ``d`` with nothing (the unshadowed shading the client applies to
  the virtual object in hull-plane mode), so ``I / d`` darkens that shading.
- ``ground`` — shadowing planes on the real receiving surfaces: the ground and the faces of
  real proxies marked ``receiver``, wherever a virtual object's shadow can fall for suns and
  sky patches down to ``min_sun_elevation_deg``. ``d`` is irradiance with the real proxies
  only, so ``I / d`` is exactly the virtual objects' effect on the real surface.
- ``lightmap`` — the virtual objects' and the real proxies' own surfaces through a lightmap
  unwrap (xatlas; bake.lightmap): irradiance ``I`` with self-shadowing and the real world's
  shadows, seen without the parallax of hull planes from any viewpoint. Faces that rest
  face-down on the ground (a podium's underside) are hidden from every viewpoint: they get
  no texels and are left out of the model.

Texel convention: texel ``(x, y)`` is column ``x``, row ``y`` from the top of the atlas image;
its centre has texture coordinate ``((x + 0.5) / W, (y + 0.5) / H)`` as in glTF (origin top
left). Plane receivers carry a one-texel border computed like any other texel, so bilinear
filtering never reads a neighbour's texels, and cover whole 4x4 blocks (xatlas aligns lightmap
charts the same way), so no block of the compressed textures spans two receivers.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
import trimesh

from daylit.spherical import normalize

PAD_TEXELS = 1
BLOCK = 4  # texture sizes are multiples of the 4x4 compression block


@dataclass
class Receiver:
    """One receiving surface inside an atlas.

    Attributes
    ----------
    name, kind, object : what it is (``kind`` in hull | ground | wall | surface)
    size : (w, h) texels it occupies (planes: including the border)
    rect : (x, y, w, h) where it sits in the atlas, set by packing
    vertices, faces, normals : its mesh for the GLB, world frame (normals per vertex)
    texel_uv : (V, 2) vertex positions in the receiver's own texel units (x right, y down)
    plane : dict or None; origin_m, axis_u, axis_v, normal, texel_m of a plane receiver
    """

    name: str
    kind: str
    object: str | None
    size: tuple[int, int]
    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    texel_uv: np.ndarray
    plane: dict | None = None
    rect: tuple[int, int, int, int] = (0, 0, 0, 0)
    # Lightmap receivers: texel -> (triangle, barycentric) sampling, set by the unwrap.
    samples: tuple | None = None

    def atlas_uv(self, width: int, height: int) -> np.ndarray:
        """(V, 2) glTF texture coordinates of the mesh vertices in the packed atlas."""
        x, y = self.rect[0], self.rect[1]
        return (self.texel_uv + np.array([x, y])) / np.array([width, height])

    def manifest_entry(self) -> dict:
        entry = {"name": self.name, "kind": self.kind, "rect": [int(v) for v in self.rect]}
        if self.object:
            entry["object"] = self.object
        if self.plane:
            entry.update({k: _rounded(v) for k, v in self.plane.items()})
        return entry


@dataclass
class Atlas:
    """Receivers packed into one texture, with a sample point for every texel they use.

    Attributes
    ----------
    id, role : ``hull``/``ground``/``lightmap``; ``shadowing`` or ``lightmap``
    stacks : dict stack name -> light configuration (see ``bake.irradiance``)
    width, height : texels
    texels : (N, 2) int, (x, y) of every texel that gets a value
    points, normals : (N, 3) world-frame sample point and surface normal of each texel
    labels : (N,) int, the flat surface each texel lies on (the bounce is smoothed within one)
    contact : dict or None, texels whose sample point was moved onto a contact line
        (bake.contact.move_buried_samples)
    """

    id: str
    role: str
    stacks: dict
    texel_m: float
    receivers: list[Receiver]
    d_reference: str | None = None
    width: int = 0
    height: int = 0
    texels: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    normals: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    labels: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    # Texels moved onto contact lines (bake.contact.move_buried_samples), None before.
    contact: dict | None = None

    @property
    def count(self) -> int:
        return len(self.texels)

    def to_image(self, values: np.ndarray) -> np.ndarray:
        """Scatter per-texel ``values`` (N, ...) into an image (H, W, ...), zeros elsewhere."""
        image = np.zeros((self.height, self.width) + values.shape[1:], dtype=values.dtype)
        image[self.texels[:, 1], self.texels[:, 0]] = values
        return image

    def label_image(self) -> np.ndarray:
        """(H, W) int: each texel's surface label, -1 where there is no texel."""
        image = np.full((self.height, self.width), -1, dtype=np.int64)
        image[self.texels[:, 1], self.texels[:, 0]] = self.labels
        return image

    def coverage(self) -> np.ndarray:
        """(H, W) bool: which texels carry values."""
        mask = np.zeros((self.height, self.width), dtype=bool)
        mask[self.texels[:, 1], self.texels[:, 0]] = True
        return mask


def _rounded(value):
    if isinstance(value, np.ndarray):
        return [round(float(x), 9) for x in value]
    return round(float(value), 9)


# --------------------------------------------------------------------------------------------
# Plane receivers


def plane_receiver(name, kind, obj, triangles, normal, texel_m, offset_m=0.0) -> Receiver:
    """A planar receiver covering ``triangles`` (F, 3, 3), with a texel grid in its plane.

    The grid is aligned with the polygon's minimum-area bounding rectangle and has a one-texel
    border; the mesh is the triangles moved ``offset_m`` along ``normal``.
    """
    normal = normalize(np.asarray(normal, dtype=float))
    points = triangles.reshape(-1, 3) + offset_m * normal
    t1 = normalize(
        np.cross(normal, [0.0, 1.0, 0.0])
        if abs(normal[1]) < 0.9
        else np.cross(normal, [1.0, 0.0, 0.0])
    )
    t2 = np.cross(normal, t1)
    flat = np.stack([points @ t1, points @ t2], axis=1)
    (_, _), (_, _), angle_deg = cv2.minAreaRect(flat.astype(np.float32))
    a = np.radians(angle_deg)
    axis_u = np.cos(a) * t1 + np.sin(a) * t2
    axis_v = np.cross(normal, axis_u)
    u, v = points @ axis_u, points @ axis_v
    w = int(np.ceil((u.max() - u.min()) / texel_m - 1e-9)) + 2 * PAD_TEXELS
    h = int(np.ceil((v.max() - v.min()) / texel_m - 1e-9)) + 2 * PAD_TEXELS
    # Whole 4x4 blocks: with every rectangle block-aligned in the atlas, no compressed block
    # mixes two receivers (otherwise the shadow ratio is off at such seams: docs/benchmarks.md
    # "Figures behind choices in the code").
    w, h = (
        round_up(max(w, 2 * PAD_TEXELS + 1), BLOCK),
        round_up(max(h, 2 * PAD_TEXELS + 1), BLOCK),
    )
    origin = u.min() * axis_u + v.min() * axis_v + (points[0] @ normal) * normal
    origin = origin - PAD_TEXELS * texel_m * (axis_u + axis_v)
    texel_uv = np.stack(
        [(u - u.min()) / texel_m + PAD_TEXELS, (v - v.min()) / texel_m + PAD_TEXELS], 1
    )
    faces = np.arange(len(points)).reshape(-1, 3)
    return Receiver(
        name=name,
        kind=kind,
        object=obj,
        size=(w, h),
        vertices=points,
        faces=faces,
        normals=np.tile(normal, (len(points), 1)),
        texel_uv=texel_uv,
        plane={
            "origin_m": origin,
            "axis_u": axis_u,
            "axis_v": axis_v,
            "normal": normal,
            "texel_m": texel_m,
        },
    )


def plane_texel_points(receiver: Receiver) -> tuple[np.ndarray, np.ndarray]:
    """Grid texels of a plane receiver: local (x, y) (h*w, 2) and world points (h*w, 3)."""
    w, h = receiver.size
    p = receiver.plane
    xs, ys = np.meshgrid(np.arange(w), np.arange(h))
    local = np.stack([xs.ravel(), ys.ravel()], axis=1)
    world = (
        p["origin_m"]
        + ((local[:, 0:1] + 0.5) * p["texel_m"]) * p["axis_u"]
        + ((local[:, 1:2] + 0.5) * p["texel_m"]) * p["axis_v"]
    )
    return local, world


def coplanar_groups(mesh: trimesh.Trimesh) -> list[np.ndarray]:
    """Face indices of each plane of a mesh: trimesh's facets plus lone faces."""
    grouped = np.zeros(len(mesh.faces), dtype=bool)
    groups = []
    for facet in mesh.facets:
        groups.append(np.asarray(facet))
        grouped[facet] = True
    groups += [np.array([i]) for i in np.flatnonzero(~grouped)]
    return groups


def bounding_polytope(mesh: trimesh.Trimesh, max_planes: int) -> trimesh.Trimesh:
    """The convex hull of ``mesh``, or, if it has more than ``max_planes`` planes (a curved
    object), a coarser convex polytope that still encloses every vertex.

    The coarse polytope takes its plane normals from the hull of a farthest-point sample of
    the hull's vertices and moves each plane out to the mesh's support distance along its
    normal; the planes' half-space intersection is the polytope.
    """
    from scipy.spatial import HalfspaceIntersection

    hull = mesh.convex_hull
    if len(coplanar_groups(hull)) <= max_planes:
        return hull
    points = hull.vertices
    count = max(4, max_planes // 2 + 2)  # a hull of k points has at most 2k - 4 faces
    chosen = [int(np.argmax(np.linalg.norm(points - points.mean(axis=0), axis=1)))]
    distance = np.linalg.norm(points - points[chosen[0]], axis=1)
    while len(chosen) < min(count, len(points)):
        chosen.append(int(np.argmax(distance)))
        distance = np.minimum(distance, np.linalg.norm(points - points[chosen[-1]], axis=1))
    coarse = trimesh.Trimesh(points[chosen]).convex_hull
    normals = np.array([coarse.face_normals[g[0]] for g in coplanar_groups(coarse)])
    support = (points @ normals.T).max(axis=0)  # (planes,)
    halfspaces = np.concatenate([normals, -support[:, None]], axis=1)  # n.x - d <= 0
    corners = HalfspaceIntersection(halfspaces, points.mean(axis=0)).intersections
    return trimesh.Trimesh(corners).convex_hull


def hull_receivers(
    parts, texel_m: float, offset_m: float, min_area_m2: float, max_planes: int = 24
) -> list[Receiver]:
    """Shadowing planes on the convex hull of every virtual part (Kakuta 2.1.1); a curved
    part gets a coarser enclosing polytope of at most about ``max_planes`` planes."""
    receivers = []
    for part in parts:
        hull = bounding_polytope(part.mesh, max_planes)
        for k, group in enumerate(coplanar_groups(hull)):
            tris = hull.vertices[hull.faces[group]]
            if hull.area_faces[group].sum() < min_area_m2 or tris[..., 1].max() < 0.05:
                continue  # too small to matter, or lying on the ground under the object
            normal = hull.face_normals[group[0]]
            receivers.append(
                plane_receiver(
                    f"hull/{part.name}/{k}",
                    "hull",
                    part.object_name,
                    tris,
                    normal,
                    texel_m,
                    offset_m,
                )
            )
    return receivers


def drop_buried(receivers: list[Receiver], scene, probes: int = 9, rays: int = 24) -> list:
    """Receivers whose plane is not buried inside other (closed) geometry.

    Each plane is probed at up to ``probes`` of its texel centres with ``rays`` directions;
    it is dropped when at least 90 % of the rays find their origin inside a solid: they
    cross more back faces than front ones on their way out (:func:`bake.contact.solid_depth`;
    no view can ever see such a plane, and its texels would all be black). Why not the first
    hit alone (the rule before): where parts overlap, a plane inside one part sees another
    part's faces inside it from the front, and was kept (a plinth's planes inside a hall,
    facing a screen also inside it: tests/bake/test_receivers.py). The rays are turned
    upward: the ground is an open surface, not a solid's face, and a downward ray from
    inside a part meets the part's underside or the ground in one place, whichever the
    tracer finds first (the count is then one off); upward rays never meet it, and where a
    point lies does not depend on the direction it is probed in.
    """
    from bake import tracing_loops as loops
    from bake.cachepoints import lattice
    from bake.contact import solid_depth
    from bake.raytrace import RAY_OFFSET_M

    uv = lattice(rays)
    kept = []
    for receiver in receivers:
        _, world = plane_texel_points(receiver)
        pick = np.linspace(0, len(world) - 1, min(probes, len(world))).astype(int)
        points = np.ascontiguousarray(world[pick], dtype=np.float64)
        normals = np.repeat(np.asarray(receiver.plane["normal"], np.float64)[None, :], len(pick), 0)
        origins = np.empty((len(pick) * rays, 3), dtype=np.float32)
        all_dirs = np.empty_like(origins)
        loops.cosine_weighted_rays(
            points, normals, uv, np.zeros((len(pick), 2)), RAY_OFFSET_M, origins, all_dirs
        )
        all_dirs[:, 1] = np.abs(all_dirs[:, 1])
        depth, _ = solid_depth(scene, origins, all_dirs)
        if (depth > 0).mean() < 0.9:
            kept.append(receiver)
    return kept


# --------------------------------------------------------------------------------------------
# Where can a virtual object's shadow fall?


def shadow_directions(site, min_elevation_deg: float, dome_centroids: np.ndarray) -> np.ndarray:
    """Directions toward the sun over a year (every 10 days, every 20 minutes) and toward the
    sky patches, all at least ``min_elevation_deg`` high: ``(m, 3)`` unit vectors."""
    import pandas as pd

    from daylit.sky import direction_from_azimuth_elevation, sun_positions

    times = pd.date_range("2025-01-01", "2025-12-31 23:59", freq="20min", tz=site.timezone)
    times = times[(times.day_of_year % 10) == 1]
    az, el = sun_positions(site.latitude_deg, site.longitude_deg, site.elevation_m, times)
    keep = el >= min_elevation_deg
    suns = direction_from_azimuth_elevation(az[keep], el[keep]).reshape(-1, 3)
    sky_el = np.degrees(np.arcsin(np.clip(dome_centroids[:, 1], -1, 1)))
    sky = dome_centroids[sky_el >= min_elevation_deg]
    dirs = np.concatenate([suns, sky])
    # Suns repeat day to day: thin them to about one per degree.
    rounded = np.round(dirs * 60.0)
    _, first = np.unique(rounded, axis=0, return_index=True)
    return dirs[np.sort(first)]


def reached(points, normals, directions, virtual_scene, batch: int = 2_000_000) -> np.ndarray:
    """Which points can be shadowed by a virtual object: any ray to ``directions`` from the
    point (above its surface) hits virtual geometry. Returns ``(m,)`` bool."""
    from bake.raytrace import RAY_OFFSET_M

    out = np.zeros(len(points), dtype=bool)
    per = max(1, batch // max(len(directions), 1))
    for start in range(0, len(points), per):
        p = points[start : start + per]
        n = normals[start : start + per]
        facing = n @ directions.T > 0.0  # (b, m)
        pi, di = np.nonzero(facing)
        origins = p[pi] + RAY_OFFSET_M * n[pi]
        hit = virtual_scene.occluded(origins, directions[di])
        out[start : start + per] = np.bincount(pi[hit], minlength=len(p)) > 0
    return out


def ground_receivers(site, directions, virtual_scene, texel_m: float) -> list[Receiver]:
    """Rectangles of the ground where virtual shadows can fall (one per connected region)."""
    ground = site.ground
    cx, cz = ground.center_m
    sx, sz = ground.size_m
    probe_m = max(2.0 * texel_m, 1.0)
    nx, nz = max(2, int(np.ceil(sx / probe_m))), max(2, int(np.ceil(sz / probe_m)))
    xs = cx - sx / 2 + (np.arange(nx) + 0.5) * sx / nx
    zs = cz - sz / 2 + (np.arange(nz) + 0.5) * sz / nz
    gx, gz = np.meshgrid(xs, zs)
    points = np.stack([gx.ravel(), np.zeros(gx.size), gz.ravel()], axis=1)
    normals = np.tile([0.0, 1.0, 0.0], (len(points), 1))
    mask = reached(points, normals, directions, virtual_scene).reshape(nz, nx)
    # Soft sky shadows reach a little beyond the probed rays: widen by a few metres.
    grow = max(1, int(np.ceil(3.0 / probe_m)))
    mask = cv2.dilate(mask.astype(np.uint8), np.ones((2 * grow + 1, 2 * grow + 1), np.uint8)) > 0
    count, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    receivers = []
    for label in range(1, count):
        rows, cols = np.nonzero(labels == label)
        x0 = max(cx - sx / 2, xs[cols.min()] - sx / nx / 2)
        x1 = min(cx + sx / 2, xs[cols.max()] + sx / nx / 2)
        z0 = max(cz - sz / 2, zs[rows.min()] - sz / nz / 2)
        z1 = min(cz + sz / 2, zs[rows.max()] + sz / nz / 2)
        # Two triangles, counter-clockwise seen from above (normal +Y).
        quad = np.array([[x0, 0, z0], [x1, 0, z0], [x1, 0, z1], [x0, 0, z1]], dtype=float)
        tris = quad[[[0, 2, 1], [0, 3, 2]]]
        receivers.append(
            plane_receiver(
                f"ground/{label - 1}", "ground", None, tris, [0.0, 1.0, 0.0], texel_m, 0.0
            )
        )
    return receivers


def wall_receivers(site, directions, virtual_scene, texel_m, min_area_m2) -> list[Receiver]:
    """Planes of real proxies marked ``receiver`` that a virtual shadow can reach."""
    receivers = []
    for proxy in site.real:
        if not proxy.receiver:
            continue
        mesh = proxy.part.mesh
        for k, group in enumerate(coplanar_groups(mesh)):
            normal = mesh.face_normals[group[0]]
            if mesh.area_faces[group].sum() < min_area_m2 or normal[1] < -0.5:
                continue
            tris = mesh.vertices[mesh.faces[group]]
            probe = _points_in_triangles(tris, spacing_m=1.0)
            hit = reached(probe, np.tile(normal, (len(probe), 1)), directions, virtual_scene)
            if hit.any():
                receivers.append(
                    plane_receiver(
                        f"wall/{proxy.name}/{k}", "wall", proxy.name, tris, normal, texel_m, 0.0
                    )
                )
    return receivers


def _points_in_triangles(tris: np.ndarray, spacing_m: float) -> np.ndarray:
    """Deterministic points spread over triangles, about one per ``spacing_m^2``."""
    out = []
    for tri in tris:
        area = 0.5 * np.linalg.norm(np.cross(tri[1] - tri[0], tri[2] - tri[0]))
        k = max(2, int(np.ceil(np.sqrt(area) / spacing_m)) + 1)
        i, j = np.meshgrid(np.arange(k), np.arange(k))
        keep = i + j <= k - 1
        a, b = i[keep] / (k - 1), j[keep] / (k - 1)
        out.append(tri[0] + a[:, None] * (tri[1] - tri[0]) + b[:, None] * (tri[2] - tri[0]))
    return np.concatenate(out)


# --------------------------------------------------------------------------------------------
# Packing


def pack(receivers: list[Receiver], max_size: int) -> tuple[int, int]:
    """Shelf-pack receivers' rectangles; sets each ``rect``; returns the atlas (W, H).

    Raises ``ValueError`` when they cannot fit in ``max_size`` squared.
    """
    if not receivers:
        return BLOCK, BLOCK
    area = sum(r.size[0] * r.size[1] for r in receivers)
    widest = max(r.size[0] for r in receivers)
    width = round_up(max(widest, int(np.ceil(np.sqrt(area * 1.15)))), BLOCK)
    while True:
        order = sorted(range(len(receivers)), key=lambda i: (-receivers[i].size[1], i))
        x = y = shelf = 0
        for i in order:
            w, h = receivers[i].size
            if x + w > width:
                x, y, shelf = 0, y + shelf, 0
            receivers[i].rect = (x, y, w, h)
            x += w
            shelf = max(shelf, h)
        height = round_up(y + shelf, BLOCK)
        if height <= max_size and width <= max_size:
            return width, height
        if width >= max_size:
            raise ValueError(f"receivers need more than {max_size}x{max_size} texels")
        width = min(max_size, round_up(int(width * 1.25), BLOCK))


def round_up(value: int, multiple: int) -> int:
    return int(-(-value // multiple) * multiple)


def plane_atlas(atlas_id, receivers, texel_m, stacks, d_reference, max_size) -> Atlas:
    """Pack plane receivers into an atlas and list every texel with its world point."""
    width, height = pack(receivers, max_size)
    texels, points, normals, labels = [], [], [], []
    for index, r in enumerate(receivers):
        local, world = plane_texel_points(r)
        texels.append(local + np.array(r.rect[:2]))
        points.append(world)
        normals.append(np.tile(r.plane["normal"], (len(world), 1)))
        labels.append(np.full(len(world), index))
    atlas = Atlas(atlas_id, "shadowing", stacks, texel_m, receivers, d_reference, width, height)
    if receivers:
        atlas.texels = np.concatenate(texels)
        atlas.points = np.concatenate(points)
        atlas.normals = np.concatenate(normals)
        atlas.labels = np.concatenate(labels)
    return atlas
