"""Test doubles for the light server: sources the tests control, and settings."""

from __future__ import annotations

import asyncio
import threading
from pathlib import Path

import numpy as np

from server.config import load_settings
from server.measure import Frame
from server.protocol import Flags
from server.sources.base import Source

ROOT = Path(__file__).resolve().parents[2]


def settings_for(tmp_path: Path, **overrides):
    """Settings with a temporary web root and short timings; ``sky__rate_hz=5`` style keys."""
    web = tmp_path / "web"
    if not web.exists():
        (web / "src").mkdir(parents=True)
        (web / "index.html").write_text("<!doctype html><title>daylit</title>\n")
        (web / "src" / "main.js").write_text("export const answer = 42;\n")
    values = {
        "server.web_root": str(web),
        "server.three_root": str(ROOT / "node_modules" / "three"),
        "sky.rate_hz": 20.0,
        "sky.stale_after_s": 1.0,
        "sky.reconnect_min_s": 0.05,
        "sky.reconnect_max_s": 0.2,
        "stream.smoothing_s": 0.0,
        "stream.change_threshold": 0.0,
        "sim.size_px": 96,
        "sim.start": "2026-06-21T10:30",
    }
    values.update({k.replace("__", "."): v for k, v in overrides.items()})
    return load_settings(None, values)


def sky_frame(value: float = 0.5, size: int = 64, bgr: bool = True) -> Frame:
    """A uniform 8-bit sky frame."""
    image = np.full((size, size, 3), round(value * 255), np.uint8)
    return Frame(image, 0.0, bgr=bgr)


class ManualSource(Source):
    """A source whose frames the test pushes, and which the test can make crash."""

    def __init__(self, name: str = "manual"):
        self.name = name
        self.flags = Flags.NONE
        self.deliver = None
        self.runs = 0
        self._running = asyncio.Event()
        self._crash = asyncio.Event()

    async def run(self, deliver) -> None:
        self.deliver = deliver
        self.runs += 1
        self._crash = asyncio.Event()
        self._running.set()
        try:
            await self._crash.wait()
            raise RuntimeError("source crashed")
        finally:
            self._running.clear()
            self.deliver = None

    async def started(self) -> None:
        await asyncio.wait_for(self._running.wait(), 10.0)

    def crash(self) -> None:
        self._crash.set()

    def push(self, frame: Frame) -> None:
        self.deliver(frame)


class FakeCapture:
    """Stands in for ``cv2.VideoCapture``: delivers frames while ``camera.alive`` is set."""

    def __init__(self, camera: FakeCamera):
        self.camera = camera

    def isOpened(self) -> bool:  # noqa: N802 - OpenCV's name
        return self.camera.alive.is_set()

    def read(self):
        if not self.camera.alive.is_set():
            return False, None
        self.camera.alive.wait(0.01)  # about 100 frames per second
        return True, np.full((64, 64, 3), 128, np.uint8)

    def release(self) -> None:
        pass


class FakeCamera:
    """A camera the test can unplug and plug back in."""

    def __init__(self):
        self.alive = threading.Event()
        self.alive.set()
        self.opened = 0

    def open(self, target):
        self.opened += 1
        return FakeCapture(self)
