"""Known answers for the spherical-harmonic irradiance (hull-plane mode), computed here and
not by the code under test.

The skies are polynomials of degree <= 2 in the direction (x, y, z), so they lie in the span
of the l <= 2 harmonics and Ramamoorthi & Hanrahan's nine-coefficient irradiance is exact for
them: the cosine-weighted integral over a normal's hemisphere (Gauss-Legendre in the cosine,
uniform in azimuth, exact for these polynomial integrands) is the answer, with no harmonics
in it. The harmonics' constants below are written from the paper (Ramamoorthi & Hanrahan
2001, "An Efficient Representation for Irradiance Environment Maps", Eq. 3 and Eq. 8), not
imported from daylit.

Directions are unit vectors of shape ``(..., 3)`` in the world frame (+Y up); radiance is in
W/(m^2 sr), irradiance in W/m^2.
"""

from __future__ import annotations

import numpy as np

# Y_lm in the paper's order (00, 1-1, 10, 11, 2-2, 2-1, 20, 21, 22), applied to (x, y, z).
_Y00, _Y1, _Y2_OFF, _Y20, _Y22 = 0.282095, 0.488603, 1.092548, 0.315392, 0.546274
# The clamped cosine's coefficients A_l (the paper's Eq. 8): pi, 2 pi / 3, pi / 4.
A_L = {0: np.pi, 1: 2.0 * np.pi / 3.0, 2: np.pi / 4.0}
BAND_OF = np.array([0, 1, 1, 1, 2, 2, 2, 2, 2])


def harmonics(w: np.ndarray) -> np.ndarray:
    """The nine real harmonics at unit directions ``w`` (..., 3): (..., 9)."""
    x, y, z = w[..., 0], w[..., 1], w[..., 2]
    return np.stack([_Y00 * np.ones_like(x), _Y1 * y, _Y1 * z, _Y1 * x, _Y2_OFF * x * y,
                     _Y2_OFF * y * z, _Y20 * (3 * z * z - 1), _Y2_OFF * x * z,
                     _Y22 * (x * x - y * y)], axis=-1)


def _gauss_cap(axis: np.ndarray, mu_low: float, nodes: int = 8, azimuths: int = 16):
    """Directions and weights (sr) of a quadrature over the cap mu = w . axis >= mu_low,
    exact for polynomials in w of degree < min(2 nodes, azimuths): ((Q, 3), (Q,))."""
    axis = axis / np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    t, wt = np.polynomial.legendre.leggauss(nodes)
    mu = mu_low + (1.0 - mu_low) * (t + 1.0) / 2.0
    wmu = wt * (1.0 - mu_low) / 2.0
    phi = (np.arange(azimuths) + 0.5) * 2.0 * np.pi / azimuths
    s = np.sqrt(1.0 - mu**2)
    dirs = (mu[:, None, None] * axis + (s[:, None] * np.cos(phi))[..., None] * u
            + (s[:, None] * np.sin(phi))[..., None] * v)
    weights = wmu[:, None] * np.full(azimuths, 2.0 * np.pi / azimuths)
    return dirs.reshape(-1, 3), weights.reshape(-1)


def sphere_quadrature():
    """Directions (Q, 3) and weights (Q,) sr over the whole sphere (exact to degree 15)."""
    return _gauss_cap(np.array([0.0, 1.0, 0.0]), -1.0)


def toward(d):
    """A sky bright only toward unit direction d, zero opposite: ((1 + w.d) / 2)^2."""
    d = np.asarray(d, dtype=float) / np.linalg.norm(d)
    return lambda w: ((1.0 + w @ d) / 2.0) ** 2


def band(axis):
    """A sky bright on the great circle around ``axis``, dark at its poles: 1 - (w.axis)^2."""
    a = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    return lambda w: 1.0 - (w @ a) ** 2


def random_quadratic(rng):
    """A positive sky w^T A w + b.w + c with every one of the nine terms present."""
    A = rng.normal(size=(3, 3))
    A = A + A.T
    b = rng.normal(size=3)
    c = np.abs(np.linalg.eigvalsh(A)).max() + np.abs(b).sum() + 0.1
    return lambda w: np.einsum("...i,ij,...j->...", w, A, w) + w @ b + c


def sky_sh9(sky) -> np.ndarray:
    """The sky's L_lm = integral of L(w) Y_lm(w) dw over the sphere: (9,)."""
    dirs, weight = sphere_quadrature()
    return (sky(dirs) * weight) @ harmonics(dirs)


def irradiance(sky, normals: np.ndarray) -> np.ndarray:
    """integral of L(w) max(n.w, 0) dw for each unit normal (N, 3): (N,). No harmonics."""
    out = []
    for n in np.asarray(normals, dtype=float):
        dirs, weight = _gauss_cap(n, 0.0)
        out.append(np.sum(sky(dirs) * (dirs @ n) * weight))
    return np.array(out)


def irradiance_from_sh9(L: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """The paper's E(n) = sum_lm A_l L_lm Y_lm(n): (N,) for L (9,)."""
    a = np.array([A_L[b] for b in BAND_OF])
    return harmonics(np.asarray(normals, dtype=float)) @ (a * L)


def normals_that_differ() -> np.ndarray:
    """Each axis both ways and oblique directions (none along an axis): (N, 3) unit."""
    axes = np.concatenate([np.eye(3), -np.eye(3)])
    oblique = np.array([[1, 1, 0], [1, 0, 1], [0, 1, 1], [1, -2, 3], [-3, 1, 2], [2, 3, -1],
                        [-1, -1, -1], [3, -1, -2]], dtype=float)
    return np.concatenate([axes, oblique / np.linalg.norm(oblique, axis=1, keepdims=True)])


def skies_that_differ(rng) -> dict:
    """Skies that tell the nine terms apart, by name."""
    return {
        "toward +x": toward([1, 0, 0]), "toward +z": toward([0, 0, 1]),
        "toward -y": toward([0, -1, 0]), "band around y": band([0, 1, 0]),
        "band around x": band([1, 0, 0]), "toward x+z": toward([1, 0, 1]),
        "random 1": random_quadratic(rng), "random 2": random_quadratic(rng),
        "random 3": random_quadratic(rng),
    }
