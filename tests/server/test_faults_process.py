"""The real ``daylit serve`` process under abuse (issue 19): a slowloris, one address holding
many sockets, the file descriptors running out, and SIGTERM with clients connected.

Each test starts the command as a subprocess (what ships), talks to it over real sockets, and
reads its standard error from a file (a pipe could fill and stall the server). Time bounds are
generous: the machine is shared and loaded.
"""

from __future__ import annotations

import asyncio
import json
import os
import resource
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import aiohttp
import pytest

from tests.server.helpers import stop_process

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Served:
    """``daylit serve BUILD`` on 127.0.0.1:port with ``--set`` options; stderr in a file."""

    def __init__(self, build_dir: Path, tmp_path: Path, *sets: str, file_limit: int = 0):
        self.port = free_port()
        self.err_path = tmp_path / f"serve-{self.port}.err"
        args = [sys.executable, "-m", "daylit.cli", "serve", str(build_dir), "--host",
                "127.0.0.1", "--port", str(self.port), "--set", "sim.size_px=96",
                "--set", "sky.rate_hz=10", "--set", "sun.enabled=false"]
        for s in sets:
            args += ["--set", s]

        def lower_file_limit() -> None:
            resource.setrlimit(resource.RLIMIT_NOFILE, (file_limit, file_limit))

        self.err = open(self.err_path, "w")  # noqa: SIM115 - closed in stop()
        self.proc = subprocess.Popen(
            args, stdout=subprocess.PIPE, stderr=self.err, text=True, cwd=ROOT,
            env=dict(os.environ, PYTHONUNBUFFERED="1"),
            preexec_fn=lower_file_limit if file_limit else None,
        )
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline:
            line = self.proc.stdout.readline()
            if "open http://" in line:
                break
            if not line and self.proc.poll() is not None:
                raise AssertionError(f"daylit serve exited: {self.stderr()}")
        self.url = f"http://127.0.0.1:{self.port}"

    def stderr(self) -> str:
        self.err.flush()
        return self.err_path.read_text()

    def status(self, source_address: str = "127.0.0.1", timeout_s: float = 10.0) -> dict:
        """``GET /api/status`` from ``source_address`` (any 127.x.y.z is this machine)."""
        with socket.create_connection(("127.0.0.1", self.port), timeout=timeout_s,
                                      source_address=(source_address, 0)) as sock:
            sock.sendall(b"GET /api/status HTTP/1.1\r\nHost: 127.0.0.1\r\n"
                         b"Connection: close\r\n\r\n")
            data = b""
            while chunk := sock.recv(65536):
                data += chunk
        head, _, body = data.partition(b"\r\n\r\n")
        assert head.startswith(b"HTTP/1.1 200"), head[:200]
        return json.loads(body)

    def stop(self) -> None:
        stop_process(self.proc, signal.SIGINT)
        self.proc.stdout.close()
        self.err.close()


@pytest.fixture
def serve(build_dir, tmp_path):
    started: list[Served] = []

    def start(*sets: str, file_limit: int = 0) -> Served:
        served = Served(build_dir, tmp_path, *sets, file_limit=file_limit)
        started.append(served)
        return served

    yield start
    for served in started:
        served.stop()


def closed_by_server(sock: socket.socket, within_s: float) -> bool:
    """True if the server closes ``sock`` (EOF or reset) within ``within_s``."""
    sock.settimeout(0.2)
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:
        try:
            if sock.recv(4096) == b"":
                return True
        except TimeoutError:
            continue
        except ConnectionError:
            return True
    return False


async def test_a_slowloris_is_cut_off_by_the_header_timeout(serve):
    served = serve("server.header_timeout_s=2")
    session = aiohttp.ClientSession()
    ws = await session.ws_connect(f"{served.url}/ws/light")  # must outlive the timeout
    loris = socket.create_connection(("127.0.0.1", served.port), timeout=5)
    t0 = time.monotonic()
    try:
        loris.sendall(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n")
        cut = False
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not cut:
            try:
                loris.sendall(b"X")  # one byte of a header that never ends, every 0.5 s
            except OSError:
                cut = True
                break
            cut = closed_by_server(loris, 0.5)
        assert cut, "the server waited over 30 s for a request's headers"
        assert served.status()["source"] == "sim"  # others are served meanwhile
        while time.monotonic() - t0 < 4.0:  # twice the header timeout: the stream goes on
            msg = await ws.receive(timeout=10)
            assert msg.type in (aiohttp.WSMsgType.TEXT, aiohttp.WSMsgType.BINARY), msg
    finally:
        loris.close()
        await ws.close()
        await session.close()


def test_one_address_cannot_take_every_connection(serve):
    served = serve("server.max_connections_per_address=5", "server.header_timeout_s=60")
    idle = [socket.create_connection(("127.0.0.1", served.port)) for _ in range(5)]
    try:
        time.sleep(0.5)  # let the server accept them
        sixth = socket.create_connection(("127.0.0.1", served.port))
        assert closed_by_server(sixth, 10.0), "a sixth connection from one address was kept"
        sixth.close()
        # Another address is served while 127.0.0.1 is at its limit.
        assert served.status(source_address="127.0.0.2")["source"] == "sim"
        idle.pop().close()
        deadline = time.monotonic() + 10
        while True:  # the freed slot is given back
            try:
                assert served.status()["source"] == "sim"
                break
            except (AssertionError, OSError):
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.2)
    finally:
        for sock in idle:
            sock.close()
    err = served.stderr()
    assert "max_connections_per_address" in err
    assert "Traceback" not in err


def test_out_of_file_descriptors_backs_off_and_logs_once_per_interval(serve):
    served = serve("server.max_connections_per_address=10000", "server.header_timeout_s=60",
                   file_limit=160)
    flood: list[socket.socket] = []
    try:
        for _ in range(300):  # far more than the server can hold open
            sock = socket.socket()
            sock.setblocking(False)
            sock.connect_ex(("127.0.0.1", served.port))
            flood.append(sock)
        time.sleep(4.0)
        err = served.stderr()
        assert "out of system resource" not in err  # asyncio's own line, once per attempt
        assert 1 <= err.count("out of file descriptors") <= 2, err[-3000:]
    finally:
        for sock in flood:
            sock.close()
    deadline = time.monotonic() + 20
    while True:  # with the flood gone, new clients are served again
        try:
            assert served.status(timeout_s=3)["source"] == "sim"
            break
        except (AssertionError, OSError):
            if time.monotonic() > deadline:
                raise
            time.sleep(0.3)
    assert served.proc.poll() is None
    assert len(served.stderr()) < 20_000


async def test_sigterm_closes_every_client_with_1001_and_exits(serve):
    served = serve()
    async with aiohttp.ClientSession() as session:
        sockets = []
        for _ in range(3):
            ws = await session.ws_connect(f"{served.url}/ws/light")
            assert json.loads((await ws.receive(timeout=30)).data)["type"] == "hello"
            assert (await ws.receive(timeout=60)).type == aiohttp.WSMsgType.BINARY
            sockets.append(ws)
        t0 = time.monotonic()
        served.proc.send_signal(signal.SIGTERM)

        async def close_code(ws) -> int | None:
            while True:
                msg = await ws.receive(timeout=30)
                if msg.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED,
                                aiohttp.WSMsgType.ERROR):
                    return ws.close_code

        # All three read at once, as three browsers would: each answers its close frame as it
        # comes, not after the one before it (the server waits 2 s for the answers).
        codes = list(await asyncio.gather(*(close_code(ws) for ws in sockets)))
    for _ in range(300):
        if served.proc.poll() is not None:
            break
        time.sleep(0.1)
    exit_s = time.monotonic() - t0
    assert codes == [1001, 1001, 1001]
    assert served.proc.poll() == 0, served.stderr()[-3000:]
    assert exit_s < 20.0  # the goal is 5 s; the bound is loose for a loaded machine
    err = served.stderr()
    assert "stopping after" in err and "Traceback" not in err


def test_file_limit_helper_really_lowers_the_limit():
    """The test above relies on setrlimit in the child: check it takes effect there."""
    out = subprocess.run(
        [sys.executable, "-c", "import resource; print(resource.getrlimit("
         "resource.RLIMIT_NOFILE)[0])"],
        preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_NOFILE, (160, 160)),
        capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "160"


def test_files_and_kept_alive_connections_pass_through_the_listener(serve, build_dir):
    """The listener hands connections to aiohttp unchanged: files (sendfile), keep-alive."""
    import http.client

    served = serve()
    conn = http.client.HTTPConnection("127.0.0.1", served.port, timeout=10)
    try:
        for _ in range(2):  # the same connection twice
            conn.request("GET", "/build/site.glb")
            resp = conn.getresponse()
            assert resp.status == 200
            assert resp.read() == (build_dir / "site.glb").read_bytes()
        conn.request("GET", "/build/manifest.json")
        resp = conn.getresponse()
        assert resp.status == 200 and json.loads(resp.read())["scene"]["id"] == "testsite"
    finally:
        conn.close()
