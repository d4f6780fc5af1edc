"""The light dome: the sky's upper hemisphere tiled by geodesic triangles (Sato 2.1, Kakuta 2.2.1).

Light ``i`` is triangle ``i`` of the dome everywhere in daylit (the one index rule). Two
geodesic families tile the hemisphere *exactly*, with the horizon made of triangle edges:

- **icosahedral**, even frequency ``f`` with a five-fold axis at the zenith: ``10 f^2`` lights
  (40, 160, 360, 640, 1000, ...). Frequency 2 is Kakuta's 40-light dome. The equator is a grid
  line of the subdivision only for even ``f`` (it passes through the midpoints of the
  icosahedron's zig-zag edges), which is why odd frequencies are not offered.
- **octahedral**, any frequency ``f``: ``4 f^2`` lights (36, 64, ..., 144, 196, ..., 400, ...).
  The octahedron's equatorial edges are the horizon. Its grid points are placed with an
  equal-area octahedral map (Clarberg 2008) rather than by central projection, which brings the
  ratio of largest to smallest patch from 4.2 to 1.83 at 400 lights (icosahedral: 1.5-1.8).
  It is used only when it matches the requested count better than the icosahedral family.

``Dome.for_light_count(n)`` picks the family and frequency whose count is closest to ``n``
(icosahedral on ties), so ``--lights 160`` and ``--lights 400`` both give exactly that many.

Every vertex is projected onto the unit sphere and every edge is a great-circle arc, so the
patches' solid angles sum to ``2 pi`` to rounding error.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from daylit.spherical import (
    centroid_direction,
    clipped_cosine_integral,
    normalize,
    patch_sh9,
    solid_angle,
)

MIN_LIGHTS = 4
MAX_LIGHTS = 20000


@dataclass(frozen=True)
class Dome:
    """A geodesic hemisphere.

    Attributes
    ----------
    kind : str
        ``"icosahedral"`` or ``"octahedral"``.
    frequency : int
        Subdivisions of each edge of the base polyhedron.
    vertices : (n, 3, 3) float64
        Unit vertices of each light's triangle, counter-clockwise seen from outside.
    """

    kind: str
    frequency: int
    vertices: np.ndarray

    @property
    def count(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def centroids(self) -> np.ndarray:
        """(n, 3) unit directions through each triangle's centroid."""
        return centroid_direction(self.vertices)

    @property
    def solid_angles_sr(self) -> np.ndarray:
        """(n,) solid angle of each light in sr; sums to 2 pi."""
        return solid_angle(self.vertices)

    @property
    def cosine_weighted_sr(self) -> np.ndarray:
        """(n,) irradiance an open upward surface gets from each light at unit radiance,
        ``integral of cos(zenith) over the patch``; sums to pi."""
        return clipped_cosine_integral(self.vertices, np.array([[0.0, 1.0, 0.0]]))[0]

    @classmethod
    def build(cls, kind: str, frequency: int) -> Dome:
        if kind == "icosahedral":
            if frequency < 2 or frequency % 2:
                raise ValueError("an icosahedral dome needs an even frequency >= 2")
            tris = _subdivide(*_icosahedron(), frequency)
        elif kind == "octahedral":
            if frequency < 1:
                raise ValueError("an octahedral dome needs a frequency >= 1")
            tris = _subdivide(*_octahedron(), frequency, place=_octahedral_equal_area)
        else:
            raise ValueError(f"unknown dome kind {kind!r}")
        return cls(kind, frequency, _upper_hemisphere(tris))

    @classmethod
    def for_light_count(cls, lights: int) -> Dome:
        """The geodesic dome whose light count is closest to ``lights``."""
        if not MIN_LIGHTS <= lights <= MAX_LIGHTS:
            raise ValueError(f"light count must be between {MIN_LIGHTS} and {MAX_LIGHTS}")
        options = []
        f = 2
        while 10 * f * f <= 2 * MAX_LIGHTS:
            options.append((abs(10 * f * f - lights), 0, "icosahedral", f))
            f += 2
        f = 1
        while 4 * f * f <= 2 * MAX_LIGHTS:
            options.append((abs(4 * f * f - lights), 1, "octahedral", f))
            f += 1
        _, _, kind, frequency = min(options)
        return cls.build(kind, frequency)

    def to_manifest(self) -> dict:
        """The dome as the manifest lists it: every light with index, vertices, centroid, sr.

        ``cosine_weighted_sr`` is the irradiance an open upward surface gets from the light at
        unit radiance; ``sh9`` its spherical-harmonic projection (for shading by normal).
        """
        omega = self.solid_angles_sr
        centroids = self.centroids
        up = self.cosine_weighted_sr
        sh9 = patch_sh9(self.vertices)
        return {
            "kind": self.kind,
            "frequency": self.frequency,
            "count": self.count,
            "lights": [
                {
                    "index": i,
                    "vertices": [[round(float(x), 12) for x in v] for v in self.vertices[i]],
                    "centroid": [round(float(x), 12) for x in centroids[i]],
                    "solid_angle_sr": float(omega[i]),
                    "cosine_weighted_sr": float(up[i]),
                    "sh9": [round(float(x), 10) for x in sh9[i]],
                }
                for i in range(self.count)
            ],
        }


def _icosahedron() -> tuple[np.ndarray, np.ndarray]:
    """Unit icosahedron with a vertex at +Y (zenith): vertices (12, 3), faces (20, 3)."""
    ring_y = 1.0 / np.sqrt(5.0)
    ring_r = 2.0 / np.sqrt(5.0)
    verts = [[0.0, 1.0, 0.0]]
    for k in range(5):  # upper ring
        a = 2.0 * np.pi * k / 5.0
        verts.append([ring_r * np.sin(a), ring_y, -ring_r * np.cos(a)])
    for k in range(5):  # lower ring, rotated by half a step
        a = 2.0 * np.pi * (k + 0.5) / 5.0
        verts.append([ring_r * np.sin(a), -ring_y, -ring_r * np.cos(a)])
    verts.append([0.0, -1.0, 0.0])
    faces = []
    for k in range(5):
        u0, u1 = 1 + k, 1 + (k + 1) % 5
        l0, l1 = 6 + k, 6 + (k + 1) % 5
        faces += [[0, u0, u1], [u0, l0, u1], [u1, l0, l1], [11, l1, l0]]
    return np.array(verts), np.array(faces)


def _octahedron() -> tuple[np.ndarray, np.ndarray]:
    """Unit octahedron with a vertex at +Y: vertices (6, 3), faces (8, 3)."""
    verts = np.array(
        [[0, 1, 0], [1, 0, 0], [0, 0, 1], [-1, 0, 0], [0, 0, -1], [0, -1, 0]], dtype=float
    )
    faces = []
    for k in range(4):
        a, b = 1 + k, 1 + (k + 1) % 4
        faces += [[0, a, b], [5, b, a]]
    return verts, np.array(faces)


def _octahedral_equal_area(p: np.ndarray) -> np.ndarray:
    """Map points of the unit octahedron ``|x|+|y|+|z| = 1`` to the sphere, preserving area.

    ``r = |x| + |z|`` is the distance from the pole in the octahedron's L1 sense; the image lies
    at height ``1 - r^2`` with its azimuth spread evenly across each quadrant, so equal areas
    on a face map to equal solid angles and the face's equator edge maps to the equator.
    """
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    r = np.abs(x) + np.abs(z)
    safe_r = np.where(r > 0.0, r, 1.0)
    phi = np.where(r > 0.0, 0.25 * np.pi * ((np.abs(z) - np.abs(x)) / safe_r + 1.0), 0.0)
    height = 1.0 - r * r
    radius = r * np.sqrt(np.maximum(2.0 - r * r, 0.0))
    return np.stack(
        [
            np.sign(x) * radius * np.cos(phi),
            np.where(y >= 0.0, height, -height),
            np.sign(z) * radius * np.sin(phi),
        ],
        axis=-1,
    )


def _subdivide(verts: np.ndarray, faces: np.ndarray, frequency: int, place=normalize) -> np.ndarray:
    """Split each face into ``frequency^2`` triangles on a barycentric grid, then project.

    ``place`` maps the flat grid points onto the unit sphere (central projection by default).

    Returns triangles (20 f^2 or 8 f^2, 3, 3) of unit vertices, each counter-clockwise seen
    from outside.
    """
    f = frequency
    out = []
    for face in faces:
        a, b, c = verts[face]

        def grid(i: int, j: int, a=a, b=b, c=c) -> np.ndarray:
            # Point i steps from a toward b and j steps toward c.
            return a + (b - a) * (i / f) + (c - a) * (j / f)

        for i in range(f):
            for j in range(f - i):
                out.append([grid(i, j), grid(i + 1, j), grid(i, j + 1)])
                if i + j < f - 1:
                    out.append([grid(i + 1, j), grid(i + 1, j + 1), grid(i, j + 1)])
    tris = normalize(place(np.array(out)))
    # Orient every triangle counter-clockwise seen from outside: det(a, b, c) > 0.
    det = np.einsum("ij,ij->i", tris[:, 0], np.cross(tris[:, 1], tris[:, 2]))
    flip = det < 0
    tris[flip] = tris[flip][:, [0, 2, 1]]
    return tris


def _upper_hemisphere(tris: np.ndarray) -> np.ndarray:
    """Triangles above the horizon, ordered from the zenith down, then clockwise from north.

    Vertices on the horizon are snapped to ``y = 0`` exactly (they are there up to rounding),
    so the horizon is a chain of great-circle arcs along the equator.
    """
    tris = tris.copy()
    tris[..., 1][np.abs(tris[..., 1]) < 1e-12] = 0.0
    tris = normalize(tris)
    centroid = centroid_direction(tris)
    upper = tris[centroid[:, 1] > 0.0]
    c = centroid_direction(upper)
    zenith_deg = np.degrees(np.arccos(np.clip(c[:, 1], -1, 1)))
    azimuth_deg = np.degrees(np.arctan2(c[:, 0], -c[:, 2])) % 360.0  # clockwise from north
    order = np.lexsort((np.round(azimuth_deg, 6), np.round(zenith_deg, 6)))
    return upper[order]
