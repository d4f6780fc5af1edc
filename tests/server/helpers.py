"""Test doubles for the light server: sources the tests control, and settings."""

from __future__ import annotations

import asyncio
import json
import signal
import socket
import subprocess
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


class KioskSequence:
    """Synthetic site-camera frames for a build's kiosk view, with exact ground truth.

    Two people walk across the view: ``near`` in front of the virtual building (at 0.6 of its
    depth), ``far`` behind it (1.2 of its depth); both enter after the first ``empty_frames``
    frames of the empty site, which the occlusion pipeline learns as the background.
    ``truths[i]`` is frame ``i``'s :class:`server.occlusion.synthetic.TruthFrame`; ``depth`` the
    view's virtual depth image.
    """

    def __init__(self, build_dir: Path, view_id: str = "kiosk", frames: int = 30,
                 empty_frames: int = 10, fps: float = 10.0):
        from server.occlusion import OcclusionProcessor
        from server.occlusion.synthetic import SyntheticSite, Walker

        proc = OcclusionProcessor.from_build(build_dir, view_id)
        cam = proc.camera
        depth = proc.virtual_depth_m
        rows, cols = np.nonzero(np.isfinite(depth))
        u = int(np.median(cols))
        building_m = float(depth[rows[cols == u].max(), u])  # the building's base, that column
        forward = cam.R[:, 2]
        ray = cam.ray_directions(u + 0.5, 0.5 * cam.height)[0]
        heading = np.array([ray[0], 0.0, ray[2]]) / np.hypot(ray[0], ray[2])
        side = np.array([heading[2], 0.0, -heading[0]])
        enter_s = empty_frames / fps + 0.01

        def walker(depth_m, start_side_m, speed_mps, **clothes):
            along = depth_m / float(heading @ forward)
            p = cam.origin_m * [1, 0, 1] + heading * along + side * start_side_m
            v = side * speed_mps
            return Walker((p[0], p[2]), (v[0], v[2]), enter_s=enter_s, **clothes)

        self.near_depth_m, self.far_depth_m = 0.6 * building_m, 1.2 * building_m
        walkers = [walker(self.near_depth_m, -1.5, 0.6),
                   walker(self.far_depth_m, 1.5, -0.6, shirt=(0.1, 0.5, 0.2))]
        self.site = SyntheticSite(cam, walkers, fps=fps, duration_s=frames / fps)
        self.camera = cam
        self.depth = depth
        self.empty_frames = empty_frames
        self.truths = [self.site.frame(i) for i in range(self.site.frame_count)]

    @property
    def images(self) -> list[np.ndarray]:
        return [t.image for t in self.truths]

    def write(self, folder: Path) -> Path:
        """The frames as lossless PNG files ``frame_000.png`` ... in ``folder`` (a replay)."""
        import cv2

        folder.mkdir(parents=True, exist_ok=True)
        for i, image in enumerate(self.images):
            cv2.imwrite(str(folder / f"frame_{i:03d}.png"), image)
        return folder

    def index_of(self, jpeg: bytes) -> int:
        """Which frame a streamed JPEG shows (the nearest in mean absolute difference)."""
        import cv2

        image = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR).astype(np.int16)
        errors = [np.abs(image - frame).mean() for frame in self.images]
        return int(np.argmin(errors))

    def people_pixels(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Frame ``i``'s pixels of the near and the far person where they overlap the virtual
        building (the near one must hide it there, the far one must be hidden)."""
        truth = self.truths[i]
        over = np.isfinite(self.depth)
        by_depth = sorted(truth.people, key=lambda p: p.depth_m)
        near = far = np.zeros_like(over)
        for person in by_depth:
            pixels = (truth.person_index == person.index) & over
            if abs(person.depth_m - self.near_depth_m) < abs(person.depth_m - self.far_depth_m):
                near = pixels
            else:
                far = pixels
        return near, far


async def raw_websocket_that_never_reads(port: int, query: str = "") -> socket.socket:
    """A WebSocket handshake to ``/ws/light?<query>`` over a socket with a tiny receive
    buffer, never read again: a client the server must not wait for."""
    path = f"/ws/light?{query}" if query else "/ws/light"
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect(("127.0.0.1", port))
    sock.sendall(
        f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\n".encode()
        + b"Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
        b"Sec-WebSocket-Version: 13\r\n\r\n"
    )
    return sock


def interrupt_and_wait(proc: subprocess.Popen, timeout_s: float) -> None:
    """Ctrl-C a ``daylit`` process and wait for it to exit (killed if it does not in time)."""
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


async def first_light_v2(client):
    """Open ``/ws/light?protocol=2`` on an aiohttp test client and wait for its first LIGHT
    message; returns (the socket, the decoded message)."""
    from aiohttp import WSMsgType

    from server import protocol

    ws = await client.ws_connect("/ws/light?protocol=2")
    assert json.loads((await ws.receive(timeout=10)).data)["protocol"] == 2
    while True:
        msg = await ws.receive(timeout=30)
        assert msg.type == WSMsgType.BINARY
        m = protocol.decode(msg.data)
        if m.type == protocol.MessageType.LIGHT:
            return ws, m


async def wait_for(predicate, timeout_s: float = 60.0, period_s: float = 0.05) -> None:
    """Poll ``predicate()`` until it is true; fail after ``timeout_s`` (a bound for a loaded
    machine, never a measured time)."""
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout_s
    while not predicate():
        assert loop.time() < end, "condition not reached"
        await asyncio.sleep(period_s)


def stop_process(proc: subprocess.Popen, sig: int = signal.SIGTERM, timeout_s: float = 30.0):
    """Stop a `daylit serve` subprocess with ``sig`` (killed if it takes over ``timeout_s``)."""
    if proc.poll() is None:
        proc.send_signal(sig)
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
