"""From frames to streamed vectors: measure the newest frame, smooth, decide, publish.

A source hands frames to :meth:`LightPipeline.deliver`, which keeps only the newest; the
measuring task measures it off the event loop, folds it into the temporal filter and publishes
when the change threshold says so. A watchdog marks the light stale when frames stop coming,
keeps re-sending the last good vector with the STALE flag (so clients know), and the stale flag
clears with the next good frame. A source that has not delivered a frame within
``stale_after_s`` of the start is stale too, with the source's last error in the status. Frames
that cannot be measured are skipped with a log line.

A frame of a size the meter has no matrix for yet (a replay folder of mixed sizes, a camera
switching resolution) is skipped while that size's matrix is built on a worker thread (seconds
for large frames); frames of the sizes already known are measured meanwhile, and the new
size's frames from when the matrix is ready. The very first frame's matrix is built in line.

With a sun meter, each vector is published with the sun (docs/sun.md): version-2 clients get
the sky without the disc and the sun apart (direction, smoothed normal irradiance, source;
SUN_ESTIMATED when it is the clear-sky model's or the scene's estimate; with a
:class:`server.fusion.SceneFusion`, the scene's sun replaces the model's where the sky camera
clipped it), version-1 clients the
sky with the sun's irradiance folded back into the patch that holds its direction
(``r_p += E / omega_p``).
"""

from __future__ import annotations

import asyncio
import collections
import logging
import time
from dataclasses import dataclass

import cv2
import numpy as np

from daylit.spherical import PatchLookup, solid_angle
from daylit.sun import SunSource
from server.lightstream import LightHub
from server.measure import Frame, FrameError, Measurement, SkyMeter
from server.newest import Newest
from server.protocol import Flags, fold_sun
from server.sources.base import Source
from server.sunmeter import SunMeasurement
from server.temporalfilter import TemporalFilter

log = logging.getLogger("daylit.pipeline")


@dataclass
class PublishedSun:
    """The sun as published: the newest direction and source, the smoothed irradiance."""

    direction: np.ndarray  # (3,) unit, site frame; zeros when none
    normal_irradiance_w_m2: np.ndarray  # (3,) RGB, W/m^2, smoothed
    source: SunSource


class LightPipeline:
    """Measuring and publishing for one sky source."""

    def __init__(
        self,
        meter: SkyMeter,
        temporal: TemporalFilter,
        hub: LightHub,
        source: Source,
        stale_after_s: float = 5.0,
        solid_angles_sr: np.ndarray | None = None,
    ):
        """``solid_angles_sr`` (n,): each light's solid angle (the manifest's), for folding
        the sun into its patch for version-1 clients; default: from the meter's dome."""
        self.meter = meter
        self.temporal = temporal
        self.hub = hub
        self.source = source
        self.stale_after_s = stale_after_s
        self.stale = False
        self.latest_frame: Frame | None = None
        self.latest_measurement: Measurement | None = None
        self.last_frame_wall_s: float | None = None
        self.frames_in = 0
        self.frames_measured = 0
        self.frames_skipped = 0
        self.frames_replaced = 0
        self.measure_ms: collections.deque[float] = collections.deque(maxlen=50)
        self._frame_times: collections.deque[float] = collections.deque(maxlen=64)
        self._frames: Newest[Frame] = Newest()
        self._saturated = np.zeros(0, dtype=bool)
        self.sun: SunMeasurement | None = None  # the newest frame's sun
        self.sun_ms: collections.deque[float] = collections.deque(maxlen=50)
        self._lookup: PatchLookup | None = None
        self._solid_angles_sr = solid_angles_sr
        self._last_skip_log_s = -1e9
        self._building: set[tuple[int, int]] = set()  # sizes (px) whose matrix is being built
        self._build_tasks: set[asyncio.Task] = set()
        self._unusable: dict[tuple[int, int], str] = {}  # sizes (px) with no matrix: why
        self.source_error = ""  # why the source's task last failed ("" if it has not)
        self._source_failed_s: float | None = None
        self.started_s = time.time()
        self.fusion = None  # a server.fusion.SceneFusion beside a sky camera, or None
        self.fusion_off = ""  # why there is none

    # ------------------------------------------------------------------------------- input

    def deliver(self, frame: Frame) -> None:
        """Called by the source for each frame; never blocks, keeps only the newest."""
        if self._frames.put(frame):
            self.frames_replaced += 1  # measuring is slower than the source: drop the older
        self.frames_in += 1

    # ---------------------------------------------------------------------------- tasks

    async def run_source(self) -> None:
        """The source's task (supervised): its failure is kept for the status."""
        try:
            await self.source.run(self.deliver)
        except Exception as exc:
            self.source_error = f"{exc}"
            self._source_failed_s = time.time()
            raise

    def _new_size(self, frame: Frame) -> bool:
        """True (and the size's matrix building off the event loop) if the frame is of a
        size the meter has no matrix for while it has one for another size."""
        image = frame.image
        if not isinstance(image, np.ndarray) or image.ndim != 3:
            return False  # measure() says what is wrong with it
        size = (image.shape[1], image.shape[0])
        if self.meter.matrix_count == 0 or self.meter.has_matrix(*size):
            return False
        if size in self._unusable:  # e.g. a size the calibration does not fit
            self._skip(f"skipping a frame from {self.source.name}: {self._unusable[size]}")
            return True
        if size not in self._building:
            self._building.add(size)
            log.info("%s: frames of a new size, %dx%d: building its measuring matrix on a "
                     "worker thread; frames of that size are skipped until it is ready",
                     self.source.name, *size)
            task = asyncio.create_task(self._build(size), name=f"matrix {size}")
            self._build_tasks.add(task)
            task.add_done_callback(self._build_tasks.discard)
        self.frames_skipped += 1
        return True

    async def _build(self, size: tuple[int, int]) -> None:
        try:
            await asyncio.to_thread(self.meter.prepare, *size)
        except Exception as exc:  # e.g. a size the calibration does not fit: not again
            self._unusable[size] = f"no measuring matrix for {size[0]}x{size[1]} frames: {exc}"
            log.warning("%s: %s", self.source.name, self._unusable[size])
        finally:
            self._building.discard(size)

    async def measure_forever(self) -> None:
        while True:
            frame = await self._frames.take()
            if self._new_size(frame):
                continue
            t0 = time.perf_counter()
            try:
                m = await asyncio.to_thread(self.meter.measure, frame)
            except FrameError as exc:
                self._skip(f"skipping a frame from {self.source.name}: {exc}")
                continue
            except Exception as exc:  # a bad frame must never stop the stream
                log.exception("measuring failed")
                self._skip(f"skipping a frame from {self.source.name}: {exc!r}")
                continue
            self.measure_ms.append(1e3 * (time.perf_counter() - t0))
            self.accept(frame, m)

    def _skip(self, message: str) -> None:
        self.frames_skipped += 1
        now = time.monotonic()
        if now - self._last_skip_log_s > 10.0:  # one line per 10 s, not one per frame
            log.warning("%s (%d skipped so far)", message, self.frames_skipped)
            self._last_skip_log_s = now

    def accept(self, frame: Frame, m: Measurement) -> None:
        """Fold one measurement in and publish if it changed enough (or flags changed)."""
        now = time.time()
        if self.fusion is not None:  # the scene's sun where the sky camera clipped it
            m = self.fusion.fuse(m, now)
        self.latest_frame = frame
        self.latest_measurement = m
        self.last_frame_wall_s = now
        self._frame_times.append(time.monotonic())
        self.frames_measured += 1
        if self.frames_measured == 1:
            mat = self.meter.matrix
            log.info("first frame from %s: %dx%d, measured at %dx%d (%d pixels, %d lights, "
                     "matrix built in %.1f s)", self.source.name, frame.image.shape[1],
                     frame.image.shape[0], mat.camera.width, mat.camera.height,
                     mat.pixels_used, mat.count, mat.build_s)
        self.source_error = ""
        if self.stale:
            log.info("%s: frames again; light no longer stale", self.source.name)
            self.stale = False
        if m.saturated.any() and not self._saturated.any():
            log.info("saturated lights (clipped pixels, e.g. the sun): %s",
                     np.flatnonzero(m.saturated).tolist())
        self._saturated = m.saturated
        if m.sun is not None:
            if self.sun is None or m.sun.source != self.sun.source:
                log.info("sun: %s", m.sun.source.label)
            self.sun = m.sun
            self.sun_ms.append(m.sun_ms)
            self.temporal.update(m.radiance, m.capture_time_s, m.sun.normal_irradiance_w_m2,
                                 m.sun.direction)
        else:
            self.temporal.update(m.radiance, m.capture_time_s)
        self._maybe_publish(now, m.capture_time_s)

    def _flags(self) -> int:
        flags = int(self.source.flags)
        if self.stale:
            flags |= Flags.STALE
        if self._saturated.any():
            flags |= Flags.SATURATED
        if self.sun is not None and self.sun.source in (SunSource.MODEL, SunSource.SCENE):
            flags |= Flags.SUN_ESTIMATED
        return flags

    def published_sun(self) -> PublishedSun | None:
        """The sun to publish now (None without a sun meter)."""
        if self.sun is None or self.temporal.sun is None:
            return None
        if self.sun.source == SunSource.NONE:
            return PublishedSun(np.zeros(3), np.zeros(3), SunSource.NONE)
        return PublishedSun(self.sun.direction.copy(), self.temporal.sun.copy(),
                            self.sun.source)

    def folded(self, rgb: np.ndarray, sun: PublishedSun | None) -> np.ndarray:
        """The version-1 vector: ``rgb`` with the sun in the patch holding its direction."""
        if sun is None or not np.any(sun.direction):
            return rgb
        if self._lookup is None:
            self._lookup = PatchLookup(self.meter.dome_vertices)
            if self._solid_angles_sr is None:
                self._solid_angles_sr = solid_angle(self.meter.dome_vertices)
        patch = int(self._lookup(sun.direction[None, :])[0])
        return fold_sun(rgb, sun, patch, self._solid_angles_sr)

    def _maybe_publish(self, now_s: float, capture_time_s: float, force: bool = False) -> None:
        flags = self._flags()
        source = None if self.sun is None else int(self.sun.source)
        key = (flags, self._saturated.tobytes(), source)
        if force or self.temporal.should_send(now_s, key):
            rgb = self.temporal.value.astype(np.float32)
            sun = self.published_sun()
            self.hub.publish_light(rgb, self._saturated, capture_time_s, flags, sun=sun,
                                   folded_rgb=self.folded(rgb, sun))
            self.temporal.mark_sent(now_s, key)

    async def watch_forever(self, period_s: float = 0.25) -> None:
        """Stale detection and keep-alive re-sends."""
        while True:
            await asyncio.sleep(period_s)
            now = time.time()
            idle_s = now - (self.last_frame_wall_s or self.started_s)
            if not self.stale and idle_s > self.stale_after_s:
                self.stale = True
                if self.temporal.value is None:
                    log.warning("%s: no frame measured in %.1f s since the start; light "
                                "marked stale (%s)", self.source.name, idle_s,
                                self.last_error() or "no error reported")
                else:
                    log.warning("%s: no frame for %.1f s; light marked stale, serving the "
                                "last good vector", self.source.name, idle_s)
            if self.temporal.value is None:
                continue
            capture = self.latest_measurement.capture_time_s if self.latest_measurement else now
            self._maybe_publish(now, capture)

    # ---------------------------------------------------------------------------- reports

    @property
    def fps(self) -> float:
        times = self._frame_times
        if len(times) < 2 or time.monotonic() - times[-1] > self.stale_after_s:
            return 0.0
        return (len(times) - 1) / max(times[-1] - times[0], 1e-9)

    def last_error(self) -> str:
        """The source's own last error, else why its task last failed ("" if neither)."""
        return str(self.source.status().get("last_error") or self.source_error)

    def status(self) -> dict:
        m = self.latest_measurement
        last = self.last_frame_wall_s
        failed = self._source_failed_s
        # A source whose task failed after its last frame is not delivering, whatever it says.
        connected = bool(self.source.connected) and (
            failed is None or (last is not None and last > failed))
        return {
            "source": self.source.name,
            "simulated": bool(self.source.flags & Flags.SIMULATED),
            "fps": round(self.fps, 3),
            "last_frame_time": (None if last is None else time.strftime(
                "%Y-%m-%dT%H:%M:%SZ", time.gmtime(last))),
            "last_frame_time_s": last,
            "stale": self.stale,
            "saturated_lights": [] if m is None else np.flatnonzero(m.saturated).tolist(),
            "saturated_pixels": 0 if m is None else m.saturated_pixels,
            "frames_measured": self.frames_measured,
            "frames_skipped": self.frames_skipped,
            "frames_replaced": self.frames_replaced,
            "measure_ms": round(float(np.median(self.measure_ms)), 3) if self.measure_ms
            else None,
            "sun": self.sun_status(),
            "fusion": {"off": self.fusion_off or "not configured"} if self.fusion is None
            else self.fusion.status(),
            **self.source.status(),
            "connected": connected and bool(self.source.status().get("connected", True)),
            "last_error": self.last_error() or None,
        }

    def sun_status(self) -> dict | None:
        """``sun`` of ``/api/status``: where, how bright (smoothed, as streamed), from what;
        None without a sun meter or before the first frame."""
        if self.sun is None:
            return None
        out = self.sun.status()
        if self.temporal.sun is not None and self.sun.source != SunSource.NONE:
            out["normal_irradiance_W_m2"] = [round(float(v), 3) for v in self.temporal.sun]
        out["sun_ms"] = round(float(np.median(self.sun_ms)), 3) if self.sun_ms else None
        return out

    def sky_jpeg(self, max_size_px: int = 320, quality: int = 80) -> bytes | None:
        """The newest sky frame, scaled to fit ``max_size_px``, as JPEG (None before any)."""
        frame = self.latest_frame
        if frame is None:
            return None
        image = frame.image
        if image.dtype != np.uint8:
            image = np.clip(image.astype(np.float32) * (255.0 if image.dtype.kind == "f" else
                                                        255.0 / 65535.0), 0, 255)
            image = image.astype(np.uint8)
        if not frame.bgr:
            image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
        h, w = image.shape[:2]
        scale = min(1.0, max_size_px / max(h, w))
        if scale < 1.0:
            image = cv2.resize(image, (max(1, round(w * scale)), max(1, round(h * scale))),
                               interpolation=cv2.INTER_AREA)
        ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])
        return buf.tobytes() if ok else None
