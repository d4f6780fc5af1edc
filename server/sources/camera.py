"""A live camera through OpenCV ``VideoCapture``: device index, video file or stream URL.

The camera is read on its own thread (``read()`` blocks). When it stops delivering, the
source marks itself disconnected, releases the device and tries again after a pause that
doubles up to ``reconnect_max_s``; it never raises. The pipeline marks the light stale when
frames stop, and keeps serving the last good vector.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import threading
import time
from collections.abc import Callable

import cv2

from server.measure import Frame
from server.sources.base import Deliver, Source

log = logging.getLogger("daylit.sources")


# A network stream that stops sending must not block ``read()`` forever: FFmpeg gives up
# after this long, the source reconnects.
STREAM_TIMEOUT_MS = 10_000


def open_video_capture(target: int | str, timeout_ms: int = STREAM_TIMEOUT_MS):
    """Open a ``cv2.VideoCapture`` (the default ``open_capture`` of :class:`CameraSource`).

    A device index goes to OpenCV's default backend. A URL (``rtsp://``, ``http://.../mjpeg``,
    anything with ``://``) goes to OpenCV's FFmpeg backend, as IP cameras deliver MJPEG over
    HTTP or H.264 over RTSP, with open and read time-outs of ``timeout_ms``; RTSP is read over
    TCP (UDP drops packets, which smears H.264 frames) unless
    ``OPENCV_FFMPEG_CAPTURE_OPTIONS`` says otherwise. Files go to the default backend.
    """
    if isinstance(target, str) and "://" in target:
        if target.lower().startswith("rtsp") and \
                "OPENCV_FFMPEG_CAPTURE_OPTIONS" not in os.environ:
            os.environ["OPENCV_FFMPEG_CAPTURE_OPTIONS"] = "rtsp_transport;tcp"
        return cv2.VideoCapture(target, cv2.CAP_FFMPEG,
                                [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, int(timeout_ms),
                                 cv2.CAP_PROP_READ_TIMEOUT_MSEC, int(timeout_ms)])
    cap = cv2.VideoCapture(target)
    if isinstance(target, int):
        cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)  # newest frame, not a queue of old ones
    return cap


class CameraSource(Source):
    """Frames from a camera, at most ``rate_hz`` per second.

    Parameters
    ----------
    target : int or str
        Device index, file or URL, as ``cv2.VideoCapture`` takes it.
    open_capture : callable
        Opens the capture; tests pass a fake with ``isOpened()``, ``read()``, ``release()``.
    """

    def __init__(
        self,
        target: int | str,
        rate_hz: float = 2.0,
        reconnect_min_s: float = 1.0,
        reconnect_max_s: float = 30.0,
        open_capture: Callable = open_video_capture,
        name: str | None = None,
    ):
        self.target = target
        self.name = name or f"camera:{target}"
        self.period_s = 1.0 / rate_hz
        self.reconnect_min_s = reconnect_min_s
        self.reconnect_max_s = reconnect_max_s
        self.open_capture = open_capture
        self.connected = False
        self.reconnects = 0
        self.last_error = ""

    async def run(self, deliver: Deliver) -> None:
        loop = asyncio.get_running_loop()
        stop = threading.Event()
        done = loop.create_future()

        def from_thread(fn, *args) -> None:
            try:
                loop.call_soon_threadsafe(fn, *args)
            except RuntimeError:  # the loop has closed (the server is stopping): drop it
                stop.set()

        def hand_over(frame: Frame) -> None:
            from_thread(deliver, frame)

        def finish() -> None:
            if not done.done():
                done.set_result(None)

        thread = threading.Thread(
            target=self._read_forever, args=(hand_over, stop, lambda: from_thread(finish)),
            name=f"daylit-{self.name}", daemon=True,
        )
        thread.start()
        try:
            await done  # only when the thread ends, which it does only when stopped
        finally:
            stop.set()
            self.connected = False

    def _read_forever(self, hand_over, stop: threading.Event, finished) -> None:
        wait_s = self.reconnect_min_s
        cap = None
        last_sent = 0.0
        try:
            while not stop.is_set():
                if cap is None:
                    try:
                        cap = self.open_capture(self.target)
                        if not cap.isOpened():
                            raise OSError("cannot open")
                    except Exception as exc:  # any driver error means: retry later
                        self._fail(f"{self.name}: {exc}; retrying in {wait_s:.0f} s", cap)
                        cap = None
                        stop.wait(wait_s)
                        wait_s = min(2 * wait_s, self.reconnect_max_s)
                        continue
                try:
                    ok, image = cap.read()
                except Exception as exc:
                    ok, image = False, None
                    self.last_error = str(exc)
                if not ok or image is None:
                    self._fail(f"{self.name}: stopped delivering frames; reconnecting in "
                               f"{wait_s:.0f} s", cap)
                    cap = None
                    stop.wait(wait_s)
                    wait_s = min(2 * wait_s, self.reconnect_max_s)
                    continue
                if not self.connected:
                    log.info("%s: delivering frames %s", self.name,
                             f"{image.shape[1]}x{image.shape[0]}" if image.ndim >= 2 else "")
                self.connected = True
                wait_s = self.reconnect_min_s
                now = time.monotonic()
                if now - last_sent >= self.period_s * 0.999:
                    last_sent = now
                    hand_over(Frame(image, time.time(), bgr=True))
                    if self._is_file():  # a file reads faster than real time: pace it
                        stop.wait(self.period_s)
        finally:
            if cap is not None:
                cap.release()
            self.connected = False
            finished()

    def _is_file(self) -> bool:
        return isinstance(self.target, str) and "://" not in self.target

    def _fail(self, message: str, cap) -> None:
        if self.connected or not self.reconnects:
            log.warning(message)
        else:
            log.debug(message)
        self.connected = False
        self.reconnects += 1
        self.last_error = message
        if cap is not None:
            with contextlib.suppress(Exception):  # a broken driver may fail to release too
                cap.release()

    def status(self) -> dict:
        return {"connected": self.connected, "reconnects": self.reconnects,
                "last_error": self.last_error}
