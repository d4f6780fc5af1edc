"""The sun apart from the sky (docs/sun.md): find it in a frame, measure or estimate it, and
take its disc out of the sky before the patch means are computed.

Per frame, for the frame's time (``Frame.sky_time_s``, else its capture time):

1. **Where**: NREL SPA for the site (:class:`daylit.sun.SunPath`). Below the horizon the
   source is NONE: zero irradiance and nothing replaced.
2. **A window** of the *full-resolution* frame around the sun's pixel (the camera model's
   projection), linearised as the meter does (8-bit and 16-bit codes through the inverse
   response, float frames as they are) and turned into radiance
   ``L = linear * photometric_factor / exposure / vignetting`` (W/(m^2 sr)). Only this window
   is touched: a few thousand pixels.
3. **Measured** (HDR frames, nothing clipped at the sun): the brightest pixel within
   ``SEARCH_DEG`` of the ephemeris (so a camera whose north is a little off still finds the
   disc), then over an aperture of ``max(APERTURE_DEG, 3 pixels)`` around it the excess over
   the sky, ``E = sum (L - L_bg) omega`` with ``L_bg`` the per-channel median of an annulus
   outside the aperture and ``omega`` each pixel's solid angle; the direction is the
   excess-weighted centroid of those pixels' directions (it refines the ephemeris).
4. **Model** (8-bit frames, or any frame clipped at the sun): the clear-sky DNI (Ineichen, Linke
   turbidity ``[sun] linke_turbidity``) times the sun's colour times the *visible fraction*:
   the fraction of the pixels within ``max(sun radius, 1.5 pixels)`` of the ephemeris that
   are clipped, or, if larger, the fraction of the pixels the disc itself overlaps that are
   clipped (at low resolution a disc much smaller than a pixel clips only the one to four
   pixels it falls on); 0 when a cloud hides the sun (none clipped). The direction is the
   ephemeris.
5. **The sky without the disc**: in the working-resolution linear image the patch matrix
   consumes, the working pixels of the sun's region (the aperture or the small disc, plus the
   connected clipped blob, plus a margin of ``MARGIN_WORKING_PX``) are replaced by the median
   of a ring of working pixels around them. The caller then leaves the replaced pixels out of
   the SATURATED bitmask.

A sun outside the camera's view (a lens narrower than the sky, or pointed elsewhere) cannot be
seen: the clear-sky model with visible fraction 1 (the camera cannot tell clouds there).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from daylit.sky import SUN_ANGULAR_RADIUS_DEG, azimuth_elevation_from_direction
from daylit.sun import DEFAULT_LINKE_TURBIDITY, LUMINANCE_RGB, ClearSun, SunPath, SunSource
from server.fisheye import FisheyeCamera

APERTURE_DEG = 1.5  # the measured disc: the excess within this of its centre (or 3 pixels)
APERTURE_MIN_PX = 3.0
SEARCH_DEG = 3.0  # the disc is looked for this far from the ephemeris (HDR)
BLOB_LIMIT_DEG = 8.0  # a clipped blob around the sun is followed this far at most
VISIBLE_MIN_PX = 1.5  # the visible-fraction disc: at least this radius
MARGIN_WORKING_PX = 2  # replaced working pixels reach this far past the sun's region
RING_WORKING_PX = 3  # ... and take the median of a ring this wide around it


@dataclass
class SunMeasurement:
    """One frame's sun.

    Attributes
    ----------
    direction : (3,) float
        Unit site direction toward the sun (+X east, +Y up, -Z north); zeros when NONE.
    normal_irradiance_w_m2 : (3,) float
        RGB direct normal irradiance, W/m^2 (times the photometric factor when measured).
    source : SunSource
    visible_fraction : float
        Model: the fraction of the small disc around the ephemeris that is clipped (1: clear,
        0: hidden). Measured: 1. None: 0.
    direction_measured : bool
        The direction is the disc's centroid in the frame (else the ephemeris).
    ephemeris : (3,) float
        The SPA direction at the frame's time (zeros below the horizon).
    """

    direction: np.ndarray
    normal_irradiance_w_m2: np.ndarray
    source: SunSource
    visible_fraction: float = 0.0
    direction_measured: bool = False
    ephemeris: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @classmethod
    def none(cls, ephemeris: np.ndarray | None = None) -> SunMeasurement:
        eph = np.zeros(3) if ephemeris is None else ephemeris
        return cls(np.zeros(3), np.zeros(3), SunSource.NONE, 0.0, False, eph)

    @property
    def azimuth_deg(self) -> float:
        return float(azimuth_elevation_from_direction(self._toward())[0])

    @property
    def elevation_deg(self) -> float:
        return float(azimuth_elevation_from_direction(self._toward())[1])

    def _toward(self) -> np.ndarray:
        return self.direction if np.any(self.direction) else self.ephemeris

    def status(self) -> dict:
        """``sun`` of ``/api/status``."""
        up = bool(np.any(self._toward()))
        return {
            "azimuth_deg": round(self.azimuth_deg, 3) if up else None,
            "elevation_deg": round(self.elevation_deg, 3) if up else None,
            "normal_irradiance_W_m2": [round(float(v), 3) for v in self.normal_irradiance_w_m2],
            "source": self.source.label,
            "visible_fraction": round(float(self.visible_fraction), 4),
            "direction_measured": self.direction_measured,
        }


class _Cone:
    """Which unit directions lie within an angle of ``toward``: a cosine comparison (no
    arccos per pixel). ``within(angle_rad)`` -> (m,) bool."""

    def __init__(self, dirs: np.ndarray, toward: np.ndarray):
        self.cos = dirs @ toward

    def within(self, angle_rad: float) -> np.ndarray:
        return self.cos >= math.cos(angle_rad)


class SunMeter:
    """Measures or estimates the sun in frames of one site's sky camera.

    Parameters
    ----------
    latitude_deg, longitude_deg, elevation_m : the site (the manifest's ``scene``).
    linke_turbidity : float
        Of the clear-sky model used where the camera clipped the sun.
    """

    def __init__(self, latitude_deg: float, longitude_deg: float, elevation_m: float,
                 linke_turbidity: float = DEFAULT_LINKE_TURBIDITY):
        self.path = SunPath(latitude_deg, longitude_deg, elevation_m, linke_turbidity)
        self._used: tuple[int, np.ndarray] | None = None
        self._geometry: tuple | None = None

    def clear_sun(self, time_s: float) -> ClearSun:
        return self.path.at(time_s)

    def _used_map(self, m) -> np.ndarray:
        """Working pixels of the crop that some light uses (bool, flat)."""
        if self._used is None or self._used[0] != id(m):
            used = m.whole_light >= 0
            used[m.cut_pixel] = True
            self._used = (id(m), used)
        return self._used[1]

    def measure(
        self,
        image: np.ndarray,
        time_s: float,
        camera: FisheyeCamera,
        m,
        linear: np.ndarray,
        to_linear,
        photometry,
        exposure: float,
        bgr: bool,
        clip_threshold: float,
    ) -> tuple[SunMeasurement, np.ndarray | None]:
        """The sun of one frame, and its region replaced in ``linear`` (in place).

        Parameters
        ----------
        image : (H, W, 3) the full-resolution frame (codes or float linear values).
        camera : the lens at the frame's full resolution.
        m : PatchMatrix; ``linear`` (h, w, 3) float32: its working-resolution linear image.
        to_linear : callable, codes (..., 3) -> linear float32 in [0, 1] (float: unchanged).
        clip_threshold : raw value at or above which a channel counts as clipped (inf: HDR).

        Returns the measurement and the replaced working pixels (bool, ``linear``'s flat
        index), or None when nothing was replaced.
        """
        clear = self.path.at(time_s)
        if clear.apparent_elevation_deg < 0.0:
            return SunMeasurement.none(clear.direction.copy()), None
        s = clear.direction
        px, ok = camera.project(s[None, :])
        u, v = px[0]
        h_img, w_img = image.shape[:2]
        if not ok[0] or not (0 <= u < w_img and 0 <= v < h_img):
            return self._model(clear, 1.0), None
        pix_rad, (x0, y0, x1, y1), grid, dirs, seen = self._window(camera, int(u), int(v),
                                                                    w_img, h_img)
        aperture = max(math.radians(APERTURE_DEG), APERTURE_MIN_PX * pix_rad)
        search = max(math.radians(SEARCH_DEG), 2 * APERTURE_MIN_PX * pix_rad)
        visible_r = max(math.radians(SUN_ANGULAR_RADIUS_DEG), VISIBLE_MIN_PX * pix_rad)
        ring_in, ring_out = aperture + 2 * pix_rad, 2 * aperture + 2 * pix_rad
        raw = image[y0:y1, x0:x1]
        clipped = (raw.reshape(-1, 3).max(axis=1) >= clip_threshold) & seen
        to_sun = _Cone(dirs, s)
        near_sun = to_sun.within(visible_r)
        disc = near_sun & seen
        # The pixels the disc itself overlaps (at low resolution a disc much smaller than a
        # pixel clips the one to four pixels it falls on, not all within 1.5 pixels).
        r_sun_px = math.radians(SUN_ANGULAR_RADIUS_DEG) / pix_rad
        gap = np.maximum(np.abs(grid - [u, v]) - 0.5, 0.0)
        touched = (np.hypot(gap[:, 0], gap[:, 1]) < r_sun_px) & seen
        region = None
        if not np.isfinite(clip_threshold) or not (clipped[disc].any()
                                                   or clipped[touched].any()):
            if raw.dtype == np.uint8:
                # 8-bit: a disc that is not clipped is a hidden (or very dim) sun.
                result = self._model(clear, 0.0)
                region = near_sun | touched
            else:
                result, region = self._measured(raw, grid, dirs, seen, to_sun, search, aperture,
                                                ring_in, ring_out, camera, to_linear,
                                                photometry, exposure, bgr, clear)
        else:
            fraction = max(float(clipped[disc].mean()) if disc.any() else 0.0,
                           float(clipped[touched].mean()) if touched.any() else 0.0)
            result = self._model(clear, fraction)
            region = near_sun | touched
        if clipped.any():
            region = region | _blob_touching(clipped, region, (y1 - y0, x1 - x0),
                                            to_sun.within(math.radians(BLOB_LIMIT_DEG)))
        replaced = self._replace(linear, m, region.reshape(y1 - y0, x1 - x0), x0, y0)
        return result, replaced

    def _window(self, camera: FisheyeCamera, u: int, v: int, width: int, height: int):
        """For the sun on pixel (u, v): a pixel's angular size there (rad), the window
        (x0, y0, x1, y1) around it, its pixel centres (m, 2), site directions (m, 3) and which
        are sky above the horizon. Kept while the sun stays on the same pixel (a minute)."""
        key = (id(camera), u, v, width, height)
        if self._geometry is None or self._geometry[0] != key:
            c = np.array([[u, v]], dtype=float)
            du = camera.unproject(c + [0.5, 0.0])[0] - camera.unproject(c - [0.5, 0.0])[0]
            dv = camera.unproject(c + [0.0, 0.5])[0] - camera.unproject(c - [0.0, 0.5])[0]
            pix_rad = float(math.sqrt(np.linalg.norm(np.cross(du, dv))))
            aperture = max(math.radians(APERTURE_DEG), APERTURE_MIN_PX * pix_rad)
            search = max(math.radians(SEARCH_DEG), 2 * APERTURE_MIN_PX * pix_rad)
            reach = max(search + 2 * aperture + 2 * pix_rad, math.radians(BLOB_LIMIT_DEG))
            half = int(math.ceil(reach / pix_rad)) + 2
            x0, x1 = max(0, u - half), min(width, u + half + 1)
            y0, y1 = max(0, v - half), min(height, v + half + 1)
            gx, gy = np.meshgrid(np.arange(x0, x1, dtype=float), np.arange(y0, y1, dtype=float))
            grid = np.stack([gx.ravel(), gy.ravel()], axis=-1)
            dirs, seen = camera.unproject(grid)
            self._geometry = (key, pix_rad, (x0, y0, x1, y1), grid, dirs,
                              seen & (dirs[:, 1] >= 0.0))
        return self._geometry[1:]

    def _model(self, clear: ClearSun, fraction: float) -> SunMeasurement:
        return SunMeasurement(clear.direction.copy(), clear.dni_rgb_w_m2 * fraction,
                              SunSource.MODEL, fraction, False, clear.direction.copy())

    def _measured(self, raw, grid, dirs, seen, to_sun, search, aperture, ring_in, ring_out,
                  camera, to_linear, photometry, exposure, bgr, clear):
        lin = to_linear(raw).reshape(-1, 3).astype(np.float64)
        if bgr:
            lin = lin[:, ::-1]
        theta = np.arccos(np.clip((dirs @ camera.site_from_camera)[:, 2], -1.0, 1.0))
        gain = photometry.vignetting_gain(theta)
        factor = np.asarray(photometry.photometric_factor, dtype=np.float64)
        radiance = lin * factor / exposure / gain[:, None]
        lum = radiance @ LUMINANCE_RGB
        near = np.flatnonzero(to_sun.within(search) & seen)
        peak = dirs[near[np.argmax(lum[near])]] if near.size else clear.direction
        to_peak = _Cone(dirs, peak)
        inside = to_peak.within(aperture) & seen
        ring = ~to_peak.within(ring_in) & to_peak.within(ring_out) & seen
        if not inside.any() or not ring.any():
            return self._model(clear, 1.0), to_sun.within(aperture)
        background = np.median(radiance[ring], axis=0)
        excess = radiance[inside] - background
        omega = _solid_angles(camera, grid[inside])
        irradiance = np.maximum((excess * omega[:, None]).sum(axis=0), 0.0)
        weight = np.maximum(excess @ LUMINANCE_RGB, 0.0) * omega
        direction, measured = clear.direction.copy(), False
        if weight.sum() > 0.0:
            d = (weight[:, None] * dirs[inside]).sum(axis=0)
            direction, measured = d / np.linalg.norm(d), True
        result = SunMeasurement(direction, irradiance, SunSource.MEASURED, 1.0, measured,
                                clear.direction.copy())
        return result, to_peak.within(aperture)

    def _replace(self, linear: np.ndarray, m, region: np.ndarray, x0: int, y0: int
                 ) -> np.ndarray | None:
        """Replace the working pixels under ``region`` (full-resolution window at x0, y0) by
        the median of a ring around them; returns the replaced pixels (flat bool)."""
        b = m.binning
        cx0, cy0 = m.crop[0], m.crop[1]
        hw, ww = linear.shape[:2]
        ys, xs = np.nonzero(region)
        wy = (ys + y0 - cy0) // b
        wx = (xs + x0 - cx0) // b
        keep = (wy >= 0) & (wy < hw) & (wx >= 0) & (wx < ww)
        if not keep.any():
            return None
        wy, wx = wy[keep], wx[keep]
        pad = MARGIN_WORKING_PX + RING_WORKING_PX + 1
        by0, by1 = max(0, wy.min() - pad), min(hw, wy.max() + pad + 1)
        bx0, bx1 = max(0, wx.min() - pad), min(ww, wx.max() + pad + 1)
        box = np.zeros((by1 - by0, bx1 - bx0), np.uint8)
        box[wy - by0, wx - bx0] = 1

        def grow(mask, r):
            kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
            return cv2.dilate(mask, kernel)

        inner = grow(box, MARGIN_WORKING_PX)
        outer = grow(inner, RING_WORKING_PX)
        used = self._used_map(m).reshape(hw, ww)[by0:by1, bx0:bx1]
        ring = (outer > 0) & (inner == 0) & used
        sub = linear[by0:by1, bx0:bx1]
        sub[inner > 0] = np.median(sub[ring], axis=0) if ring.any() else 0.0
        replaced = np.zeros((hw, ww), dtype=bool)
        replaced[by0:by1, bx0:bx1] = inner > 0
        return replaced.ravel()


def _solid_angles(camera: FisheyeCamera, pixels: np.ndarray) -> np.ndarray:
    """Solid angle (sr) of full-resolution pixels (m, 2), from their neighbours' directions."""
    du = camera.unproject(pixels + [0.5, 0.0])[0] - camera.unproject(pixels - [0.5, 0.0])[0]
    dv = camera.unproject(pixels + [0.0, 0.5])[0] - camera.unproject(pixels - [0.0, 0.5])[0]
    return np.linalg.norm(np.cross(du, dv), axis=-1)


def _blob_touching(clipped: np.ndarray, region: np.ndarray, shape: tuple[int, int],
                   limit: np.ndarray) -> np.ndarray:
    """Clipped pixels (flat, window) connected to ``region``, within ``limit``."""
    mask = (clipped & limit).reshape(shape).astype(np.uint8)
    count, labels = cv2.connectedComponents(mask, connectivity=8)
    if count <= 1:
        return np.zeros(clipped.shape, dtype=bool)
    flat = labels.ravel()
    # Pixels next to the region count too: a blob may start just outside the small disc.
    grown = cv2.dilate(region.reshape(shape).astype(np.uint8), np.ones((3, 3), np.uint8))
    keep = np.zeros(count, dtype=bool)
    keep[flat[grown.ravel() > 0]] = True
    keep[0] = False  # not clipped
    return keep[flat]
