"""The sun's direct term at receiver points: the oracle of the client's sun (docs/sun.md).

The client draws the sun as a directional light whose shadow maps are cast by the virtual
models and the real proxies. This module computes the same term by ray casting the same
geometry, the meshes of a build's ``site.glb`` whose role is ``virtual`` or ``real`` (never the
ground or the shadowing planes):

    E_sun(x) = E_sun_normal * max(0, n . s) * V(x)

``V(x)`` in [0, 1] is the fraction of the sun's disc (angular radius
:data:`daylit.sky.SUN_ANGULAR_RADIUS_DEG`, uniform radiance, no limb darkening) seen from
``x``: rays from ``x`` (offset 2 mm along its normal) toward :data:`DISC_SAMPLES` fixed
directions spread evenly over the disc, cast with Embree. The part of the disc below the
horizon counts as hidden (the open ground around the site, as the bake assumes, reaches the
horizon); the ground mesh itself is not a caster.

Disc samples: a Vogel (golden-angle) spiral with equal solid angle per sample, chosen over a
jittered or square grid because it is deterministic and its samples project evenly onto every
direction across the disc: as a straight shadow edge sweeps over the disc, the visible fraction
rises in steps of ``1/N`` without clumps. With ``N = 256`` it stays within 2 % (median over
edge orientations 1.4 %) of the exact circular-segment curve, which puts the 50 % point within
3 % of the disc's projected radius (about 1.5 mm at 10 m behind a wall); a 16 x 16 concentric
grid does worse (3 %), 1024 samples better (0.7 %) at four times the rays.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bake.raytrace import RAY_OFFSET_M, Geometry, RayScene
from daylit.sky import SUN_ANGULAR_RADIUS_DEG

DISC_SAMPLES = 256
CASTER_ROLES = ("virtual", "real")
CASTER_SETS = ("all", "virtual", "real", "none")
_RAYS_PER_BATCH = 1 << 20  # keeps a batch's arrays near 50 MB


def disc_directions(sun_direction, samples: int = DISC_SAMPLES) -> np.ndarray:
    """Unit directions (samples, 3) spread evenly over the sun's disc around ``sun_direction``.

    Sample ``k`` sits at polar angle ``theta_k`` from the centre with
    ``1 - cos(theta_k) = (k + 1/2) / samples * (1 - cos(theta_max))`` (equal solid angle per
    sample) and at azimuth ``k`` times the golden angle about the centre: deterministic.
    """
    s = np.asarray(sun_direction, dtype=np.float64)
    s = s / np.linalg.norm(s)
    helper = np.array([0.0, 1.0, 0.0]) if abs(s[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    t1 = np.cross(s, helper)
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(s, t1)
    k = np.arange(samples) + 0.5
    one_minus_cos_max = 1.0 - np.cos(np.radians(SUN_ANGULAR_RADIUS_DEG))
    cos_theta = 1.0 - k / samples * one_minus_cos_max
    sin_theta = np.sqrt(np.maximum(0.0, 1.0 - cos_theta**2))
    phi = (np.arange(samples) * np.pi * (3.0 - np.sqrt(5.0))) % (2.0 * np.pi)
    return (
        cos_theta[:, None] * s
        + (sin_theta * np.cos(phi))[:, None] * t1
        + (sin_theta * np.sin(phi))[:, None] * t2
    )


class SunCasters:
    """The sun's shadow casters of a build, ready for ray casting.

    Parameters
    ----------
    meshes : list of (role, vertices (V, 3) float metres, faces (F, 3) int)
        ``role`` is ``"virtual"`` or ``"real"``; site frame (+X east, +Y up, -Z north).
    """

    def __init__(self, meshes):
        by_role = {role: [] for role in CASTER_ROLES}
        for role, vertices, faces in meshes:
            if role not in by_role:
                raise ValueError(f"a caster's role must be one of {CASTER_ROLES}, got {role!r}")
            by_role[role].append((np.asarray(vertices, np.float64), np.asarray(faces, np.int64)))
        self.face_counts = {role: sum(len(f) for _, f in by_role[role]) for role in CASTER_ROLES}
        self._scenes = {
            "all": RayScene(_geometry(by_role["virtual"] + by_role["real"])),
            "virtual": RayScene(_geometry(by_role["virtual"])),
            "real": RayScene(_geometry(by_role["real"])),
            "none": RayScene(_geometry([])),
        }

    @classmethod
    def from_site_glb(cls, path: Path | str) -> SunCasters:
        """The ``virtual`` and ``real`` nodes of a ``site.glb`` written by the baker."""
        from bake.gltf import read_site_glb

        nodes = read_site_glb(Path(path))
        return cls(
            [
                (node["extras"]["role"], node["vertices"], node["faces"])
                for node in nodes.values()
                if node["extras"].get("role") in CASTER_ROLES
            ]
        )

    def visible_fraction(
        self, points, normals, sun_direction, casters: str = "all", samples: int = DISC_SAMPLES
    ) -> np.ndarray:
        """Fraction of the sun's disc seen from each point, shape ``(m,)`` in [0, 1].

        Parameters
        ----------
        points : (m, 3) float, metres, on receiver surfaces (site frame)
        normals : (m, 3) float, the surfaces' normals (need not be unit)
        sun_direction : (3,) float, toward the sun's centre (need not be unit)
        casters : ``"all"`` (virtual models and real proxies), ``"virtual"``, ``"real"`` or
            ``"none"`` (only the horizon hides the sun)
        samples : rays per point over the disc

        0 where ``n . s <= 0`` (the surface faces away from the sun's centre).
        """
        if casters not in self._scenes:
            raise ValueError(f"casters must be one of {CASTER_SETS}, got {casters!r}")
        points, normals = _points_normals(points, normals)
        s = np.asarray(sun_direction, dtype=np.float64)
        s = s / np.linalg.norm(s)
        directions = disc_directions(s, samples)  # (k, 3)
        above_horizon = directions[:, 1] > 0.0
        out = np.zeros(len(points))
        facing = np.flatnonzero(normals @ s > 0.0)
        if not above_horizon.any() or len(facing) == 0:
            return out
        directions = directions[above_horizon]
        scene = self._scenes[casters]
        origins = points + RAY_OFFSET_M * normals
        per_batch = max(1, _RAYS_PER_BATCH // len(directions))
        for start in range(0, len(facing), per_batch):
            index = facing[start : start + per_batch]
            o = np.repeat(origins[index], len(directions), axis=0)
            d = np.tile(directions, (len(index), 1))
            blocked = scene.occluded(o, d).reshape(len(index), len(directions))
            out[index] = (~blocked).sum(axis=1) / samples
        return out

    def irradiance(
        self,
        points,
        normals,
        sun_direction,
        normal_irradiance_rgb,
        without: str = "real",
        samples: int = DISC_SAMPLES,
    ) -> dict:
        """The sun's direct irradiance with and without the virtual objects.

        Parameters
        ----------
        points, normals : (m, 3) float (see :meth:`visible_fraction`)
        sun_direction : (3,) float, toward the sun
        normal_irradiance_rgb : (3,) float or a number, the sun's direct normal irradiance,
            W/m^2 (the disc's radiance times its solid angle)
        without : the casters of the "without" term: ``"real"`` (the real proxies, as the
            shadowing planes' ``d``) or ``"none"``

        Returns
        -------
        dict with ``"with"``, ``"without"``: (m, 3) W/m^2, ``E_n * max(0, n . s) * V`` with
        ``V`` for all casters and for ``without``; ``"visible_with"``, ``"visible_without"``:
        (m,) the ``V``; ``"cos"``: (m,) ``max(0, n . s)`` with unit ``n`` and ``s``.
        """
        points, normals = _points_normals(points, normals)
        s = np.asarray(sun_direction, dtype=np.float64)
        s = s / np.linalg.norm(s)
        e_n = np.broadcast_to(np.asarray(normal_irradiance_rgb, dtype=np.float64), (3,))
        unit = normals / np.linalg.norm(normals, axis=1, keepdims=True)
        cos = np.maximum(0.0, unit @ s)
        v_with = self.visible_fraction(points, normals, s, "all", samples)
        v_without = self.visible_fraction(points, normals, s, without, samples)
        return {
            "with": (cos * v_with)[:, None] * e_n,
            "without": (cos * v_without)[:, None] * e_n,
            "visible_with": v_with,
            "visible_without": v_without,
            "cos": cos,
        }


def _points_normals(points, normals) -> tuple[np.ndarray, np.ndarray]:
    points = np.atleast_2d(np.asarray(points, dtype=np.float64))
    normals = np.atleast_2d(np.asarray(normals, dtype=np.float64))
    normals = np.broadcast_to(normals, points.shape)
    if points.shape[1:] != (3,):
        raise ValueError(f"points must have shape (m, 3), got {points.shape}")
    if not (np.all(np.isfinite(points)) and np.all(np.isfinite(normals))):
        raise ValueError("points and normals must be finite")
    if np.any(np.linalg.norm(normals, axis=1) == 0.0):
        raise ValueError("a normal is zero; give each point its surface's normal")
    return points, normals / np.linalg.norm(normals, axis=1, keepdims=True)


def _geometry(meshes) -> Geometry:
    """A :class:`bake.raytrace.Geometry` of plain (vertices, faces) meshes: only the
    triangles matter here (albedo and flags unused)."""
    vertices, faces = [], []
    offset = 0
    for v, f in meshes:
        vertices.append(v)
        faces.append(f + offset)
        offset += len(v)
    if not faces:
        v, f = np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    else:
        v, f = np.concatenate(vertices), np.concatenate(faces)
    return Geometry(v, f, np.zeros((len(f), 3)), np.zeros(len(f), bool), np.zeros(len(f), int))
