"""Test-only helpers for the browser tests: Chromium through Playwright, a small stand-in
light server whose stream the test controls, ``daylit serve`` as a subprocess, and readers for
what the page hands back.

The stand-in (:class:`StubServer`) serves ``web/``, three.js and a build exactly at the paths
``daylit serve`` uses, and a ``/ws/light`` that sends the hello and then whatever binary
messages the test pushes (light vectors, site-camera frames, occlusion masks). The real server
is exercised end to end in ``test_web_e2e.py``.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

import numpy as np
from aiohttp import WSMsgType, web

REPO = Path(__file__).resolve().parents[2]
WEB = REPO / "web"
THREE = REPO / "node_modules" / "three"
SCREENSHOTS = Path(__file__).resolve().parent / "screenshots"

CHROMIUM_FLAGS = [
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--no-sandbox",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--headless=new",
    # A fake camera for the phone's camera mode (no real device, no permission prompt).
    "--use-fake-device-for-media-stream",
    "--use-fake-ui-for-media-stream",
]

TYPES = {
    ".js": "text/javascript", ".mjs": "text/javascript", ".html": "text/html",
    ".css": "text/css", ".json": "application/json", ".wasm": "application/wasm",
    ".ktx2": "image/ktx2", ".glb": "model/gltf-binary", ".png": "image/png",
    ".bin": "application/octet-stream",
}


def chromium_path() -> str:
    """Debian's chromium (installed by `make test`); never a downloaded browser."""
    for candidate in (os.environ.get("DAYLIT_CHROMIUM"), "/usr/bin/chromium",
                      shutil.which("chromium")):
        if candidate and Path(candidate).exists():
            return candidate
    raise RuntimeError("chromium is not installed: run `make test` (it installs Debian's "
                       "chromium) or set DAYLIT_CHROMIUM")


def node_path() -> str:
    """Node, which the README's set-up installs (`make setup` runs `npm ci` with it); a test
    that needs it fails without it, never skips."""
    node = os.environ.get("DAYLIT_NODE") or shutil.which("node")
    if not node:
        raise RuntimeError("node is not installed: install Node 20 and run `make setup` "
                           "(README.md, Set-up), or set DAYLIT_NODE")
    return node


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def decode_floats(result: dict) -> np.ndarray:
    """(H, W, 4) float32 from the page's {width, height, data: base64}."""
    raw = base64.b64decode(result["data"])
    return np.frombuffer(raw, dtype="<f4").reshape(result["height"], result["width"], 4)


class StubServer:
    """A light server stand-in on a thread of its own; ``push(bytes)`` broadcasts."""

    def __init__(self, build_dir: Path, hello: dict | None = None,
                 fail_paths: tuple[str, ...] = ()):
        self.build_dir = Path(build_dir)
        self.manifest = json.loads((self.build_dir / "manifest.json").read_text())
        self.hello = {
            "type": "hello", "protocol": 1, "scene": self.manifest["scene"]["id"],
            "lights": self.manifest["dome"]["count"], "manifest": "/build/manifest.json",
            "source": "test", "simulated": False, "streams": ["light"],
            "available_streams": ["light"], "site_camera": None, "smoothing_s": 0.0,
            "server_time_s": 0.0,
        }
        self.hello.update(hello or {})
        self.fail_paths = set(fail_paths)
        self.clients: set[web.WebSocketResponse] = set()
        self.received: list[str] = []
        self.served: list[str] = []  # the build's paths asked for ("build/ktx2/...")
        self.last: list[bytes] = []  # sent again to every client that connects
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self._loop = asyncio.new_event_loop()
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self):
        self._thread.start()
        if not self._ready.wait(10):
            raise RuntimeError("stub server did not start")
        return self

    def __exit__(self, *exc):
        asyncio.run_coroutine_threadsafe(self._shutdown(), self._loop).result(10)
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(10)

    def _run(self):
        asyncio.set_event_loop(self._loop)
        app = web.Application()
        app.router.add_get("/ws/light", self._ws)
        app.router.add_get("/build/{tail:.*}", self._static(self.build_dir, "build/"))
        app.router.add_get("/vendor/three/{tail:.*}", self._static(THREE, None))
        app.router.add_get("/{tail:.*}", self._static(WEB, None))
        self._runner = web.AppRunner(app, access_log=None)
        self._loop.run_until_complete(self._runner.setup())
        site = web.TCPSite(self._runner, "127.0.0.1", self.port)
        self._loop.run_until_complete(site.start())
        self._ready.set()
        self._loop.run_forever()

    async def _shutdown(self):
        for ws in list(self.clients):
            await ws.close()
        await self._runner.cleanup()

    def _static(self, root: Path, prefix: str | None):
        async def handle(request: web.Request):
            tail = request.match_info["tail"] or "index.html"
            if prefix:
                self.served.append(prefix + tail)
            if prefix and prefix + tail in self.fail_paths:
                raise web.HTTPNotFound()
            path = (root / tail).resolve()
            if not path.is_relative_to(root.resolve()) or not path.is_file():
                raise web.HTTPNotFound()
            return web.FileResponse(path, headers={
                "Content-Type": TYPES.get(path.suffix, "application/octet-stream"),
                "Cache-Control": "no-store"})
        return handle

    async def _ws(self, request: web.Request):
        ws = web.WebSocketResponse()
        await ws.prepare(request)
        hello = dict(self.hello, server_time_s=time.time())
        await ws.send_str(json.dumps(hello))
        for data in self.last:
            await ws.send_bytes(data)
        self.clients.add(ws)
        try:
            async for msg in ws:
                if msg.type == WSMsgType.TEXT:
                    self.received.append(msg.data)
                    request_ = json.loads(msg.data)
                    if request_.get("type") == "ping":
                        await ws.send_str(json.dumps({"type": "pong", "id": request_.get("id"),
                                                      "server_time_s": time.time()}))
        finally:
            self.clients.discard(ws)
        return ws

    def push(self, *messages: bytes, remember: bool = False) -> None:
        """Send binary messages to every connected client (and later ones if ``remember``)."""
        if remember:
            self.last.extend(messages)

        async def send():
            for ws in list(self.clients):
                for data in messages:
                    await ws.send_bytes(data)
        asyncio.run_coroutine_threadsafe(send(), self._loop).result(10)

    def wait_for_clients(self, n: int = 1, timeout_s: float = 20.0) -> None:
        t0 = time.monotonic()
        while len(self.clients) < n:
            if time.monotonic() - t0 > timeout_s:
                raise TimeoutError("no client connected to the stub server")
            time.sleep(0.05)


class DaylitServer:
    """``daylit serve BUILD ARGS`` as a subprocess on a free (or given) port."""

    def __init__(self, build_dir: Path, *args: str, port: int | None = None,
                 token: str | None = None):
        self.build_dir = Path(build_dir)
        self.args = list(args)
        self.port = port or free_port()
        self.token = token  # the operator's token (DAYLIT_OPERATOR_TOKEN), None: none
        self.url = f"http://127.0.0.1:{self.port}"
        self.proc: subprocess.Popen | None = None

    def start(self, timeout_s: float = 60.0) -> DaylitServer:
        cmd = [sys.executable, "-m", "daylit.cli", "serve", str(self.build_dir),
               "--host", "127.0.0.1", "--port", str(self.port), *self.args]
        self.log_path = Path(tempfile.gettempdir()) / f"daylit-serve-{self.port}.log"
        self.log = open(self.log_path, "ab")  # noqa: SIM115
        env = {k: v for k, v in os.environ.items() if k != "DAYLIT_OPERATOR_TOKEN"}
        if self.token is not None:
            env["DAYLIT_OPERATOR_TOKEN"] = self.token
        self.proc = subprocess.Popen(cmd, cwd=REPO, stdout=self.log, stderr=subprocess.STDOUT,
                                     env=env)
        status_url = self.url + "/api/status" + (f"?token={self.token}" if self.token else "")
        t0 = time.monotonic()
        while True:
            if self.proc.poll() is not None:
                raise RuntimeError(f"daylit serve exited with {self.proc.returncode}: "
                                   + self.log_text()[-2000:])
            with contextlib.suppress(OSError), \
                    urllib.request.urlopen(status_url, timeout=2) as r:
                if json.loads(r.read()).get("sequence", 0) > 0:
                    return self
            if time.monotonic() - t0 > timeout_s:
                self.stop()
                raise TimeoutError("daylit serve sent no light vector in time")
            time.sleep(0.2)

    def log_text(self) -> str:
        return self.log_path.read_text(errors="replace")

    def stop(self) -> None:
        if self.proc and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        self.proc = None
        if getattr(self, "log", None):
            self.log.close()
            self.log = None

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()


def srgb_to_linear(code: np.ndarray) -> np.ndarray:
    c = np.asarray(code, dtype=np.float64) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
