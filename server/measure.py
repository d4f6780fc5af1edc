"""Measuring the light vector ``r`` (n x RGB) from a fisheye sky frame (Sato Sec. 5, Kakuta
2.2.3): the sky meter, which turns frames into measurements for one lens, dome and photometry.

Per frame the work is small and fixed: linearise with the inverse response curve (one 16-bit
table look-up per pixel, ``cv2.LUT``; server.photometry), bin in linear values to the working
resolution (2 x 2 area means, once or more: OpenCV's SIMD path; server.binning), both band by
band over the image circle only, and a few sparse products over the binned pixels in memory
order (CSC). Everything that depends only on the lens and the dome is precomputed once in
:class:`server.patchmatrix.PatchMatrix` (which also says how pixels cut by a patch edge are
shared). Smoothing and the decision to send are server.temporalfilter's.

Units: a frame's linear value ``x = exposure * vignetting * L / photometric_factor`` for sky
radiance ``L`` in W/(m^2 sr); the measurement returns ``L`` per patch, i.e. the ``r_i`` of
docs/architecture.md including the photometric factor of Sato Sec. 5.
"""

from __future__ import annotations

import collections
import logging
import math
import threading
import time
from dataclasses import dataclass

import cv2
import numpy as np

from server.binning import DEFAULT_WORKING_PIXELS
from server.fisheye import FisheyeCamera
from server.patchmatrix import PatchMatrix
from server.photometry import Photometry, inverse_response_table
from server.sunmeter import SunMeasurement, SunMeter

log = logging.getLogger("daylit.measure")


@dataclass
class Measurement:
    """One frame's light vector.

    Attributes
    ----------
    radiance : (n, 3) float32
        Mean radiance of each patch, W/(m^2 sr) times the photometric factor; with a sun
        meter, of the sky *without* the sun's disc (its pixels replaced from around it).
    saturated : (n,) bool
        Lights with clipped pixels (outside the sun's replaced region); their value is a
        lower bound.
    capture_time_s : float
        Unix time of the exposure.
    saturated_pixels : int
        Clipped working pixels in the frame, outside the sun's replaced region.
    sun : SunMeasurement or None
        The sun (None without a sun meter).
    sun_ms : float
        Time spent on the sun, milliseconds.
    """

    radiance: np.ndarray
    saturated: np.ndarray
    capture_time_s: float
    saturated_pixels: int = 0
    sun: SunMeasurement | None = None
    sun_ms: float = 0.0


@dataclass
class Frame:
    """A sky image from a source.

    ``image`` is (H, W, 3) uint8 or uint16 camera codes, or float32 linear values; ``bgr`` says
    whether the channels come in OpenCV's order. ``exposure`` (linear value of unit radiance)
    overrides the configured one when the source knows it. ``hdr``: a float frame without a
    white point (EXR, merged brackets): no value counts as clipped, unless ``clip_level`` is
    given: then values at or above it do (a merged bracket: where even its shortest exposure
    clipped, the value is only a lower bound). ``sky_time_s``: the time the sky is at, for the
    sun's position (None: ``capture_time_s``; the simulated sky sets its simulated time).
    """

    image: np.ndarray
    capture_time_s: float
    bgr: bool = True
    exposure: float | None = None
    truth: object = None  # the simulated sky's known answer, for tests; None for real frames
    hdr: bool = False
    sky_time_s: float | None = None
    clip_level: float | None = None


class FrameError(ValueError):
    """A frame that cannot be measured (wrong size, type or shape); it is skipped."""


class SkyMeter:
    """Turns frames into :class:`Measurement` s for one lens, dome and photometry.

    A matrix is built for each frame size met (logged once per size) and kept: up to
    ``MATRIX_SIZES`` sizes, the least recently used dropped beyond. :meth:`has_matrix` tells
    the pipeline whether a frame's size is new, so it can build that size's matrix on a
    worker thread while it goes on measuring frames of the known sizes.
    """

    MATRIX_SIZES = 4

    def __init__(
        self,
        dome_vertices: np.ndarray,
        photometry: Photometry | None = None,
        camera: FisheyeCamera | None = None,
        fov_deg: float = 180.0,
        supersample: int = 6,
        max_working_pixels: int = DEFAULT_WORKING_PIXELS,
        sky_mask: np.ndarray | None = None,
        sun: SunMeter | None = None,
    ):
        self.sun = sun
        self._cameras: dict[tuple[int, int], FisheyeCamera] = {}
        self.dome_vertices = np.asarray(dome_vertices, dtype=np.float64)
        self.photometry = photometry or Photometry()
        self.camera = camera
        self.fov_deg = fov_deg
        self.supersample = supersample
        self.max_working_pixels = max_working_pixels
        self.sky_mask = sky_mask
        self.matrix: PatchMatrix | None = None  # the one used last
        self._matrices: collections.OrderedDict[tuple[int, int], PatchMatrix] = \
            collections.OrderedDict()  # (width, height) px -> matrix, least recent first
        self._matrices_lock = threading.Lock()
        self.matrix_builds = 0
        self._luts: dict[object, np.ndarray] = {}
        self._binned_codes: np.ndarray | None = None
        self._binned_for: PatchMatrix | None = None  # the matrix _binned_codes is for
        self._factor = np.asarray(self.photometry.photometric_factor, dtype=np.float64)

    def camera_for(self, width: int, height: int) -> FisheyeCamera:
        """The calibrated lens, or an ideal equidistant one centred on a frame of this size
        (the same object for the same size)."""
        cached = self._cameras.get((width, height))
        if cached is None:
            cached = self._cameras[(width, height)] = self._camera_for(width, height)
        return cached

    def _camera_for(self, width: int, height: int) -> FisheyeCamera:
        if self.camera is None:
            return FisheyeCamera.equidistant(width, height, self.fov_deg)
        if (self.camera.width, self.camera.height) == (width, height):
            return self.camera
        if abs(width / self.camera.width - height / self.camera.height) < 1e-3:
            return self.camera.scaled_to(width, height)  # same sensor, other resolution
        raise FrameError(
            f"frame is {width}x{height} but the calibration is for "
            f"{self.camera.width}x{self.camera.height}"
        )

    def has_matrix(self, width: int, height: int) -> bool:
        """True if frames of this size (px) are measured without building a matrix first."""
        return (width, height) in self._matrices

    @property
    def matrix_count(self) -> int:
        return len(self._matrices)

    def prepare(self, width: int, height: int) -> PatchMatrix:
        """The matrix for frames of this size (px), built (seconds for large frames) and kept
        the first time. Thread-safe; raises :class:`FrameError` for a size the calibration
        does not fit."""
        key = (width, height)
        with self._matrices_lock:
            m = self._matrices.get(key)
            if m is not None:
                self._matrices.move_to_end(key)
                self.matrix = m
                return m
        camera = self.camera_for(width, height)
        log.info("building the measuring matrix for %dx%d frames (%d other sizes kept)",
                 width, height, len(self._matrices))
        m = PatchMatrix.build(
            camera,
            self.dome_vertices,
            supersample=self.supersample,
            vignetting=self.photometry,
            max_working_pixels=self.max_working_pixels,
            sky_mask=self.sky_mask,
        )
        log.info("measuring matrix for %dx%d frames built in %.1f s (measured at %dx%d, %d "
                 "pixels)", width, height, m.build_s, m.camera.width, m.camera.height,
                 m.pixels_used)
        with self._matrices_lock:
            self.matrix_builds += 1
            self._matrices[key] = m
            while len(self._matrices) > self.MATRIX_SIZES:
                self._matrices.popitem(last=False)
            self.matrix = m
        return m

    def _lut(self, levels: int) -> np.ndarray:
        if levels not in self._luts:
            self._luts[levels] = inverse_response_table(self.photometry.response, levels)
        return self._luts[levels]

    def _lut16(self) -> np.ndarray:
        """8-bit code -> 16-bit linear value for ``cv2.LUT``: (1, 256) when every channel has
        the same curve (a one-channel look-up over the interleaved image), else (1, 256, 3)."""
        if "lut16" not in self._luts:
            table = self._lut(256)
            lut = np.round(table * 65535).astype(np.uint16)
            if np.all(table == table[:, :1]):
                self._luts["lut16"] = lut[:, 0].reshape(1, 256)
            else:
                self._luts["lut16"] = lut.reshape(1, 256, 3)
        return self._luts["lut16"]

    @staticmethod
    def _clipped_pixels(crop: np.ndarray, rows: np.ndarray, threshold: float,
                        b: int) -> np.ndarray:
        """Flat working-size indices of the b x b blocks of ``crop`` with a channel at or above
        ``threshold``; ``rows``: the crop's rows that hold such values (the sun: a few)."""
        h, w = crop.shape[:2]
        wb = w // b
        rows = rows[rows < (h // b) * b]
        if rows.size == 0:
            return np.zeros(0, dtype=np.int64)
        block_rows = np.unique(rows // b)
        picked = (block_rows[:, None] * b + np.arange(b)).ravel()
        band = crop[picked, : wb * b].reshape(block_rows.size, b, wb * b * 3)
        peak = band[:, 0]
        for k in range(1, b):  # the largest value of each block's rows...
            peak = np.maximum(peak, band[:, k])
        peak = peak.reshape(block_rows.size, wb, b * 3).max(axis=2)  # ...and of its columns
        ys, xs = np.nonzero(peak >= threshold)
        return block_rows[ys].astype(np.int64) * wb + xs

    def clip_threshold(self, image: np.ndarray, hdr: bool = False,
                       clip_level: float | None = None) -> float:
        """The raw value at or above which a channel counts as clipped (inf: never). An HDR
        float frame clips only at its own ``clip_level`` (a merged bracket), if it has one."""
        level = self.photometry.saturation_level
        if image.dtype == np.uint8:
            return math.ceil(level * 255)
        if image.dtype == np.uint16:
            return math.ceil(level * 65535)
        if hdr:
            return math.inf if clip_level is None else float(clip_level)
        return level

    def to_linear(self, raw: np.ndarray) -> np.ndarray:
        """Codes (..., 3) -> linear float32 through the inverse response; floats unchanged."""
        if raw.dtype == np.uint8:
            return self._lut(256)[raw, np.arange(3)]
        if raw.dtype == np.uint16:
            return self._lut(65536)[raw, np.arange(3)]
        return raw.astype(np.float32)

    def linearize(self, image: np.ndarray, m: PatchMatrix, hdr: bool = False,
                  clip_level: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The crop's linear image at working size (float32, unit: full scale = ``scale``),
        and the flat working-size indices of pixels with a clipped channel (for ``hdr`` float
        frames none, or those at or above their ``clip_level``).

        8-bit frames go through a 16-bit table (``cv2.LUT``) and are binned in 16 bits: the
        cheapest exact path (a 16-bit linear value resolves even code 1 of an sRGB camera).
        Clipped pixels are found from the maximum of each row (one pass over the codes), then
        only in the few row blocks that hold one.
        """
        if image.ndim != 3 or image.shape[2] != 3:
            raise FrameError(f"expected an H x W x 3 image, got shape {image.shape}")
        x0, y0, x1, y1 = m.crop
        crop = image[y0:y1, x0:x1]
        h, w = crop.shape[:2]
        b = m.binning
        threshold = self.clip_threshold(image, hdr, clip_level)
        if image.dtype == np.uint8:
            linear = self._linearize_codes(crop, m)  # already binned
            b = 1
            scale = 65535.0
        elif image.dtype == np.uint16:
            linear = self._lut(65536)[crop, np.arange(3)]
            scale = 1.0
        elif image.dtype in (np.float32, np.float64):
            linear = crop.astype(np.float32)
            if not np.all(np.isfinite(linear)):
                raise FrameError("frame has non-finite values")
            scale = 1.0
        else:
            raise FrameError(f"unsupported pixel type {image.dtype}")
        if math.isinf(threshold):
            hot_rows = np.zeros(0, dtype=np.int64)
        else:
            hot_rows = np.flatnonzero(crop.reshape(h, w * 3).max(axis=1) >= threshold)
        while linear.shape[0] > h // b:  # 2 x 2 area means (b is a power of two): exact
            linear = cv2.resize(linear, (linear.shape[1] // 2, linear.shape[0] // 2),
                                interpolation=cv2.INTER_AREA)
        if scale != 1.0:
            linear = np.multiply(linear, np.float32(1.0 / scale), dtype=np.float32)
        else:
            linear = linear.astype(np.float32, copy=False)
            if np.shares_memory(linear, image):  # the sun's disc is replaced in place
                linear = linear.copy()
        clipped = self._clipped_pixels(crop, hot_rows, threshold, m.binning)
        return linear, clipped

    def _linearize_codes(self, crop: np.ndarray, m: PatchMatrix) -> np.ndarray:
        """8-bit codes -> 16-bit linear values, binned to working size, band by band
        (``m.strips``); pixels outside the bands are 0 (no light uses them)."""
        lut = self._lut16()
        b = m.binning
        h, w = crop.shape[:2]
        out = self._binned_codes
        if out is None or out.shape != (h // b, w // b, 3) or self._binned_for is not m:
            # Zero outside m's bands: a buffer of another frame size may have other bands.
            out = self._binned_codes = np.zeros((h // b, w // b, 3), np.uint16)
            self._binned_for = m
        rows = crop.reshape(h, w * 3)
        for r0, r1, c0, c1 in m.strips:
            if lut.ndim == 2:  # one curve for all channels: a 1-channel look-up
                band = cv2.LUT(rows[r0:r1, 3 * c0:3 * c1], lut).reshape(r1 - r0, c1 - c0, 3)
            else:
                band = cv2.LUT(np.ascontiguousarray(crop[r0:r1, c0:c1]), lut)
            while band.shape[0] > (r1 - r0) // b:  # 2 x 2 area means: exact
                band = cv2.resize(band, (band.shape[1] // 2, band.shape[0] // 2),
                                  interpolation=cv2.INTER_AREA)
            out[r0 // b:r1 // b, c0 // b:c1 // b] = band
        return out

    def measure(self, frame: Frame) -> Measurement:
        """Measure one frame. Raises :class:`FrameError` for frames that cannot be used."""
        image = frame.image
        if not isinstance(image, np.ndarray) or image.ndim != 3:
            raise FrameError("frame is not an H x W x 3 image")
        exposure = frame.exposure if frame.exposure is not None else self.photometry.exposure
        if not exposure or exposure <= 0 or not math.isfinite(exposure):
            raise FrameError(f"frame exposure {exposure!r} is not a positive number")
        h, w = image.shape[:2]
        m = self.prepare(w, h)
        linear, clipped = self.linearize(image, m, frame.hdr, frame.clip_level)
        sun, sun_ms = None, 0.0
        if self.sun is not None:
            t0 = time.perf_counter()
            sky_time_s = frame.capture_time_s if frame.sky_time_s is None else frame.sky_time_s
            sun, replaced = self.sun.measure(
                image, sky_time_s, self.camera_for(w, h), m, linear, self.to_linear,
                self.photometry, exposure, frame.bgr,
                self.clip_threshold(image, frame.hdr, frame.clip_level))
            if replaced is not None and clipped.size:
                clipped = clipped[~replaced[clipped]]  # the sun's clipped pixels are gone
            sun_ms = 1e3 * (time.perf_counter() - t0)
        radiance = m.apply(linear)
        if frame.bgr:
            radiance = radiance[:, ::-1]
        radiance = np.maximum(radiance, 0.0) * (self._factor / exposure)
        saturated = np.zeros(m.count, dtype=bool)
        if clipped.size:
            saturated[m.lights_at_pixels(clipped)] = True
            # A light that the lens cannot see but copies a clipped one is clipped too.
            saturated |= saturated[m.fill_from]
        return Measurement(
            radiance=radiance.astype(np.float32),
            saturated=saturated,
            capture_time_s=frame.capture_time_s,
            saturated_pixels=int(clipped.size),
            sun=sun,
            sun_ms=sun_ms,
        )
