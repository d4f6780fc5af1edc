"""The measuring process and the fan-out apart (issue 19): real ``daylit serve`` processes, a
real ``redis-server`` started here on a free port, real WebSocket clients.

- through Redis: one measuring process and two fan-out workers on one port; clients on both
  workers get the same messages (same sequence numbers, same bytes); killing one worker closes
  only its clients, who reconnect to the other; Redis restarted, the workers go on without a
  restart; a broker that is down at start is a clear error;
- ``--workers 2`` without a broker: both workers serve on one port, the same sequence, and
  SIGTERM to the parent stops all of them with 1001 to the clients.

Which worker a connection lands on is the kernel's choice (SO_REUSEPORT): the tests open
clients until both workers have some, and read each worker's own count from its status.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import aiohttp
import pytest

from server import protocol
from tests.server.helpers import stop_process, wait_for

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(shutil.which("redis-server") is None,
                                 reason="redis-server is not installed (make setup)")]

ROOT = Path(__file__).resolve().parents[2]
SETS = ["sim.size_px=96", "sky.rate_hz=4", "sun.enabled=false", "stream.change_threshold=0",
        "stream.smoothing_s=0"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class RedisServer:
    """``redis-server`` on 127.0.0.1:port, without persistence; restartable on that port."""

    def __init__(self, tmp_path: Path, password: str = ""):
        self.port = free_port()
        self.dir = tmp_path / "redis"
        self.dir.mkdir()
        self.proc: subprocess.Popen | None = None
        self.password = password
        auth = f":{password}@" if password else ""
        self.url = f"redis://{auth}127.0.0.1:{self.port}/0"

    def start(self) -> None:
        self.proc = subprocess.Popen(
            ["redis-server", "--port", str(self.port), "--bind", "127.0.0.1", "--save", "",
             "--appendonly", "no", "--dir", str(self.dir)]
            + (["--requirepass", self.password] if self.password else []),
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            with contextlib.suppress(OSError), \
                    socket.create_connection(("127.0.0.1", self.port), 1) as sock:
                sock.sendall(b"PING\r\n")
                if sock.recv(64).startswith((b"+PONG", b"-NOAUTH")):
                    return
            time.sleep(0.05)
        raise AssertionError("redis-server did not start")

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            self.proc.wait(timeout=30)


@pytest.fixture
def redis_server(tmp_path):
    server = RedisServer(tmp_path)
    server.start()
    yield server
    server.stop()


class Serve:
    """``daylit serve BUILD ARGS...`` on 127.0.0.1:port; stderr in a file; started when
    stdout says ``ready``."""

    def __init__(self, build_dir: Path, tmp_path: Path, port: int, *args: str,
                 ready: str = "open http://"):
        self.port = port
        self.err_path = tmp_path / f"serve-{time.monotonic_ns()}.err"
        argv = [sys.executable, "-m", "daylit.cli", "serve", str(build_dir), "--host",
                "127.0.0.1", "--port", str(port), *args]
        for s in SETS:
            argv += ["--set", s]
        self.err = open(self.err_path, "w")  # noqa: SIM115 - closed in stop()
        self.proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=self.err, text=True,
                                     cwd=ROOT, env=dict(os.environ, PYTHONUNBUFFERED="1"))
        self.code: int | None = None
        if ready:
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline:
                line = self.proc.stdout.readline()
                if ready in line:
                    break
                if not line and self.proc.poll() is not None:
                    raise AssertionError(f"daylit serve exited: {self.stderr()}")

    def stderr(self) -> str:
        self.err.flush()
        return self.err_path.read_text()

    def stop(self) -> None:
        stop_process(self.proc, signal.SIGTERM)
        self.proc.stdout.close()
        self.err.close()


@pytest.fixture
def serve(build_dir, tmp_path):
    started: list[Serve] = []

    def start(port: int, *args: str, ready: str = "open http://") -> Serve:
        served = Serve(build_dir, tmp_path, port, *args, ready=ready)
        started.append(served)
        return served

    yield start
    for served in reversed(started):
        served.stop()


async def status(port: int) -> dict:
    """``/api/status`` on a new connection (the kernel picks the worker)."""
    conn = aiohttp.TCPConnector(force_close=True)
    async with aiohttp.ClientSession(connector=conn) as session, \
            session.get(f"http://127.0.0.1:{port}/api/status") as resp:
        assert resp.status == 200
        return await resp.json()


async def statuses_by_worker(port: int, pids: int = 2, tries: int = 200) -> dict[int, dict]:
    """The status of each of ``pids`` workers (asked until every one has answered)."""
    seen: dict[int, dict] = {}
    for _ in range(tries):
        body = await status(port)
        seen[body["relay"]["pid"]] = body
        if len(seen) == pids:
            return seen
    raise AssertionError(f"only workers {sorted(seen)} answered in {tries} requests")


class Client:
    """A light-stream client that records every LIGHT message: sequence -> bytes."""

    def __init__(self, port: int):
        self.port = port
        self.messages: dict[int, bytes] = {}
        self.order: list[int] = []
        self.stale: list[bool] = []  # each LIGHT message's STALE flag, in order
        self.close_code: int | None = None
        self.hello: dict | None = None
        self.task: asyncio.Task | None = None

    async def start(self) -> None:
        self.session = aiohttp.ClientSession(connector=aiohttp.TCPConnector(force_close=True))
        self.ws = await self.session.ws_connect(f"http://127.0.0.1:{self.port}/ws/light")
        self.hello = json.loads((await self.ws.receive(timeout=30)).data)
        self.task = asyncio.create_task(self._read())

    async def _read(self) -> None:
        async for msg in self.ws:
            if msg.type == aiohttp.WSMsgType.BINARY:
                m = protocol.decode(msg.data)
                if m.type == protocol.MessageType.LIGHT:
                    self.messages[m.sequence] = msg.data
                    self.order.append(m.sequence)
                    self.stale.append(bool(m.flags & protocol.Flags.STALE))
        self.close_code = self.ws.close_code

    @property
    def closed(self) -> bool:
        return self.task is not None and self.task.done()

    async def close(self) -> None:
        with contextlib.suppress(Exception):
            await self.ws.close()
        if self.task is not None:
            with contextlib.suppress(Exception):
                await self.task
        await self.session.close()


async def open_clients(port: int, count: int) -> list[Client]:
    clients = [Client(port) for _ in range(count)]
    for c in clients:
        await c.start()
    return clients


async def spread_clients(port: int, count: int = 8) -> tuple[list[Client], dict[int, dict]]:
    """``count`` clients at least, opened until both workers hold some; (clients, each
    worker's status once every client is counted)."""
    clients = await open_clients(port, count)
    for _ in range(8):
        by_pid = await statuses_by_worker(port)
        if sum(s["clients"] for s in by_pid.values()) == len(clients) and \
                all(s["clients"] > 0 for s in by_pid.values()):
            return clients, by_pid
        clients += await open_clients(port, 4)
    raise AssertionError("the clients did not spread over both workers")


def assert_same_stream(clients: list[Client]) -> None:
    """Every client got increasing sequence numbers; any sequence two clients got is the same
    bytes; and some sequences every client got."""
    common = set.intersection(*(set(c.messages) for c in clients))
    assert len(common) >= 3, [c.order for c in clients]
    for c in clients:
        assert c.order == sorted(c.order)
    for seq in common:
        assert len({c.messages[seq] for c in clients}) == 1


async def wait_for_messages(clients: list[Client], n: int) -> None:
    marks = {id(c): len(c.order) for c in clients}
    await wait_for(lambda: all(len(c.order) >= marks[id(c)] + n for c in clients), 120)


async def test_two_workers_through_redis(serve, redis_server):
    port = free_port()
    broker = ["--broker", redis_server.url]
    measuring = serve(port, "--role", "measure", *broker, ready="publishing to")
    a = serve(port, "--role", "fanout", *broker)
    b = serve(port, "--role", "fanout", *broker)
    assert measuring.proc.poll() is None
    clients, by_pid = await spread_clients(port)
    try:
        assert set(by_pid) == {a.proc.pid, b.proc.pid}
        for body in by_pid.values():
            assert body["relay"]["connected"] and not body["stale"]
            assert body["source"] == "sim" and body["relay"]["link"] == redis_server.url
        assert all(c.hello["source"] == "sim" for c in clients)
        await wait_for_messages(clients, 6)
        assert_same_stream(clients)

        # Killing worker a closes its clients alone; they reconnect to b.
        on_a = by_pid[a.proc.pid]["clients"]
        a.proc.kill()
        a.proc.wait(timeout=30)
        await wait_for(lambda: sum(c.closed for c in clients) == on_a, 60)
        survivors = [c for c in clients if not c.closed]
        assert len(survivors) == len(clients) - on_a
        await wait_for_messages(survivors, 3)  # b's clients never noticed
        reconnected = await open_clients(port, on_a)
        after = await status(port)
        assert after["relay"]["pid"] == b.proc.pid and after["clients"] == len(clients)
        await wait_for_messages(survivors + reconnected, 4)
        assert_same_stream(survivors + reconnected)

        # Redis restarted: b and the measuring process go on, neither restarted; meanwhile
        # b's clients are sent the last vector marked STALE, and fresh ones after.
        assert not any(c.stale[-1] for c in survivors)
        redis_server.stop()

        async def b_says(stale: bool) -> bool:
            body = await status(port)
            return body["stale"] == stale and body["relay"]["connected"] == (not stale)

        deadline = time.monotonic() + 60
        while not await b_says(True):
            assert time.monotonic() < deadline, "the worker did not see the broker go"
            await asyncio.sleep(0.2)
        await wait_for(lambda: all(c.stale[-1] for c in survivors), 30)
        redis_server.start()
        seq_before = max(max(c.order) for c in survivors)
        deadline = time.monotonic() + 60
        while not await b_says(False):
            assert time.monotonic() < deadline, "the worker did not recover with the broker"
            await asyncio.sleep(0.2)
        await wait_for(lambda: all(max(c.order) > seq_before + 2 for c in survivors), 60)
        assert not any(c.stale[-1] for c in survivors)
        assert measuring.proc.poll() is None and b.proc.poll() is None
        assert (await status(port))["relay"]["connects"] >= 2
        for served in (measuring, b):
            assert "Traceback" not in served.stderr()
        assert "lost the broker" in b.stderr()
    finally:
        for c in clients:
            await c.close()
        for c in locals().get("reconnected", []):
            await c.close()


@pytest.mark.parametrize("role", ["fanout", "measure"])
def test_a_broker_down_at_start_is_a_clear_error(serve, role):
    port = free_port()
    down = f"redis://127.0.0.1:{free_port()}/0"
    served = serve(port, "--role", role, "--broker", down, ready="")
    code = served.proc.wait(timeout=180)  # imports alone take tens of seconds on a loaded machine
    err = served.stderr()
    assert code == 1, err
    assert "cannot reach the broker" in err and "redis-server" in err and "--broker" in err
    assert "Traceback" not in err


async def test_two_local_workers_share_the_port_and_the_sequence(serve):
    port = free_port()
    parent = serve(port, "--workers", "2")
    clients, by_pid = await spread_clients(port)
    try:
        assert len(by_pid) == 2 and parent.proc.pid not in by_pid
        for body in by_pid.values():
            assert body["relay"]["link"].startswith("local:") and not body["stale"]
        await wait_for_messages(clients, 6)
        assert_same_stream(clients)

        parent.proc.send_signal(signal.SIGTERM)
        parent.proc.wait(timeout=30)
        await wait_for(lambda: all(c.closed for c in clients), 30)
        assert {c.close_code for c in clients} == {1001}
        for pid in by_pid:  # the workers are gone too
            with pytest.raises(ProcessLookupError):
                os.kill(pid, 0)
        assert parent.proc.returncode == 0
        assert "Traceback" not in parent.stderr()
    finally:
        for c in clients:
            await c.close()


def exited(pid: int) -> bool:
    """The process is gone, or a zombie waiting for whoever adopted it to reap it."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return True
    return state in ("Z", "X")


async def test_workers_stop_when_their_parent_is_killed(serve):
    """SIGKILL to the parent of ``--workers 2`` (it cannot stop its children): the kernel
    sends each worker SIGTERM (PR_SET_PDEATHSIG), which closes its clients with 1001 and exits;
    nothing is left holding the port."""
    port = free_port()
    parent = serve(port, "--workers", "2")
    clients, by_pid = await spread_clients(port)
    try:
        await wait_for_messages(clients, 2)
        parent.proc.kill()
        parent.proc.wait(timeout=30)
        await wait_for(lambda: all(c.closed for c in clients), 30)
        assert {c.close_code for c in clients} == {1001}
        await wait_for(lambda: all(exited(pid) for pid in by_pid), 30)
        with pytest.raises(OSError), socket.create_connection(("127.0.0.1", port), 2):
            pass
    finally:
        for c in clients:
            await c.close()


async def test_a_local_worker_that_dies_is_replaced(serve):
    """``--workers 2``: a worker killed is started again by the parent; its clients reconnect
    (to whichever worker the kernel picks) and the others never notice."""
    port = free_port()
    parent = serve(port, "--workers", "2")
    clients, by_pid = await spread_clients(port)
    reconnected: list[Client] = []
    try:
        victim = min(by_pid)
        on_victim = by_pid[victim]["clients"]
        os.kill(victim, signal.SIGKILL)
        await wait_for(lambda: sum(c.closed for c in clients) == on_victim, 60)
        survivors = [c for c in clients if not c.closed]
        await wait_for_messages(survivors, 3)
        deadline = time.monotonic() + 90
        while True:  # the parent starts another worker: two pids again, the victim not one
            try:
                pids = set(await statuses_by_worker(port, tries=50))
            except AssertionError:  # one worker only, so far
                pids = set()
            if len(pids) == 2 and victim not in pids:
                break
            assert time.monotonic() < deadline, pids
        reconnected = await open_clients(port, on_victim)
        await wait_for_messages(survivors + reconnected, 4)
        assert_same_stream(survivors + reconnected)
        assert "fan-out worker" in parent.stderr() and "starting another" in parent.stderr()
        assert parent.proc.poll() is None
    finally:
        for c in clients + reconnected:
            await c.close()


async def test_a_broker_password_from_the_settings_file_stays_out_of_sight(serve, tmp_path):
    """``[server] broker`` with a password in the settings file: ``--workers 2`` runs through
    that Redis, the workers' command lines do not carry it, the status shows ``***``."""
    redis = RedisServer(tmp_path, password="s3cret-word")
    redis.start()
    try:
        config = tmp_path / "site.toml"
        config.write_text(f'[server]\nbroker = "{redis.url}"\n')
        port = free_port()
        parent = serve(port, "--workers", "2", "--config", str(config))
        # A worker answers as soon as it listens, which on a loaded machine can be before its
        # relay has the first vector through Redis: ask again until both have it (or 60 s).
        deadline = time.monotonic() + 60
        by_pid = await statuses_by_worker(port)
        while not all(b["relay"]["connected"] and not b["stale"] for b in by_pid.values()):
            if time.monotonic() > deadline:
                break
            await asyncio.sleep(0.2)
            by_pid = await statuses_by_worker(port)
        for pid, body in by_pid.items():
            assert body["relay"]["connected"] and not body["stale"]
            assert body["relay"]["link"] == f"redis://:***@127.0.0.1:{redis.port}/0"
            assert "s3cret-word" not in Path(f"/proc/{pid}/cmdline").read_text()
        assert "s3cret-word" not in json.dumps(list(by_pid.values()))
        assert "s3cret-word" not in parent.stderr()
    finally:
        redis.stop()
