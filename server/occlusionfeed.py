"""Occlusion by visitors in the light server: the site camera's frames -> masks for kiosks.

The work (10-40 ms a frame, :mod:`server.occlusion`) runs in one worker *process* by default:
the occlusion pipeline holds the GIL for most of its time, and in a thread of the server it
would delay the light stream and every client's messages by as much (measured: the event loop's
99th-percentile lag went from 8 to 19 ms with the pipeline in a thread at 10 frames/s). The
worker keeps the pipeline's state (the background model, the last labels) between frames; the
server sends it the newest frame only and waits for the answer before it sends the next, so
nothing queues up.

- :class:`OcclusionEngine` runs in the worker: it builds the
  :class:`~server.occlusion.OcclusionProcessor` for the build's fixed view at the size of the
  frames it is given (scaled down to ``max_width``), learns the empty site from the first
  ``learn_frames`` frames, and returns the encoded mask of each frame
  (:func:`~server.occlusion.encode_mask`: the payload of an OCCLUSION_MASK message).
- :class:`OcclusionRunner` is the server's side: it starts the worker, hands it frames, logs
  what the worker logged, restarts a worker that died (the background is then learned anew),
  passes on a relearn request (SIGHUP), and reports the state for ``/api/status``.

Frames that cannot be used (wrong type, another size than the frames before) are skipped with a
log line at most every 10 s; frames of a new size that keep coming for ``RESIZE_AFTER_FRAMES``
frames mean the camera changed its resolution: the pipeline is rebuilt for it and learns the
background again.
"""

from __future__ import annotations

import asyncio
import collections
import concurrent.futures
import logging
import multiprocessing
import signal
import time
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field

from server.throttledlog import ThrottledWarnings

log = logging.getLogger("daylit.occlusion")

# Frames of another size than the pipeline's, in a row, before it is rebuilt for them.
RESIZE_AFTER_FRAMES = 20
# Aspect ratios of the frames and the baked view may differ by this much (rounding of sizes).
ASPECT_TOLERANCE = 0.01


@dataclass(frozen=True)
class OcclusionConfig:
    """What the worker needs to build its pipeline (picklable)."""

    build_dir: str
    view_id: str
    view_size: tuple[int, int]
    max_width: int = 1024
    learn_frames: int = 10
    response: str = "srgb"


@dataclass
class OcclusionOutput:
    """The worker's answer for one frame.

    ``ok`` False: the frame was skipped (``reason``). ``payload`` is the encoded mask
    (all clear while ``learning``). ``ms`` is the time the worker spent on the frame.
    ``logs`` are ``(logger, level, message)`` the worker logged meanwhile (process mode).
    """

    ok: bool
    reason: str = ""
    learning: bool = False
    payload: bytes = b""
    size: tuple[int, int] | None = None
    people: int = 0
    people_in_front: int = 0
    ms: float = 0.0
    logs: list[tuple[str, int, str]] = field(default_factory=list)


class OcclusionEngine:
    """The occlusion pipeline for one site camera, fed one frame at a time (worker side)."""

    def __init__(self, config: OcclusionConfig):
        self.config = config
        self.processor = None
        self.size: tuple[int, int] | None = None  # of the frames the processor takes
        self.input_size: tuple[int, int] | None = None  # of the camera's frames
        self._other_size: tuple[int, int] | None = None
        self._other_count = 0
        self._provisional = False  # built for the view's size before any frame came
        self._skip_warnings = ThrottledWarnings(log, interval_s=10.0)

    def prepare(self) -> None:
        """Build the pipeline for the view's own size before the first frame comes.

        Building reads the build's depth image (about a second on a loaded machine); done on
        the first frame, the camera's next frames were dropped meanwhile (newest frame only),
        and the frames learned as the empty site were then later ones, possibly with people
        in them. If the camera's frames turn out to have another size, the pipeline is
        rebuilt for them at once.
        """
        if self.processor is not None:
            return
        try:
            self._build(tuple(self.config.view_size))
            self._provisional = True
        except Exception:  # the first frame tries again, and its failure is logged per frame
            log.exception("occlusion: the pipeline could not be built for the view's size")
            self.processor = None

    def relearn(self) -> None:
        """Forget the background (and everything else): the next frames are learned anew.

        The pipeline is rebuilt from its camera and depth image at once (no file read), so no
        frame is dropped meanwhile."""
        from server.occlusion import OcclusionProcessor

        old = self.processor
        if old is not None:
            self.processor = OcclusionProcessor(old.camera, old.virtual_depth_m, old.settings)

    def working_size(self, width: int, height: int) -> tuple[int, int]:
        w = self.config.max_width
        if width <= w:
            return width, height
        return w, max(1, round(height * w / width))

    def _build(self, input_size: tuple[int, int]) -> None:
        from server.occlusion import OcclusionProcessor, OcclusionSettings

        size = self.working_size(*input_size)
        settings = OcclusionSettings(response=self.config.response,
                                     learn_frames=self.config.learn_frames)
        self.processor = OcclusionProcessor.from_build(
            self.config.build_dir, self.config.view_id, settings, frame_size=size)
        self.size, self.input_size = size, input_size
        self._other_size, self._other_count = None, 0
        log.info("occlusion: view %r, frames of %dx%d processed at %dx%d; learning the empty "
                 "site from the next %d frames", self.config.view_id, input_size[0],
                 input_size[1], size[0], size[1], self.config.learn_frames)

    def _skip(self, reason: str, t0: float) -> OcclusionOutput:
        self._skip_warnings.warn(reason, f"occlusion: skipping a site camera frame: {reason}")
        return OcclusionOutput(False, reason, ms=1e3 * (time.perf_counter() - t0))

    def _check_size(self, input_size: tuple[int, int]) -> str | None:
        """Why frames of this size cannot be used, or None; (re)builds the pipeline."""
        vw, vh = self.config.view_size
        w, h = input_size
        if abs((w / h) / (vw / vh) - 1.0) > ASPECT_TOLERANCE:
            return (f"frames are {w}x{h} but the view {self.config.view_id!r} is {vw}x{vh} "
                    "(another aspect ratio: is [occlusion] view the site camera's view?)")
        if self.processor is None or (self._provisional and input_size != self.input_size):
            self._build(input_size)
            self._provisional = False
            return None
        self._provisional = False
        if input_size == self.input_size:
            self._other_size, self._other_count = None, 0
            return None
        if input_size != self._other_size:
            self._other_size, self._other_count = input_size, 0
        self._other_count += 1
        if self._other_count >= RESIZE_AFTER_FRAMES:
            log.warning("occlusion: the site camera now delivers %dx%d frames (was %dx%d); "
                        "learning the background again", w, h, *self.input_size)
            self._build(input_size)
            return None
        return f"frame is {w}x{h}, the frames before were {self.input_size[0]}x" \
               f"{self.input_size[1]}"

    def process(self, image, capture_time_s: float | None = None,
                bgr: bool = True) -> OcclusionOutput:
        """One frame (H, W, 3) uint8; never raises."""
        import cv2
        import numpy as np

        from server.occlusion import encode_mask

        t0 = time.perf_counter()
        try:
            if not isinstance(image, np.ndarray) or image.ndim != 3 or image.shape[2] != 3:
                shape = getattr(image, "shape", None)
                return self._skip(f"not an H x W x 3 image (shape {shape})", t0)
            if image.dtype != np.uint8:
                return self._skip(f"pixel type {image.dtype}, expected uint8", t0)
            h, w = image.shape[:2]
            if h == 0 or w == 0:
                return self._skip("empty frame", t0)
            why = self._check_size((w, h))
            if why is not None:
                return self._skip(why, t0)
            if not bgr:
                image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
            if (w, h) != self.size:
                image = cv2.resize(image, self.size, interpolation=cv2.INTER_AREA)
            result = self.processor.process(image, capture_time_s)
            if not result.ok:  # the processor has logged why
                return OcclusionOutput(False, result.skipped_reason or "unusable frame",
                                       ms=1e3 * (time.perf_counter() - t0))
            return OcclusionOutput(
                True, learning=result.learning,
                payload=encode_mask(result.mask, result.people_in_front),
                size=self.size, people=len(result.people),
                people_in_front=result.people_in_front,
                ms=1e3 * (time.perf_counter() - t0),
            )
        except Exception as exc:  # a frame must never stop the stream
            log.exception("occlusion: a site camera frame failed")
            self.processor = None  # start over cleanly with the next frame
            return OcclusionOutput(False, f"pipeline error: {exc!r}",
                                   ms=1e3 * (time.perf_counter() - t0))


# ------------------------------------------------------------------ the worker process side

_ENGINE: OcclusionEngine | None = None
_LOGS: list[tuple[str, int, str]] = []


class _Collect(logging.Handler):
    """Keeps the worker's log records to hand them to the server with the next answer."""

    def emit(self, record: logging.LogRecord) -> None:
        text = record.getMessage()
        if record.exc_info:
            text += "\n" + logging.Formatter().formatException(record.exc_info)
        _LOGS.append((record.name, record.levelno, text))
        del _LOGS[:-100]


def _worker_init(config: OcclusionConfig) -> None:
    global _ENGINE
    # Ctrl-C reaches every process of the terminal's group: the server stops the worker itself.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    root = logging.getLogger()
    root.handlers[:] = [_Collect()]
    root.setLevel(logging.INFO)
    import cv2

    cv2.setNumThreads(1)  # one core for occlusion, the other for measuring and serving
    _ENGINE = OcclusionEngine(config)


def _worker_process(image, capture_time_s, bgr: bool, relearn: bool) -> OcclusionOutput:
    if relearn:
        _ENGINE.relearn()
    out = _ENGINE.process(image, capture_time_s, bgr)
    out.logs = _LOGS[:]
    _LOGS.clear()
    return out


def _worker_ping() -> bool:
    """Warms the worker up before the first frame: imports, and the pipeline built for the
    view's size (:meth:`OcclusionEngine.prepare`)."""
    import server.occlusion  # noqa: F401

    _ENGINE.prepare()
    return True


# ----------------------------------------------------------------------- the server side


class OcclusionRunner:
    """Hands site-camera frames to the occlusion worker, one at a time; the server's side.

    Parameters
    ----------
    config : OcclusionConfig
    worker : ``"process"`` (default) or ``"thread"``
    """

    def __init__(self, config: OcclusionConfig, worker: str = "process"):
        if worker not in ("process", "thread"):
            raise ValueError(f"occlusion worker must be process or thread, got {worker!r}")
        self.config = config
        self.worker = worker
        self._executor: concurrent.futures.Executor | None = None
        self._engine: OcclusionEngine | None = None  # thread mode
        self._relearn = False
        self.state = "starting"
        self.frames = 0
        self.frames_skipped = 0
        self.worker_restarts = 0
        self.relearns = 0
        self.size: tuple[int, int] | None = None
        self.people = 0
        self.people_in_front = 0
        self.last_error = ""
        self.last_frame_wall_s: float | None = None
        self.ms = collections.deque(maxlen=50)  # worker time per frame
        self.round_trip_ms = collections.deque(maxlen=50)  # frame handed over -> mask back

    # ------------------------------------------------------------------------- lifecycle

    def _start_executor(self) -> None:
        if self.worker == "thread":
            self._engine = OcclusionEngine(self.config)
            self._executor = concurrent.futures.ThreadPoolExecutor(
                1, thread_name_prefix="daylit-occlusion")
        else:
            self._executor = concurrent.futures.ProcessPoolExecutor(
                1, mp_context=multiprocessing.get_context("spawn"),
                initializer=_worker_init, initargs=(self.config,))

    async def start(self) -> None:
        """Start the worker and wait until it is ready (imports done)."""
        if self._executor is None:
            self._start_executor()
        loop = asyncio.get_running_loop()
        t0 = time.perf_counter()
        if self.worker == "process":
            await loop.run_in_executor(self._executor, _worker_ping)
            log.info("occlusion worker process ready in %.1f s", time.perf_counter() - t0)
        else:
            await loop.run_in_executor(self._executor, self._engine.prepare)
        if self.state == "starting":
            self.state = "learning"

    async def close(self) -> None:
        executor, self._executor = self._executor, None
        if executor is not None:
            await asyncio.to_thread(executor.shutdown, True, cancel_futures=True)

    def relearn(self) -> None:
        """Learn the empty site again from the next frames (the operator's reset)."""
        self._relearn = True
        self.relearns += 1
        self.state = "learning"
        log.info("occlusion: re-learning the background from the next %d frames (keep the "
                 "site camera's view empty meanwhile)", self.config.learn_frames)

    # ------------------------------------------------------------------------- per frame

    async def process(self, image, capture_time_s: float, bgr: bool = True
                      ) -> OcclusionOutput | None:
        """The mask of one frame, or None when the frame was skipped (already logged)."""
        if self._executor is None:
            await self.start()
        loop = asyncio.get_running_loop()
        relearn, self._relearn = self._relearn, False
        t0 = time.perf_counter()
        try:
            if self.worker == "thread":
                engine = self._engine

                def run():
                    if relearn:
                        engine.relearn()
                    return engine.process(image, capture_time_s, bgr)

                out = await loop.run_in_executor(self._executor, run)
            else:
                out = await loop.run_in_executor(self._executor, _worker_process, image,
                                                 capture_time_s, bgr, relearn)
        except BrokenProcessPool:
            self.worker_restarts += 1
            self.frames_skipped += 1
            self.last_error = "the occlusion worker process died"
            log.error("occlusion: the worker process died; starting a new one (it learns the "
                      "background again)")
            old, self._executor = self._executor, None
            if old is not None:
                old.shutdown(wait=False, cancel_futures=True)
            self.state = "starting"
            await self.start()
            return None
        for name, level, text in out.logs:
            logging.getLogger(name).log(level, "%s", text)
        if not out.ok:
            self.frames_skipped += 1
            self.last_error = out.reason
            return None
        self.frames += 1
        self.last_frame_wall_s = time.time()
        self.ms.append(out.ms)
        self.round_trip_ms.append(1e3 * (time.perf_counter() - t0))
        self.size = out.size
        self.people, self.people_in_front = out.people, out.people_in_front
        was = self.state
        self.state = "learning" if out.learning else "ready"
        if was == "learning" and self.state == "ready":
            log.info("occlusion: background learned; streaming masks of people in front")
        return out

    @property
    def worker_pid(self) -> int | None:
        """The worker process's id (None in thread mode or before it started)."""
        processes = getattr(self._executor, "_processes", None) or {}
        return next(iter(processes), None)

    def status(self) -> dict:
        def median(values) -> float | None:
            return round(float(sorted(values)[len(values) // 2]), 2) if values else None

        return {
            "state": self.state,
            "view": self.config.view_id,
            "worker": self.worker,
            "worker_pid": self.worker_pid,
            "size": list(self.size) if self.size else None,
            "frames": self.frames,
            "frames_skipped": self.frames_skipped,
            "people": self.people,
            "people_in_front": self.people_in_front,
            "ms_per_frame": median(self.ms),
            "round_trip_ms": median(self.round_trip_ms),
            "last_frame_time_s": self.last_frame_wall_s,
            "learn_frames": self.config.learn_frames,
            "relearns": self.relearns,
            "worker_restarts": self.worker_restarts,
            "last_error": self.last_error,
        }
