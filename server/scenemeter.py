"""The light vector from the site camera's frames (``--sky scene``): a meter for the pipeline.

:class:`SceneMeter` stands where :class:`server.measure.SkyMeter` stands for a sky camera: the
pipeline hands it the newest frame and gets a :class:`server.measure.Measurement` back. It has
the pixels it samples linearised (the site camera's inverse response, ``[scene]`` radiance per
unit and photometric factor), asks :class:`server.sceneestimate.SceneEstimator` for the sun and
sky of the build's fixed view, and integrates the estimated sky over the build's dome patches
(the same light vector the other sources give). The sun comes with source ``SunSource.SCENE``
(the LIGHT message's sun source byte 3, docs/protocol.md), and the pipeline flags its vectors
SUN_ESTIMATED. Nothing is clipped from the vector's point of view: ``saturated`` is all false
(clipped pixels are left out of the estimate instead).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import trimesh

from daylit.sky import patch_mean_radiance
from daylit.sun import ClearSun, SunPath, SunSource
from server.measure import Frame, FrameError, Measurement
from server.photometry import inverse_response_table
from server.sceneestimate import (
    PinholeView,
    SceneEstimateError,
    SceneEstimator,
    SceneLight,
)
from server.sunmeter import SunMeasurement


@dataclass
class SceneMatrix:
    """What the pipeline logs of its meter's first frame (a sky meter's matrix stands here)."""

    camera: object
    pixels_used: int
    count: int
    build_s: float


@dataclass
class _Size:
    width: int
    height: int


def real_proxies(build_dir: Path, manifest: dict) -> tuple[trimesh.Trimesh, np.ndarray]:
    """The build's real proxies and ground (nodes of role ``real`` and ``ground`` in its
    ``site.glb``) as one mesh in site metres, and their (F, 3) RGB albedos."""
    from bake.gltf import read_site_glb

    nodes = read_site_glb(Path(build_dir) / manifest["model"]["path"])
    meshes, albedo = [], []
    for node in nodes.values():
        if node["extras"].get("role") not in ("real", "ground"):
            continue
        mesh = trimesh.Trimesh(node["vertices"], node["faces"], process=False)
        meshes.append(mesh)
        albedo.append(np.tile(np.asarray(node["albedo"], float)[:3], (len(mesh.faces), 1)))
    if not meshes:
        raise SceneEstimateError("the build has no real proxies or ground to estimate from")
    return trimesh.util.concatenate(meshes), np.vstack(albedo)


class SceneMeter:
    """Measures site-camera frames of one fixed view into light vectors.

    Parameters
    ----------
    estimator : SceneEstimator (its view is the site camera's)
    dome_vertices : (n, 3, 3) the build's dome patches
    sun_path : SunPath for the site
    response : the site camera's inverse response (``srgb``, ``linear``, ``gamma:G``)
    radiance_per_unit : W/(m^2 sr) that a linear value of 1 stands for (the fixed exposure)
    photometric_factor : (3,) per-channel factor applied to linear values
    saturation_level : linear values at or above it count as clipped
    """

    def __init__(self, estimator: SceneEstimator, dome_vertices: np.ndarray, sun_path: SunPath,
                 response: object = "srgb", radiance_per_unit: float = 1.0,
                 photometric_factor=(1.0, 1.0, 1.0), saturation_level: float = 0.98):
        self.estimator = estimator
        self.dome_vertices = np.asarray(dome_vertices, float)
        self.sun_path = sun_path
        self.table = inverse_response_table(response, 256)  # (256, 3) code -> linear
        self.radiance_per_unit = float(radiance_per_unit)
        self.factor = np.asarray(photometric_factor, float)
        self.saturation_level = float(saturation_level)
        self.matrix_count = 1
        self.latest: SceneLight | None = None
        self.estimates = 0
        self._matrix: SceneMatrix | None = None

    # The pipeline's meter interface: frames of any size are scaled to the view's.
    def has_matrix(self, width: int, height: int) -> bool:
        return True

    def prepare(self, width: int, height: int) -> SceneMatrix:
        return self.matrix

    @property
    def matrix(self) -> SceneMatrix:
        if self._matrix is None:
            t0 = time.perf_counter()
            pool = self.estimator.pool_samples
            view = self.estimator.view
            self._matrix = SceneMatrix(_Size(view.width, view.height), len(pool.albedo),
                                       len(self.dome_vertices), time.perf_counter() - t0)
        return self._matrix

    def pixels(self, frame: Frame) -> tuple[np.ndarray, object, float]:
        """The frame at the view's size as RGB (H, W, 3), the function that makes its values
        linear (applied by the estimator to the pixels it samples only: a whole 1280x720
        frame through the table costs more than the estimate), and its clip level."""
        image = frame.image
        if not isinstance(image, np.ndarray) or image.ndim != 3 or image.shape[2] < 3:
            raise FrameError("frame is not an H x W x 3 image")
        image = image[:, :, :3]
        if frame.bgr:
            image = image[:, :, ::-1]
        view = self.estimator.view
        if image.dtype == np.uint8:
            table = self.table * self.factor[None, :]
            channels = np.arange(3)

            def to_linear(codes):
                return table[codes, channels]

            clip = self.saturation_level * float(self.factor.min())
        elif image.dtype.kind == "f":
            factor = self.factor

            def to_linear(values):
                return values * factor

            clip = frame.clip_level * float(factor.min()) if frame.clip_level is not None \
                else np.inf
        else:
            raise FrameError(f"site camera frames of type {image.dtype} are not supported")
        if image.shape[:2] != (view.height, view.width):
            # (8-bit codes are averaged as codes: a small bias where a frame is scaled down)
            image = cv2.resize(np.ascontiguousarray(image), (view.width, view.height),
                               interpolation=cv2.INTER_AREA)
        return image, to_linear, clip

    def estimate(self, frame: Frame) -> tuple[SceneLight, ClearSun]:
        """One frame's sun and sky (kept as ``latest``), and the sun's position at the frame's
        time; :class:`FrameError` for frames that cannot be used."""
        image, to_linear, clip = self.pixels(frame)
        when_s = frame.capture_time_s if frame.sky_time_s is None else frame.sky_time_s
        sun = self.sun_path.at(when_s)
        try:
            light = self.estimator.estimate(image, sun.direction, self.radiance_per_unit,
                                            clip_level=clip if np.isfinite(clip) else None,
                                            to_linear=to_linear)
        except SceneEstimateError as exc:
            raise FrameError(str(exc)) from None
        self.latest = light
        self.estimates += 1
        return light, sun

    def measure(self, frame: Frame) -> Measurement:
        """One frame's light vector; :class:`FrameError` for frames that cannot be used."""
        t0 = time.perf_counter()
        light, sun = self.estimate(frame)
        radiance = patch_mean_radiance(light.sky(), self.dome_vertices, samples_per_side=4,
                                       include_sun=False).astype(np.float32)
        if sun.apparent_elevation_deg > 0.0:
            measured = SunMeasurement(sun.direction.copy(),
                                      np.asarray(light.sun_normal_irradiance, float),
                                      SunSource.SCENE, 1.0, False, sun.direction.copy())
        else:
            measured = SunMeasurement.none()
        return Measurement(radiance, np.zeros(len(radiance), bool), frame.capture_time_s, 0,
                           measured, 1e3 * (time.perf_counter() - t0))

    def status(self) -> dict:
        """``scene_estimate`` of ``/api/status``."""
        light = self.latest
        out = {"estimates": self.estimates}
        if light is not None:
            out.update({
                "sun_normal_irradiance_W_m2": [round(float(v), 3)
                                               for v in light.sun_normal_irradiance],
                "sky_horizontal_irradiance_W_m2": [round(float(v), 3)
                                                   for v in light.sky_horizontal_irradiance],
                "sky_type": light.sky_type,
                "sun_observable": light.sun_observable,
                "sky_separable": light.sky_separable,
                "sky_uncertainty": (round(light.sky_uncertainty, 4)
                                    if math.isfinite(light.sky_uncertainty) else None),
                "shaded_samples": light.shaded,
                "samples_used": light.used,
                "inlier_fraction": round(light.inlier_fraction, 3),
                "surfaces": self.estimator.surface_report(),
            })
        return out


def scene_meter_for_build(build_dir: Path, manifest: dict, view_id: str, sun_path: SunPath,
                          samples: int, **kwargs) -> SceneMeter:
    """A :class:`SceneMeter` for a build's fixed view (``view_id``; empty: the first)."""
    from daylit import manifest as manifest_io

    views = manifest.get("views") or []
    if not views:
        raise SceneEstimateError("the build has no fixed view for the site camera (bake the "
                                 "scene with a [[view]])")
    matches = [v for v in views if v["id"] == view_id] if view_id else views[:1]
    if not matches:
        known = ", ".join(v["id"] for v in views)
        raise SceneEstimateError(f"view {view_id!r} is not a view of the build ({known})")
    mesh, albedo = real_proxies(build_dir, manifest)
    ground = np.asarray(manifest["ground"]["albedo"], float)
    estimator = SceneEstimator(mesh, albedo, PinholeView.from_manifest(matches[0]),
                               environment_albedo=float(ground.mean()), samples=samples)
    return SceneMeter(estimator, manifest_io.dome_vertices(manifest), sun_path, **kwargs)
