"""The phone's view for the phone-estimate tests: what pose the client's camera mode takes, as
a pinhole view Radiance can render (tests/radiance_frames.py), and the server's estimator on the
same frame (the numpy reference, server/sceneestimate.py)."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from server.sceneestimate import PinholeView, SceneEstimator

LUMA = np.array([0.2126, 0.7152, 0.0722])


def _copy_size() -> tuple[int, int]:
    """The phone estimate's copy of the picture, pixels (w, h): ESTIMATE_SIZE as the client
    declares it (web/src/phoneestimate.js), so that the tests' shifts are in its pixels."""
    source = (Path(__file__).resolve().parents[2] / "web/src/phoneestimate.js").read_text()
    w, h = re.search(r"export const ESTIMATE_SIZE = \[(\d+), (\d+)\]", source).groups()
    return int(w), int(h)


COPY_SIZE = _copy_size()
# The copy's pixels per pixel of the 192 x 108 copy the tests' tolerances were first set in
# (a tolerance of n px there is n * COPY_SCALE px now: the same angle).
COPY_SCALE = COPY_SIZE[1] / 108

# The poses (tests/server/conftest.py scene_build: an 8 x 5 x 6 m building at the origin, a
# wall to its west), each a standpoint (m) and a device orientation (alpha, beta, gamma;
# deviceorientation degrees, beta 90 is level, alpha 180 faces south):
POSES = {
    # the kiosk's standpoint (a phone held up on a balcony 7 m up), looking south and 17
    # degrees down as the kiosk's view does: the building's shaded north face, its shadow on
    # the ground, sunlit ground around it
    "balcony": ([3.0, 7.0, -24.0], (180.0, 73.0, 0.0)),
    # eye height 9 m north of the building, 15 degrees down: mostly its shaded north face and
    # sunlit ground, the shaded ground seen at grazing angles
    "eye": ([3.0, 1.6, -15.0], (180.0, 75.0, 0.0)),
}


def view_from_three(matrix_world: list[float], fov_y_deg: float, width: int,
                    height: int) -> PinholeView:
    """A PinholeView (OpenCV axes: +X right, +Y down, +Z forward) of a three.js camera: its
    world matrix (16 numbers, column-major) and vertical field of view, at ``width`` x
    ``height`` pixels (square pixels: the page's aspect must be width / height)."""
    m = np.asarray(matrix_world, float).reshape(4, 4).T
    T = m.copy()
    T[:3, :3] = m[:3, :3] @ np.diag([1.0, -1.0, -1.0])  # three looks down -Z, +Y up
    f = (height / 2.0) / math.tan(math.radians(fov_y_deg) / 2.0)
    K = np.array([[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]])
    return PinholeView(K, T, width, height)


def server_estimate(build_dir: Path, view: PinholeView, linear: np.ndarray, sun_dir,
                    frames: int = 3, seed: int = 0) -> float:
    """The server's estimator (server/sceneestimate.py) on one linear frame of ``view``: the
    median over ``frames`` estimates of the luminance sun/sky ratio."""
    from daylit import manifest as manifest_io
    from server.scenemeter import real_proxies

    mesh, albedo = real_proxies(build_dir, manifest_io.load(build_dir))
    est = SceneEstimator(mesh, albedo, view, seed=seed)
    ratios = []
    for _ in range(frames):
        light = est.estimate(linear, sun_dir)
        ratios.append(float(LUMA @ light.sun_normal_irradiance) /
                      max(float(LUMA @ light.sky_horizontal_irradiance), 1e-9))
    return float(np.median(ratios))


# Unobstructed surfaces: open ground and four walls (north, east, south, west)
COMPOSITE_NORMALS = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0],
                              [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]])


def open_irradiance_truth(spec, build_dir: Path, normals=COMPOSITE_NORMALS) -> np.ndarray:
    """(n,) Radiance's irradiance (W/m^2, grey) of unobstructed surfaces of unit ``normals``
    (site frame) under one gendaylit sky and its sun, nothing below the horizon."""
    import tempfile

    from benchmarks.radiance import (
        gendaylit,
        oconv,
        radiance_env,
        rtrace,
        sky_rad,
        sun_rad,
        to_radiance,
    )
    from daylit import manifest as manifest_io
    from tests.radiance_frames import SKY_IRRADIANCE

    _, env = radiance_env()
    sky = gendaylit(spec, manifest_io.load(build_dir), env)
    with tempfile.TemporaryDirectory(prefix="daylit-radiance-") as tmp:
        work = Path(tmp)
        (work / "sky.rad").write_text(sky_rad(sky.skyfunc))
        (work / "sun.rad").write_text(sun_rad(sky.sun_dir_rad, sky.sun_radiance)
                                      if sky.has_sun else "")
        octree = oconv(work / "open.oct", [work / "sky.rad", work / "sun.rad"], env)
        rays = np.hstack([np.zeros((len(normals), 3)) + [0.0, 0.0, 0.001],
                          to_radiance(np.asarray(normals, float))])
        return rtrace(octree, rays, SKY_IRRADIANCE, env).mean(axis=1)


def open_irradiance_estimated(estimate: dict, sun_dir, normals=COMPOSITE_NORMALS) -> np.ndarray:
    """(n,) the irradiance of the same surfaces from the phone's estimate (its sun, and its sky:
    ``modelShare`` of the CIE sky of its type, or of the Perez sky of its ``perez`` state, the
    rest isotropic; server/skyshape.py's tilted_irradiance), in the estimate's own
    (uncalibrated) units."""
    from server.skyshape import tilted_irradiance, unit_sky

    sun = float(LUMA @ np.asarray(estimate["sunNormal"], float))
    k = float(LUMA @ np.asarray(estimate["skyHorizontal"], float))
    perez = estimate.get("perez")
    shape, to_unit = unit_sky(int(estimate["skyType"]), np.asarray(sun_dir, float),
                              None if perez is None else (float(perez[0]), float(perez[1])))
    share = float(estimate["modelShare"])
    sky = share * tilted_irradiance(shape, to_unit, normals) + (1.0 - share) * 0.5 * (
        1.0 + normals[:, 1])
    return sun * np.clip(normals @ np.asarray(sun_dir, float), 0.0, None) + k * sky


def copy_shift_px(true_pose: dict, drawn_pose: dict, aspect: float = 16 / 9) -> np.ndarray:
    """Where the drawn view's pixels lie in the true camera's picture, in pixels of the
    estimate's copy (ESTIMATE_SIZE in web/src/phoneestimate.js, COPY_SIZE; ``aspect`` the
    page's): the median displacement over a grid of the copy, the shift a registration should
    find (a turn moves the picture's edges further than its centre). Both poses are camera
    mode's (``debug.cameraPose()``: matrixWorld, fovDeg) at the same standpoint. Returns
    [dx, dy], pixels."""
    def rotation(pose):
        return np.asarray(pose["matrixWorld"], float).reshape(4, 4).T[:3, :3]

    w, h = COPY_SIZE
    t = np.tan(np.radians(true_pose["fovDeg"]) / 2.0)
    xs, ys = np.meshgrid(np.linspace(0, w, 25), np.linspace(0, h, 15))
    ndc = np.column_stack([xs.ravel() / w * 2 - 1, 1 - ys.ravel() / h * 2])
    drawn = np.column_stack([ndc[:, 0] * t * aspect, ndc[:, 1] * t, -np.ones(len(ndc))])
    v = drawn @ rotation(drawn_pose).T @ rotation(true_pose)  # three looks down -Z
    seen = np.column_stack([v[:, 0] / -v[:, 2] / (t * aspect), v[:, 1] / -v[:, 2] / t])
    moved = np.column_stack([(seen[:, 0] - ndc[:, 0]) * w / 2, -(seen[:, 1] - ndc[:, 1]) * h / 2])
    return np.median(moved, axis=0)
