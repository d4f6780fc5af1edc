"""The sky camera's geometry: a fisheye lens and its rotation to the site frame.

Model
-----
Camera axes follow OpenCV: ``x`` right, ``y`` down, ``z`` along the optical axis. A camera ray at
angle ``theta`` from the axis and azimuth ``phi`` lands at the distorted angle

    theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)

and the pixel ``(u, v) = (fx theta_d cos(phi) + cx, fy theta_d sin(phi) + cy)``. This is OpenCV's
fisheye model (``cv2.fisheye``); with ``D = 0`` it is the equidistant projection ``r = f theta``
of the papers' lenses (Sato Sec. 5, Kakuta 2.2.3). OpenCV writes the model with
``theta = atan(r)`` of the normalised point, which stops at 90 degrees; here ``theta`` is taken
with ``atan2`` from the ray itself, the same formula that also covers lenses wider than 180
degrees. ``tests/server/test_fisheye.py`` checks it against ``cv2.fisheye.projectPoints`` and
``cv2.fisheye.undistortPoints`` where those apply.

Site frame (docs/architecture.md, "Frames, units, the index rule"): metres, +X east, +Y up,
-Z north. ``site_from_camera`` (3, 3) turns camera-frame vectors into site-frame vectors. The
default is a camera lying on its back, looking at the zenith, with north at the top of the
image and hence east on the left, as all-sky images are usually shown.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

CALIBRATION_FORMAT = "daylit-fisheye-calibration"

# Columns: camera x (image right) -> west, camera y (image down) -> south, optical axis -> up.
ZENITH_NORTH_UP = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])


class CalibrationError(ValueError):
    """A calibration file that is missing, malformed, or does not fit the frames."""


def yaw_rotation(yaw_deg: float) -> np.ndarray:
    """(3, 3) rotation about the site's up axis (+Y) turning azimuths clockwise by ``yaw_deg``.

    A direction at azimuth ``a`` (clockwise from north, seen from above) goes to ``a + yaw``.
    """
    t = math.radians(yaw_deg)
    c, s = math.cos(t), math.sin(t)
    # Azimuth a: (sin a, ., -cos a); rotating by +t must give (sin(a+t), ., -cos(a+t)).
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])


@dataclass(frozen=True)
class FisheyeCamera:
    """A fisheye sky camera: intrinsics, distortion, image size and orientation.

    Attributes
    ----------
    width, height : int
        Image size in pixels.
    K : (3, 3) float
        Intrinsic matrix ``[[fx, skew, cx], [0, fy, cy], [0, 0, 1]]`` (pixels; the pixel centre
        of the top-left pixel is ``(0, 0)`` as in OpenCV).
    D : (4,) float
        OpenCV fisheye distortion ``k1..k4``; zeros for the ideal equidistant lens.
    site_from_camera : (3, 3) float
        Rotation from camera to site frame.
    max_theta_deg : float
        Largest angle from the optical axis that the lens images (half the field of view).
    """

    width: int
    height: int
    K: np.ndarray
    D: np.ndarray = field(default_factory=lambda: np.zeros(4))
    site_from_camera: np.ndarray = field(default_factory=lambda: ZENITH_NORTH_UP.copy())
    max_theta_deg: float = 90.0

    @classmethod
    def equidistant(
        cls,
        width: int,
        height: int,
        fov_deg: float = 180.0,
        radius_px: float | None = None,
        site_from_camera: np.ndarray | None = None,
    ) -> FisheyeCamera:
        """An ideal equidistant lens centred in the image.

        The image circle of ``fov_deg`` has radius ``radius_px`` (default: it touches the
        shorter side of the image).
        """
        if width < 2 or height < 2:
            raise ValueError(f"image size {width}x{height} is too small")
        if not 10.0 <= fov_deg <= 360.0:
            raise ValueError(f"fov_deg must be between 10 and 360, got {fov_deg}")
        radius = radius_px if radius_px is not None else 0.5 * min(width, height)
        f = radius / math.radians(0.5 * fov_deg)
        K = np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])
        rot = ZENITH_NORTH_UP if site_from_camera is None else site_from_camera
        return cls(width, height, K, np.zeros(4), np.asarray(rot, float), 0.5 * fov_deg)

    def __post_init__(self):
        object.__setattr__(self, "K", np.asarray(self.K, dtype=np.float64).reshape(3, 3))
        object.__setattr__(self, "D", np.asarray(self.D, dtype=np.float64).reshape(4))
        rot = np.asarray(self.site_from_camera, dtype=np.float64).reshape(3, 3)
        if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-6) or np.linalg.det(rot) < 0:
            raise ValueError("site_from_camera must be a proper rotation matrix")
        object.__setattr__(self, "site_from_camera", rot)

    # ----------------------------------------------------------------------------- model

    @property
    def is_equidistant(self) -> bool:
        return not np.any(self.D)

    def distort_theta(self, theta: np.ndarray) -> np.ndarray:
        """Distorted angle ``theta_d`` for ray angles ``theta`` (radians, any shape)."""
        k1, k2, k3, k4 = self.D
        t2 = theta * theta
        return theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))

    def undistort_theta(self, theta_d: np.ndarray, iterations: int = 30) -> np.ndarray:
        """Invert :meth:`distort_theta` by Newton's method (as ``cv2.fisheye.undistortPoints``).

        Where there is no inverse on the lens's rising branch (far outside the image circle,
        where the polynomial turns back) the result is NaN, like OpenCV's flag for such points.
        """
        theta_d = np.asarray(theta_d, dtype=np.float64)
        if self.is_equidistant:
            return theta_d.copy()
        k1, k2, k3, k4 = self.D

        def slope(t):
            t2 = t * t
            return 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))

        theta = theta_d.copy()
        for _ in range(iterations):
            t2 = theta * theta
            f = theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))) - theta_d
            df = slope(theta)
            step = f / np.where(np.abs(df) > 1e-12, df, 1e-12)
            theta = theta - step
            if np.nanmax(np.abs(step), initial=0.0) < 1e-14:
                break
        # Keep only solutions on the monotonic branch that starts at theta = 0.
        grid = np.linspace(0.0, math.pi, 721)
        falling = np.flatnonzero(slope(grid) <= 0)
        limit = grid[falling[0]] if falling.size else math.pi
        bad = (np.abs(self.distort_theta(theta) - theta_d) > 1e-9) | (theta < 0) | (theta > limit)
        return np.where(bad, np.nan, theta)

    def project_camera(self, rays: np.ndarray) -> np.ndarray:
        """Pixels ``(m, 2)`` of camera-frame rays ``(m, 3)`` (need not be unit length)."""
        rays = np.asarray(rays, dtype=np.float64)
        rho = np.hypot(rays[:, 0], rays[:, 1])
        theta = np.arctan2(rho, rays[:, 2])
        theta_d = self.distort_theta(theta)
        scale = np.where(rho > 1e-15, theta_d / np.where(rho > 1e-15, rho, 1.0), 0.0)
        xd, yd = rays[:, 0] * scale, rays[:, 1] * scale
        fx, skew, cx = self.K[0]
        fy, cy = self.K[1, 1], self.K[1, 2]
        # OpenCV's fisheye skew is alpha = skew / fx.
        return np.stack([fx * xd + skew * yd + cx, fy * yd + cy], axis=-1)

    def unproject_camera(self, pixels: np.ndarray) -> np.ndarray:
        """Unit camera-frame rays ``(m, 3)`` through pixels ``(m, 2)``."""
        pixels = np.asarray(pixels, dtype=np.float64)
        fx, skew, cx = self.K[0]
        fy, cy = self.K[1, 1], self.K[1, 2]
        yd = (pixels[:, 1] - cy) / fy
        xd = (pixels[:, 0] - cx - skew * yd) / fx
        theta_d = np.hypot(xd, yd)
        theta = self.undistort_theta(theta_d)
        phi = np.arctan2(yd, xd)
        s = np.sin(theta)
        return np.stack([s * np.cos(phi), s * np.sin(phi), np.cos(theta)], axis=-1)

    def project(self, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels ``(m, 2)`` of site-frame directions ``(m, 3)``, and whether each is imaged.

        A direction is imaged when it is within ``max_theta_deg`` of the optical axis and its
        pixel centre lies on the sensor.
        """
        cam = np.asarray(dirs, dtype=np.float64) @ self.site_from_camera  # R^T d, row-wise
        px = self.project_camera(cam)
        theta = np.arctan2(np.hypot(cam[:, 0], cam[:, 1]), cam[:, 2])
        ok = (
            (theta <= math.radians(self.max_theta_deg))
            & (px[:, 0] >= -0.5) & (px[:, 0] <= self.width - 0.5)
            & (px[:, 1] >= -0.5) & (px[:, 1] <= self.height - 0.5)
        )
        return px, ok

    def unproject(self, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Unit site-frame directions ``(m, 3)`` through pixels ``(m, 2)``, and which are valid.

        Valid means inside the lens's field of view (``theta <= max_theta_deg``).
        """
        cam = self.unproject_camera(pixels)
        theta = np.arccos(np.clip(cam[:, 2], -1.0, 1.0))
        ok = theta <= math.radians(self.max_theta_deg)  # False where NaN (no inverse)
        return cam @ self.site_from_camera.T, ok

    def pixel_grid(self, rows: slice | None = None) -> np.ndarray:
        """Pixel-centre coordinates ``(h * W, 2)`` of image rows ``rows`` (default: all)."""
        rows = rows or slice(0, self.height)
        ys = np.arange(self.height)[rows].astype(np.float64)
        xs = np.arange(self.width, dtype=np.float64)
        gx, gy = np.meshgrid(xs, ys)
        return np.stack([gx.ravel(), gy.ravel()], axis=-1)

    # ------------------------------------------------------------------------ variants

    def scaled_to(self, width: int, height: int) -> FisheyeCamera:
        """The same lens on a sensor resampled to ``width x height`` (e.g. a downscaled frame)."""
        sx, sy = width / self.width, height / self.height
        K = self.K.copy()
        K[0, 0] *= sx
        K[0, 1] *= sx
        K[1, 1] *= sy
        # Pixel centres: u' + 0.5 = (u + 0.5) * s.
        K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
        K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
        return replace(self, width=width, height=height, K=K)

    def with_rotation(self, site_from_camera: np.ndarray) -> FisheyeCamera:
        return replace(self, site_from_camera=np.asarray(site_from_camera, float))

    # ----------------------------------------------------------------------------- files

    def to_json(self) -> dict:
        return {
            "format": CALIBRATION_FORMAT,
            "version": 1,
            "model": "equidistant" if self.is_equidistant else "opencv-fisheye",
            "width": self.width,
            "height": self.height,
            "K": self.K.tolist(),
            "D": self.D.tolist(),
            "site_from_camera": self.site_from_camera.tolist(),
            "max_theta_deg": self.max_theta_deg,
        }

    @classmethod
    def from_json(cls, data: dict, where: str = "calibration") -> FisheyeCamera:
        """Read :meth:`to_json` output (extra keys, such as error reports, are kept out)."""
        if not isinstance(data, dict) or data.get("format") != CALIBRATION_FORMAT:
            raise CalibrationError(f"{where}: not a daylit fisheye calibration (format key)")
        try:
            K = np.asarray(data["K"], dtype=np.float64)
            D = np.asarray(data.get("D", [0, 0, 0, 0]), dtype=np.float64)
            rot = np.asarray(data.get("site_from_camera", ZENITH_NORTH_UP), dtype=np.float64)
            width, height = int(data["width"]), int(data["height"])
            max_theta = float(data.get("max_theta_deg", 90.0))
        except (KeyError, TypeError, ValueError) as exc:
            raise CalibrationError(f"{where}: missing or malformed key: {exc}") from None
        if K.shape != (3, 3) or D.shape != (4,) or rot.shape != (3, 3):
            raise CalibrationError(f"{where}: K must be 3x3, D 4 numbers, site_from_camera 3x3")
        if not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
            raise CalibrationError(f"{where}: K must have positive focal lengths")
        try:
            return cls(width, height, K, D, rot, max_theta)
        except ValueError as exc:
            raise CalibrationError(f"{where}: {exc}") from None


def load_calibration(path: Path | str) -> tuple[FisheyeCamera, dict]:
    """Read a calibration file: the camera and the whole JSON document (for its reports)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text("utf-8"))
    except FileNotFoundError:
        raise CalibrationError(f"{path}: no such calibration file") from None
    except (OSError, json.JSONDecodeError) as exc:
        raise CalibrationError(f"{path}: cannot read: {exc}") from None
    return FisheyeCamera.from_json(data, str(path)), data


def save_json_atomic(path: Path | str, data: dict) -> None:
    """Write JSON to ``path`` via a temporary file and a rename (never a half-written file)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    tmp.write_text(json.dumps(data, indent=2) + "\n", "utf-8")
    os.replace(tmp, path)
