"""Capture-to-client latency and fan-out of ``GET /ws/light`` over loopback.

Starts ``daylit serve`` in a subprocess on a 400-light build, replaying 1280x960 JPEG sky frames
(rendered once by the simulated sky) at 10 Hz (``--rate-hz``) with smoothing and the change
threshold off, so every frame becomes a vector. Clients in this process connect and record, for
every vector, ``arrival time - capture time`` (the header's capture time is stamped when the
frame is handed over by the source, before decoding is finished, measuring and sending). Client
and server share the machine's two cores, so the client side's own cost is inside the figures.

Levels: 10 clients (latency), then 100, 250, 500 and 1000 clients (fan-out). Each level runs for
``--seconds`` (default 8) after a one-second warm-up. Printed per level: clients, vectors per
client per second, median, 99th percentile and maximum latency in ms, and how many clients got
at least 90 % of the vectors.

``--protocols 2,3`` runs every level once per protocol version, one after the other in the
same server (version 2: the sky in float32, 4902 bytes at 400 lights; version 3: float16, 2502
bytes), and prints for each the bytes per message, the messages the clients received, the
server's CPU per 1,000 messages and its messages per second per core (messages / server CPU
seconds). ``--framing`` first measures, in this process, what is done once per message
(encoding each version) and what aiohttp does per client (``send_bytes``: building the
WebSocket frame and handing it to the transport), against a bare ``transport.write`` of a
pre-built frame.

Run: ``.venv/bin/python benchmarks/bench_stream.py`` (about two minutes).

Several processes (issue 19): ``--workers N`` serves with N fan-out workers fed by the
measuring process (its Unix socket), ``--broker redis`` through a ``redis-server`` this script
starts on a free port (``--broker redis://HOST:PORT/DB``: an existing one), and
``--client-processes K`` spreads the clients over K processes of their own. Server CPU is
then the sum over the measuring process, its workers (and Redis), with its kernel share.

Clients (``stream_clients.py``): ``--client-lib aiohttp`` (the default) or ``picows`` (Cython,
on uvloop: clients cheap enough that 10,000 of them do not hide the server's latency), or
``aiohttp,picows``: each level once per library against the same server, interleaved,
``--rounds N`` times (the order swapped each round). Both time a message's receipt the same
way. With client processes, each vector's first copy's latency and its burst (first copy to
99th-percentile copy) are printed too, and every row ends with the load average.
``--server-loop uvloop`` runs the server on uvloop (an experiment, through a sitecustomize).
Example, the 10,000-client level: ``--levels 10000 --rate-hz 2 --client-processes 2
--client-lib aiohttp,picows --rounds 2``.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import resource
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import aiohttp  # noqa: E402
import cv2  # noqa: E402
import numpy as np  # noqa: E402

from benchmarks.stream_clients import (  # noqa: E402
    CLIENT_LIBS,
    Receipts,
    make_clients,
    run_loop,
)
from server.fisheye import FisheyeCamera  # noqa: E402
from server.simsky import SimulatedSky  # noqa: E402
from tests.server.conftest import make_build  # noqa: E402

RATE_HZ = 10.0  # the replay's and so the vectors' rate; --rate-hz sets it
MAX_CLIENTS = 12000  # per server process: above the largest level


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def make_frames(folder: Path, count: int = 10) -> None:
    camera = FisheyeCamera.equidistant(1280, 960)
    sim = SimulatedSky.for_site(45.0, 10.0, 0.0, "UTC", camera=camera, cloud_cover=0.4)
    for k in range(count):
        frame = sim.render_at(sim.clock.start_s + 60.0 * k)
        bgr = cv2.cvtColor(frame.image, cv2.COLOR_RGB2BGR)
        cv2.imwrite(str(folder / f"{k:03d}.jpg"), bgr, [cv2.IMWRITE_JPEG_QUALITY, 92])


def start_server(build: Path, frames: Path, port: int, extra: tuple[str, ...] = (),
                 server_loop: str = "asyncio") -> subprocess.Popen:
    """``daylit serve`` on the frames in ``frames``; ``server_loop`` "uvloop" runs it (and its
    workers, which inherit the environment) on uvloop through a ``sitecustomize`` that
    installs uvloop's event loop policy: an experiment, not a server setting."""
    cmd = [
        sys.executable, "-m", "daylit.cli", "serve", str(build), "--host", "127.0.0.1",
        "--port", str(port), "--sky", f"replay:{frames}", "--log-level", "warning",
        "--set", f"sky.rate_hz={RATE_HZ}", "--set", "stream.smoothing_s=0",
        "--set", "stream.change_threshold=0", "--set", f"server.max_clients={MAX_CLIENTS}",
        "--set", "sky.stale_after_s=60",
        # Every benchmark client comes from 127.0.0.1.
        "--set", "server.max_connections_per_address=10000",
        *extra,
    ]
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    if server_loop == "uvloop":
        site = build.parent / "uvloop_site"
        site.mkdir(exist_ok=True)
        (site / "sitecustomize.py").write_text(
            "import asyncio\nimport uvloop\n\n"
            "asyncio.set_event_loop_policy(uvloop.EventLoopPolicy())\n")
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(site),
                                                          env.get("PYTHONPATH", "")]))
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, cwd=ROOT, env=env)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if "open http://" in line:
            return proc
        if proc.poll() is not None:
            break
    proc.kill()
    raise SystemExit("the server did not start")


def cpu_seconds(pid: int, system_only: bool = False) -> float:
    """User + system CPU time of a process (Linux /proc); ``system_only``: the kernel's part
    (system calls: the sockets' sends, and on loopback the receiving side's TCP work)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[12]) + (0 if system_only else int(fields[11]))) / os.sysconf("SC_CLK_TCK")


def process_tree(pid: int) -> list[int]:
    """``pid`` and its descendants (Linux /proc)."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        for task in Path(f"/proc/{p}/task").glob("*/children"):
            todo += [int(c) for c in task.read_text().split()]
    return out


def tree_cpu_seconds(pids: list[int], system_only: bool = False) -> float:
    total = 0.0
    for pid in pids:
        with contextlib.suppress(FileNotFoundError, ProcessLookupError):
            total += cpu_seconds(pid, system_only)
    return total


def start_redis(port: int) -> subprocess.Popen:
    proc = subprocess.Popen(["redis-server", "--port", str(port), "--bind", "127.0.0.1",
                             "--save", "", "--appendonly", "no"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        try:
            with socket.create_connection(("127.0.0.1", port), 1) as sock:
                sock.sendall(b"PING\r\n")
                if sock.recv(16).startswith(b"+PONG"):
                    return proc
        except OSError:
            time.sleep(0.05)
    proc.kill()
    raise SystemExit("redis-server did not start")


def _client_process(url: str, clients: int, seconds: float, go_event, out,
                    client_lib: str = "aiohttp") -> None:
    """One client process of ``run_level_processes``: its latencies (s) and CPU seconds.
    ``client_lib``: aiohttp, or picows on uvloop (``stream_clients``; the same receipt
    timing for both)."""

    async def go():
        receipts = Receipts(clients, keep_sequences=True)
        conns = make_clients(client_lib, url, receipts)
        await conns.open(clients)
        out.put("connected")
        await asyncio.to_thread(go_event.wait)  # every process connected, warmed up
        receipts.measuring = True
        cpu0 = time.process_time()
        await asyncio.sleep(seconds)
        receipts.measuring = False
        cpu = time.process_time() - cpu0
        await conns.close()
        return receipts.latencies_s, receipts.sequences, cpu

    out.put(run_loop(client_lib, go()))


def summarize(latencies: list[list[float]], clients: int, seconds: float, server_cpu: float,
              client_cpu: float) -> dict:
    """One level's figures from each client's capture-to-receipt latencies (seconds)."""
    every = np.concatenate([np.asarray(x) for x in latencies]) * 1e3
    expected = RATE_HZ * seconds
    return {
        "clients": clients,
        "rate": len(every) / clients / seconds,
        "p50": float(np.median(every)) if every.size else float("nan"),
        "p99": float(np.percentile(every, 99)) if every.size else float("nan"),
        "max": float(every.max()) if every.size else float("nan"),
        "full": sum(len(x) >= 0.9 * expected for x in latencies),
        "server_cpu": server_cpu,
        "client_cpu": client_cpu,
        "messages": int(every.size),
    }


async def run_level_processes(url: str, clients: int, seconds: float, server_pid: int,
                              processes: int, extra_pids: tuple[int, ...] = (),
                              client_lib: str = "aiohttp") -> dict:
    """As :func:`run_level`, the clients spread over ``processes`` processes of
    ``client_lib`` clients."""
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    queue = ctx.Queue()
    go_event = ctx.Event()
    shares = [clients // processes + (i < clients % processes) for i in range(processes)]
    procs = [ctx.Process(target=_client_process, args=(url, n, seconds, go_event, queue,
                                                       client_lib))
             for n in shares if n]
    for p in procs:
        p.start()
    for _ in procs:
        assert await asyncio.to_thread(queue.get, True, 300) == "connected"
    await asyncio.sleep(1.0)  # warm-up, as run_level
    pids = process_tree(server_pid) + list(extra_pids)
    cpu0, sys0, t0 = tree_cpu_seconds(pids), tree_cpu_seconds(pids, True), time.monotonic()
    go_event.set()
    await asyncio.sleep(seconds)
    wall = time.monotonic() - t0
    server_cpu = (tree_cpu_seconds(pids) - cpu0) / wall
    server_sys = (tree_cpu_seconds(pids, True) - sys0) / wall
    results = [await asyncio.to_thread(queue.get, True, 120) for _ in procs]
    for p in procs:
        p.join(30)
    latencies = [x for lat, _, _ in results for x in lat]
    sequences = [x for _, seq, _ in results for x in seq]
    return {**summarize(latencies, clients, seconds, server_cpu,
                        sum(cpu for _, _, cpu in results) / seconds),
            **burst_figures(latencies, sequences), "server_sys": server_sys}


def burst_figures(latencies: list[list[float]], sequences: list[list[int]]) -> dict:
    """Where a vector's latency goes (ms, medians over the vectors every client could get):
    ``first``, capture to its first copy's receipt (measuring, relay, the first write);
    ``burst``, its first copy's receipt to its 99th-percentile copy's (writing it to every
    client and the clients reading it: the fan-out)."""
    by_sequence: dict[int, list[float]] = {}
    for lat, seq in zip(latencies, sequences, strict=True):
        for latency_s, sequence in zip(lat, seq, strict=True):
            by_sequence.setdefault(sequence, []).append(latency_s)
    if not by_sequence:
        return {"first": float("nan"), "burst": float("nan")}
    most = max(len(v) for v in by_sequence.values())
    # Vectors at the run's edges reached only the clients still (or already) measuring.
    whole = [np.asarray(v) * 1e3 for v in by_sequence.values() if len(v) >= 0.9 * most]
    return {"first": float(np.median([v.min() for v in whole])),
            "burst": float(np.median([np.percentile(v, 99) - v.min() for v in whole]))}


async def wait_for_first_vector(base: str) -> None:
    """The first frame builds the measuring matrix (about a second): keep it out of the run."""
    async with aiohttp.ClientSession() as session:
        for _ in range(600):
            async with session.get(f"{base}/api/status") as resp:
                if (await resp.json())["sequence"] > 0:
                    return
            await asyncio.sleep(0.1)
    raise SystemExit("no vector from the server")


async def run_level(url: str, clients: int, seconds: float, server_pid: int) -> dict:
    """One level with aiohttp clients in this process (``--client-processes 1``)."""
    receipts = Receipts(clients)
    conns = make_clients("aiohttp", url, receipts)
    await conns.open(clients)
    await asyncio.sleep(1.0)
    receipts.measuring = True
    cpu0, own0, t0 = cpu_seconds(server_pid), time.process_time(), time.monotonic()
    await asyncio.sleep(seconds)
    receipts.measuring = False
    wall = time.monotonic() - t0
    server_cpu = (cpu_seconds(server_pid) - cpu0) / wall
    client_cpu = (time.process_time() - own0) / wall
    await conns.close()
    latencies, sizes = receipts.latencies_s, receipts.sizes
    return {
        **summarize(latencies, clients, seconds, server_cpu, client_cpu),
        "bytes": sorted(sizes),
        "server_cpu_s": server_cpu * wall,
    }


def framing_costs(lights: int = 400, repeats: int = 20000) -> None:
    """Per message (once, at publishing) and per client (aiohttp's send_bytes) costs, in this
    process, for protocol versions 2 and 3 at ``lights`` lights."""
    from types import SimpleNamespace

    from aiohttp._websocket.writer import WebSocketWriter

    from server import protocol

    rng = np.random.default_rng(1)
    sky = (10.0 ** rng.uniform(-1, 3, (lights, 1)) * rng.uniform(0.3, 1, (lights, 3)))
    sun = SimpleNamespace(direction=np.array([0.3, 0.8, -0.5]),
                          normal_irradiance_w_m2=np.array([900.0, 850.0, 800.0]), source=1)
    sat = np.zeros(lights, bool)

    class NullTransport:
        """Takes the bytes and drops them: what is left is aiohttp's own work."""

        def write(self, data):
            pass

        def is_closing(self):
            return False

    def per_call_us(fn, n):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        return (time.perf_counter() - t0) / n * 1e6

    async def send_cost(message: bytes) -> float:
        writer = WebSocketWriter(SimpleNamespace(_paused=False), NullTransport())
        t0 = time.perf_counter()
        for _ in range(repeats):
            await writer.send_frame(message, aiohttp.WSMsgType.BINARY)
        return (time.perf_counter() - t0) / repeats * 1e6

    def socket_send_us(frame: bytes, n: int) -> float:
        """A blocking send of the frame on a local socket pair (the kernel's part)."""
        a, b = socket.socketpair()
        spent = 0.0
        try:
            for _ in range(n):
                t0 = time.perf_counter()
                a.sendall(frame)
                spent += time.perf_counter() - t0
                got = 0
                while got < len(frame):
                    got += len(b.recv(1 << 16))
        finally:
            a.close()
            b.close()
        return spent / n * 1e6

    def tcp_fanout_send_us(frame: bytes, sockets: int = 5000, rounds: int = 5
                           ) -> tuple[float, float]:
        """The frame sent once to each of ``sockets`` loopback TCP connections, as a fan-out
        burst does (no asyncio, no aiohttp: the floor of a burst): (wall, system CPU) us
        per send, medians over ``rounds``. On loopback the kernel also runs the receiving
        side's TCP in the sender's system call."""
        listener = socket.create_server(("127.0.0.1", 0), backlog=4096)
        pairs, walls, systems = [], [], []
        try:
            for _ in range(sockets):
                client = socket.create_connection(listener.getsockname())
                server_side, _ = listener.accept()
                server_side.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                pairs.append((server_side, client))
            for _ in range(rounds):
                sys0, t0 = resource.getrusage(resource.RUSAGE_SELF).ru_stime, time.perf_counter()
                for server_side, _ in pairs:
                    server_side.send(frame)
                walls.append((time.perf_counter() - t0) / sockets * 1e6)
                systems.append((resource.getrusage(resource.RUSAGE_SELF).ru_stime - sys0)
                               / sockets * 1e6)
                for _, client in pairs:
                    client.recv(1 << 16)
        finally:
            listener.close()
            for a, b in pairs:
                a.close()
                b.close()
        return float(np.median(walls)), float(np.median(systems))

    print(f"Per message and per client, {lights} lights, {repeats} calls each (this process):")
    print(f"{'protocol':>8} {'bytes':>6} {'encode once us':>14} {'send_bytes us':>13} "
          f"{'header+copy us':>14} {'socket send us':>14} {'TCP x5000 us (sys)':>18}")
    for version in (2, 3):
        data = protocol.encode_light(sky, sat, 1, 2.0, version=version, sun=sun)
        encode_us = per_call_us(lambda v=version: protocol.encode_light(
            sky, sat, 1, 2.0, version=v, sun=sun), 2000)
        send_us = asyncio.run(send_cost(data))
        # What a pre-built frame would save per client: the header and the copy behind it.
        copy_us = per_call_us(lambda d=data: struct.pack("!BBH", 0x82, 126, len(d)) + d, repeats)
        frame = struct.pack("!BBH", 0x82, 126, len(data)) + data
        kernel_us = socket_send_us(frame, repeats // 4)
        tcp_us, tcp_sys_us = tcp_fanout_send_us(frame)
        print(f"{version:8d} {len(data):6d} {encode_us:14.1f} {send_us:13.2f} {copy_us:14.2f} "
              f"{kernel_us:14.2f} {tcp_us:9.2f} ({tcp_sys_us:5.2f})")
    print()


async def main_async(levels: list[int], seconds: float, protocols: list[int] | None = None,
                     workers: int = 1, broker: str = "", client_processes: int = 1,
                     client_libs: tuple[str, ...] = ("aiohttp",), rounds: int = 1,
                     server_loop: str = "asyncio") -> None:
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        build = make_build(tmp / "build", lights=400, scene_id="bench")
        frames = tmp / "frames"
        frames.mkdir()
        make_frames(frames)
        port = free_port()
        redis = None
        extra: tuple[str, ...] = ()
        if broker == "redis":
            redis_port = free_port()
            redis = start_redis(redis_port)
            broker = f"redis://127.0.0.1:{redis_port}/0"
        if workers > 1 or broker:
            extra = ("--workers", str(workers))
        if broker:
            extra += ("--broker", broker)
        proc = start_server(build, frames, port, extra, server_loop)
        try:
            url = f"http://127.0.0.1:{port}/ws/light"
            await wait_for_first_vector(f"http://127.0.0.1:{port}")
            if protocols:
                print(f"400 lights, 1280x960 JPEG replay at {RATE_HZ:g} Hz, {seconds:g} s a "
                      "level, loopback, 2 cores shared\n")
                await compare_protocols(url, levels, seconds, proc.pid, protocols)
                return
            print(f"400 lights ({12 * 400 + 74} bytes a vector), 1280x960 JPEG replay at "
                  f"{RATE_HZ:g} Hz, {seconds:g} s a level, loopback, 2 cores shared")
            print(f"workers: {workers}, broker: {broker or 'none'}, client processes: "
                  f"{client_processes}, server event loop: {server_loop}\n")
            print(f"{'round':>5} {'client lib':>10} {'clients':>7} {'vec/s each':>10} "
                  f"{'p50 ms':>7} {'p99 ms':>7} {'max ms':>7} {'>=90% of vectors':>16} "
                  f"{'1st copy ms':>11} {'burst ms':>8} "
                  f"{'server CPU':>10} {'of it kernel':>12} {'client CPU':>10} "
                  f"{'msg/s per server core':>21} "
                  f"{'load avg 1 min':>14}")
            for round_ in range(rounds):
                # Interleaved: each level's client libraries, in the other order each round.
                libs = client_libs if round_ % 2 == 0 else client_libs[::-1]
                for n in levels:
                    for lib in libs:
                        if client_processes > 1 or workers > 1 or broker or lib != "aiohttp":
                            r = await run_level_processes(
                                url, n, seconds, proc.pid, client_processes,
                                (redis.pid,) if redis else (), lib)
                        else:
                            r = await run_level(url, n, seconds, proc.pid)
                        print(f"{round_ + 1:5d} {lib:>10} {r['clients']:7d} {r['rate']:10.2f} "
                              f"{r['p50']:7.1f} {r['p99']:7.1f} {r['max']:7.1f} "
                              f"{r['full']:10d}/{n:<5} "
                              f"{r.get('first', float('nan')):11.1f} "
                              f"{r.get('burst', float('nan')):8.1f} "
                              f"{100 * r['server_cpu']:9.0f}% "
                              f"{100 * r.get('server_sys', float('nan')):11.0f}% "
                              f"{100 * r['client_cpu']:9.0f}% "
                              f"{r['clients'] * r['rate'] / max(r['server_cpu'], 1e-9):21.0f} "
                              f"{os.getloadavg()[0]:14.2f}", flush=True)
        finally:
            proc.terminate()
            proc.wait(timeout=30)
            if redis is not None:
                redis.terminate()
                redis.wait(timeout=30)


async def compare_protocols(url: str, levels: list[int], seconds: float, server_pid: int,
                            protocols: list[int]) -> None:
    """Each level once per protocol version, in the same server, one after the other."""
    print(f"{'protocol':>8} {'bytes':>6} {'clients':>7} {'vec/s each':>10} {'p50 ms':>7} "
          f"{'p99 ms':>7} {'messages':>8} {'server CPU':>10} {'CPU ms/1000 msg':>15} "
          f"{'msg/s per core':>14}")
    for n in levels:
        for version in protocols:
            r = await run_level(f"{url}?protocol={version}", n, seconds, server_pid)
            per_1000_ms = 1e6 * r["server_cpu_s"] / max(r["messages"], 1)
            per_core = r["messages"] / max(r["server_cpu_s"], 1e-9)
            size = "/".join(map(str, r["bytes"])) or "-"
            print(f"{version:8d} {size:>6} {n:7d} {r['rate']:10.2f} {r['p50']:7.1f} "
                  f"{r['p99']:7.1f} {r['messages']:8d} {100 * r['server_cpu']:9.0f}% "
                  f"{per_1000_ms:15.1f} {per_core:14.0f}", flush=True)


def main() -> None:
    global RATE_HZ  # read by start_server, summarize and the printed heading
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=8.0)
    parser.add_argument("--levels", default="10,100,250,500,1000")
    parser.add_argument("--protocols", default="",
                        help="e.g. 2,3: run every level once per protocol version")
    parser.add_argument("--framing", action="store_true",
                        help="first measure encoding and aiohttp's per-client framing")
    parser.add_argument("--workers", type=int, default=1,
                        help="fan-out workers (daylit serve --workers)")
    parser.add_argument("--broker", default="",
                        help="redis (a redis-server started here) or redis://HOST:PORT/DB")
    parser.add_argument("--client-processes", type=int, default=1,
                        help="processes the clients are spread over")
    parser.add_argument("--rate-hz", type=float, default=RATE_HZ,
                        help="vectors a second (the replay's frame rate); e.g. 2 for the "
                        "10,000-client level")
    parser.add_argument("--client-lib", default="aiohttp",
                        help="the clients' WebSocket library, one of "
                        f"{','.join(CLIENT_LIBS)} (picows runs on uvloop), or several "
                        "separated by commas: each level once per library, interleaved")
    parser.add_argument("--rounds", type=int, default=1,
                        help="repeat every level this many times (libraries in the other "
                        "order each round)")
    parser.add_argument("--server-loop", choices=("asyncio", "uvloop"), default="asyncio",
                        help="the server's event loop (uvloop: an experiment, set from outside)")
    args = parser.parse_args()
    client_libs = tuple(args.client_lib.split(","))
    for lib in client_libs:
        if lib not in CLIENT_LIBS:
            parser.error(f"--client-lib: {lib!r} is not one of {', '.join(CLIENT_LIBS)}")
    RATE_HZ = args.rate_hz
    # SIGTERM (a killed run) unwinds like Ctrl-C, so the server it started is stopped too.
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    # Each client is a socket on both ends (server, its workers and the clients inherit this).
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (min(hard, 2 * MAX_CLIENTS + 1024), hard))
    if args.framing:
        framing_costs()
    protocols = [int(x) for x in args.protocols.split(",") if x]
    asyncio.run(main_async([int(x) for x in args.levels.split(",")], args.seconds, protocols,
                           args.workers, args.broker, args.client_processes, client_libs,
                           args.rounds, args.server_loop))


if __name__ == "__main__":
    main()
