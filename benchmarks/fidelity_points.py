"""The fidelity benchmark's points: where daylit and Radiance are compared.

- **Points**: a grid over the ground atlas's ground receivers, a grid on the real proxies'
  wall receivers (neither buried inside a part), points on the models' own faces (virtual and
  real; faces of at least 0.5 m^2, in the middle of their triangle, none buried inside another
  part), and for a sky with a sun, lines of closely spaced ground points across the sun's
  shadow edges of the hall, the fence and the visitor centre (found by projecting each
  object's vertices along the sun onto the ground: the far edge of the projected outline).

The metrics over them are in ``fidelity_metrics.py``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from benchmarks.radiance import SURFACE_OFFSET_M
from daylit.sky import SUN_ANGULAR_RADIUS_DEG

# ------------------------------------------------------------------------------------------
# Points


@dataclass
class PointSet:
    """Points in the site frame with their normals, what they are and where, for one sky."""

    points: np.ndarray  # (m, 3)
    normals: np.ndarray  # (m, 3)
    group: list  # "ground", "wall" (real proxies' walls), "model" (models' own faces), "line"
    label: list  # receiver or object name
    lines: dict = field(default_factory=dict)  # name -> dict(index, t, ...)

    def __len__(self) -> int:
        return len(self.points)

    def extend(self, points, normals, group: str, labels) -> np.ndarray:
        start = len(self.points)
        self.points = np.concatenate([self.points, np.asarray(points, float).reshape(-1, 3)])
        self.normals = np.concatenate([self.normals, np.asarray(normals, float).reshape(-1, 3)])
        labels = [labels] * len(points) if isinstance(labels, str) else list(labels)
        self.group += [group] * len(points)
        self.label += labels
        return np.arange(start, len(self.points))


def empty_points() -> PointSet:
    return PointSet(np.zeros((0, 3)), np.zeros((0, 3)), [], [])


def receiver_grid(receiver: dict, step_m: float) -> np.ndarray:
    """Texel centres of a plane receiver every ``step_m`` (at least 1.5 texels off its
    border), site frame."""
    t = receiver["texel_m"]
    w, h = receiver["rect"][2], receiver["rect"][3]
    step = max(1, round(step_m / t))
    xs = np.arange(2, w - 2, step) + 0.5
    ys = np.arange(2, h - 2, step) + 0.5
    X, Y = np.meshgrid(xs, ys)
    o, u, v = (np.array(receiver[k], float) for k in ("origin_m", "axis_u", "axis_v"))
    return o + t * X.reshape(-1, 1) * u + t * Y.reshape(-1, 1) * v


def locatable(build, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Which points ``daylit probe`` can put on a receiver."""
    from bake.evaluate import ProbeError

    ok = np.zeros(len(points), bool)
    for k, (p, n) in enumerate(zip(points, normals, strict=True)):
        try:
            build.locate(p, n)
            ok[k] = True
        except ProbeError:
            pass
    return ok


def site_points(build, nodes: dict, ground_step_m: float, wall_step_m: float,
                model_points: int, seed: int = 15) -> PointSet:
    """The sky-independent points: a grid on the ground receivers, a grid on the real
    proxies' wall receivers, and points on the models' own faces (virtual and real)."""
    ps = empty_points()
    ground = build.atlases["ground"]["receivers"]
    for r in ground:
        step = ground_step_m if r["kind"] == "ground" else wall_step_m
        p = receiver_grid(r, step)
        group = "ground" if r["kind"] == "ground" else "wall"
        ps.extend(p, np.tile(r["normal"], (len(p), 1)), group, r["name"])
    # The models' faces: area-weighted over faces of at least 0.5 m^2 not facing down, each
    # point drawn in the middle 60 % of its triangle (away from edges and texel gutters).
    rng = np.random.default_rng(seed)
    tri, names, areas = [], [], []
    for name, node in nodes.items():
        if node["extras"].get("atlas") != "lightmap":
            continue
        v, f = node["vertices"], node["faces"]
        cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        area = 0.5 * np.linalg.norm(cross, axis=1)
        normal = cross / np.maximum(2 * area, 1e-12)[:, None]
        keep = (area >= 0.5) & (normal[:, 1] > -0.2)
        for k in np.flatnonzero(keep):
            tri.append((v[f[k]], normal[k]))
            names.append(name)
            areas.append(area[k])
    if tri and model_points:
        areas = np.array(areas)
        # Half by area, half evenly per object so small parts get points too.
        objects = sorted(set(names))
        per_object = np.array([1.0 / names.count(names[k]) for k in range(len(names))])
        weight = 0.5 * areas / areas.sum() + 0.5 * per_object / len(objects)
        picks = rng.choice(len(tri), size=3 * model_points, p=weight / weight.sum())
        points, normals, labels = [], [], []
        for k in picks:
            corners, normal = tri[k]
            b = rng.dirichlet([1.0, 1.0, 1.0])
            b = 0.2 / 3 + 0.8 * b  # the middle of the triangle
            points.append(b @ corners)
            normals.append(normal)
            labels.append(names[k])
        points, normals = np.array(points), np.array(normals)
        ok = locatable(build, points, normals) & ~buried(nodes, points, normals)
        ok = np.flatnonzero(ok)[:model_points]
        ps.extend(points[ok], normals[ok], "model", [labels[k] for k in ok])
    ok = locatable(build, ps.points, ps.normals)
    # Grid points buried inside a part (the ground under the podium and the visitor centre):
    # nobody sees them, Radiance gives them nothing, and the bake gives their texels the
    # bounce of the nearest open texel (so that filtering at a wall's foot reads open values).
    flat = np.isin(ps.group, ("ground", "wall"))
    ok[flat] &= ~buried(nodes, ps.points[flat], ps.normals[flat])
    return PointSet(ps.points[ok], ps.normals[ok], [g for g, k in zip(ps.group, ok, strict=True)
                                                    if k],
                    [g for g, k in zip(ps.label, ok, strict=True) if k])


def buried(nodes: dict, points: np.ndarray, normals: np.ndarray, rays: int = 32) -> np.ndarray:
    """Points on faces buried inside another part (a wall's face inside a column): every ray
    over the hemisphere hits the back of a face (half of them: some solids are open).
    Nobody sees them; Radiance gives them
    nothing, the bake's texels bleed light into them: they are left out."""
    from bake.raytrace import Geometry, RayScene

    meshes = [(n["vertices"], n["faces"]) for n in nodes.values()
              if n["extras"].get("role") in ("virtual", "real")]
    offsets = np.cumsum([0] + [len(v) for v, _ in meshes])[:-1]
    v = np.concatenate([m[0] for m in meshes])
    f = np.concatenate([m[1] + o for m, o in zip(meshes, offsets, strict=True)])
    scene = RayScene(Geometry(v, f, np.zeros((len(f), 3)), np.zeros(len(f), bool),
                              np.zeros(len(f), int)))
    # Cosine-distributed Fibonacci directions about +Z, turned onto each normal.
    k = np.arange(rays) + 0.5
    r, phi = np.sqrt(k / rays), k * np.pi * (3.0 - np.sqrt(5.0))
    local = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1.0 - r**2)], -1)
    out = np.zeros(len(points), bool)
    for i, (p, n) in enumerate(zip(points, normals, strict=True)):
        helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        t1 = np.cross(n, helper)
        t1 /= np.linalg.norm(t1)
        t2 = np.cross(n, t1)
        d = local[:, :1] * t1 + local[:, 1:2] * t2 + local[:, 2:] * n
        face, _ = scene.first_hit(np.tile(p + SURFACE_OFFSET_M * n, (rays, 1)), d)
        hit = face >= 0
        back = np.einsum("ij,ij->i", scene.face_normals[face[hit]], d[hit]) > 0.0
        out[i] = back.sum() >= rays // 2
    return out


LINE_OBJECTS = ("hall", "fence", "visitor_centre")


def shadow_lines(build, nodes: dict, sun_dir: np.ndarray, count: int) -> list[dict]:
    """Ground lines across the sun's shadow edge of each of :data:`LINE_OBJECTS`.

    Each object's vertices are projected along the sun onto the ground; the far edge of the
    projected outline (convex hull; both ends from vertices at least 0.5 m up) is the shadow
    edge its top casts. A line crosses it at right angles in the ground plane, from the
    umbra (``t < 0``) to full sun (``t > 0``), half as long as 3 times the disc's geometric
    penumbra there (at least 0.3 m), at a place along the edge where the oracle's visible
    fraction goes from under 2 % to over 98 % and every point is on a ground receiver.
    """
    from scipy.spatial import ConvexHull

    s = sun_dir / np.linalg.norm(sun_dir)
    tan_r = math.tan(math.radians(SUN_ANGULAR_RADIUS_DEG))
    lines = []
    for obj in LINE_OBJECTS:
        verts = [n["vertices"] for n in nodes.values()
                 if n["extras"].get("role") in ("virtual", "real")
                 and n["extras"].get("object", n.get("name")) == obj]
        if not verts:
            verts = [n["vertices"] for name, n in nodes.items() if name.endswith("/" + obj)]
        if not verts:
            continue
        v = np.concatenate(verts)
        ground = v - (v[:, 1] / s[1])[:, None] * s
        flat = ground[:, [0, 2]]
        hull = ConvexHull(flat)
        centre = flat[hull.vertices].mean(axis=0)
        away = np.array([-s[0], -s[2]])
        away /= np.linalg.norm(away)
        best = None
        for a, b in hull.simplices:
            if min(v[a, 1], v[b, 1]) < 0.5:
                continue
            mid = 0.5 * (flat[a] + flat[b])
            edge = flat[b] - flat[a]
            length = np.linalg.norm(edge)
            if length < 1.0:
                continue
            outward = np.array([edge[1], -edge[0]]) / length
            if outward @ (mid - centre) < 0:
                outward = -outward
            score = (mid @ away) * min(length, 4.0)
            if outward @ away > 0.3 and (best is None or score > best[0]):
                best = (score, a, b, outward)
        if best is None:
            continue
        _, a, b, outward = best
        height = 0.5 * (v[a, 1] + v[b, 1])
        distance = height / s[1]  # along the sun's ray, ground to the edge
        # Across the edge in the ground plane: the disc's angular diameter seen along the
        # ray, stretched by the ray's slant onto the ground across this edge.
        stretch = 1.0 / max(0.05, abs(s[1]))
        penumbra = 2.0 * distance * tan_r * stretch
        half = max(0.3, 1.5 * penumbra)
        t = np.linspace(-half, half, count)
        out3 = np.array([outward[0], 0.0, outward[1]])
        for frac in (0.5, 0.35, 0.65, 0.2, 0.8):
            c2 = flat[a] + frac * (flat[b] - flat[a])
            centre3 = np.array([c2[0], 0.0, c2[1]])
            points = centre3 + t[:, None] * out3
            normals = np.tile([0.0, 1.0, 0.0], (count, 1))
            vis = build.sun_casters.visible_fraction(points, normals, s, "all")
            if vis[: count // 20].max() > 0.02 or vis[-(count // 20):].min() < 0.98:
                continue
            if not locatable(build, points[[0, count // 2, -1]], normals[:3]).all():
                continue
            if not locatable(build, points, normals).all():
                continue
            lines.append({"name": obj, "points": points, "t": t, "outward": out3,
                          "edge_height_m": float(height), "distance_m": float(distance),
                          "penumbra_geometric_m": float(penumbra)})
            break
    return lines
