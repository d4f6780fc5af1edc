"""Two of issue 19's faults measured on a code tree: SIGTERM with light-stream clients
connected, and the log when the server runs out of file descriptors.

For the tree given (default: this repository; pass an older checkout as the baseline, e.g.
``git archive cdb79ae | tar -x -C /tmp/base``), it starts that tree's ``daylit serve`` on a
40-light build with the simulated sky (96 px, 10 Hz) and:

1. connects three WebSocket clients, waits for a vector on each, sends SIGTERM and prints each
   client's close code and when it came, and when the process exited (seconds after SIGTERM);
2. starts it again with the open-file limit lowered to 160 (``resource.setrlimit`` in the
   child), opens 300 connections that send nothing, waits 5 s and prints the size of the
   server's log, its lines, and how many say "out of system resource" (asyncio's line) and
   "out of file descriptors" (the server's own).

Run: ``.venv/bin/python benchmarks/bench_faults.py [--tree PATH] [--set KEY=VALUE ...]``
(about a minute; ``--set`` is passed to the second server, e.g.
``server.max_connections_per_address=10000`` so that all 300 come from 127.0.0.1).
"""

from __future__ import annotations

import argparse
import asyncio
import os
import resource
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import aiohttp  # noqa: E402

from tests.server.conftest import make_build  # noqa: E402

FILE_LIMIT = 160
FLOOD = 300


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start(tree: Path, build: Path, port: int, err: Path, sets: list[str],
          file_limit: int = 0) -> subprocess.Popen:
    args = [sys.executable, "-m", "daylit.cli", "serve", str(build), "--host", "127.0.0.1",
            "--port", str(port), "--set", "sim.size_px=96", "--set", "sky.rate_hz=10",
            "--set", "sun.enabled=false"]
    for s in sets:
        args += ["--set", s]

    def lower() -> None:
        resource.setrlimit(resource.RLIMIT_NOFILE, (file_limit, file_limit))

    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=err.open("w"), text=True,
                            cwd=tree, preexec_fn=lower if file_limit else None,
                            env=dict(os.environ, PYTHONPATH=str(tree), PYTHONUNBUFFERED="1"))
    while "open http://" not in proc.stdout.readline():
        if proc.poll() is not None:
            raise SystemExit(f"daylit serve exited: {err.read_text()[-2000:]}")
    return proc


async def sigterm(tree: Path, build: Path, tmp: Path) -> None:
    port = free_port()
    proc = start(tree, build, port, tmp / "sigterm.err", [])
    async with aiohttp.ClientSession() as session:
        sockets = []
        for _ in range(3):
            ws = await session.ws_connect(f"http://127.0.0.1:{port}/ws/light")
            await ws.receive(timeout=30)  # hello
            await ws.receive(timeout=60)  # a vector
            sockets.append(ws)
        t0 = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        closes = []
        for ws in sockets:
            try:
                while (await ws.receive(timeout=120)).type not in (
                        aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED,
                        aiohttp.WSMsgType.ERROR):
                    pass
            except aiohttp.ClientError:
                pass
            closes.append((ws.close_code and int(ws.close_code), round(time.monotonic() - t0, 2)))
    proc.wait(timeout=180)
    print(f"SIGTERM: clients' (close code, s after SIGTERM): {closes}; process exited after "
          f"{time.monotonic() - t0:.2f} s with status {proc.returncode}")


def out_of_descriptors(tree: Path, build: Path, tmp: Path, sets: list[str]) -> None:
    port = free_port()
    err = tmp / "fds.err"
    proc = start(tree, build, port, err, sets, file_limit=FILE_LIMIT)
    flood = []
    try:
        for _ in range(FLOOD):
            sock = socket.socket()
            sock.setblocking(False)
            sock.connect_ex(("127.0.0.1", port))
            flood.append(sock)
        time.sleep(5.0)
        text = err.read_text(errors="replace")
        print(f"out of descriptors ({FLOOD} connections, file limit {FILE_LIMIT}), 5 s: log "
              f"{len(text)} bytes, {text.count(chr(10))} lines, 'out of system resource' "
              f"{text.count('out of system resource')}, 'out of file descriptors' "
              f"{text.count('out of file descriptors')}")
    finally:
        for sock in flood:
            sock.close()
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--tree", type=Path, default=ROOT, help="code tree to measure")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="setting for the second server (repeatable)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        build = make_build(tmp / "build")
        print(f"tree: {args.tree.resolve()}")
        asyncio.run(sigterm(args.tree.resolve(), build, tmp))
        out_of_descriptors(args.tree.resolve(), build, tmp, args.set)


if __name__ == "__main__":
    main()
