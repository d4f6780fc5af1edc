"""The light server's memory over a long run (the operator runs it for months): the real
`daylit serve` with the simulated sky measured as fast as it goes, WebSocket clients that
connect, take one light vector and leave, the server process's resident memory sampled after
every round. Prints each round and the growth per measured frame and per client after the
warm-up rounds (a least-squares slope), which a leak would make positive.

    python benchmarks/bench_soak.py BUILD [--rounds 40] [--clients 20] [--pause-s 20]
        [--rate-hz 20] [--warmup 5]

Rounds are counted, not timed: on a loaded machine fewer frames are measured per round and
the slope per frame says the same.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import aiohttp
import numpy as np

REPO = Path(__file__).resolve().parents[1]
DAYLIT = Path(sys.executable).parent / "daylit"


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS"):
            return int(line.split()[1]) / 1024
    raise RuntimeError(f"no VmRSS for process {pid}")


def status(port: int) -> dict:
    with urllib.request.urlopen(f"http://localhost:{port}/api/status", timeout=10) as r:
        return json.load(r)


async def client_round(port: int, clients: int) -> None:
    """Each client connects, waits for its first message (the light vector) and leaves."""
    async with aiohttp.ClientSession() as session:
        for _ in range(clients):
            async with session.ws_connect(f"http://localhost:{port}/ws/light?v=3") as ws:
                await ws.receive(timeout=30)


async def soak(args, port: int, pid: int) -> list[tuple[float, int, int, float]]:
    for _ in range(120):
        try:
            status(port)
            break
        except OSError:
            await asyncio.sleep(1)
    rows, served = [], 0
    start = time.monotonic()
    for _ in range(args.rounds):
        await client_round(port, args.clients)
        served += args.clients
        await asyncio.sleep(args.pause_s)
        frames = status(port)["sequence"]
        rows.append((time.monotonic() - start, frames, served, rss_mb(pid)))
        print(f"{rows[-1][0]:8.1f} s  frames {frames:7d}  clients {served:6d}  "
              f"RSS {rows[-1][3]:8.1f} MB", flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("build", type=Path)
    parser.add_argument("--rounds", type=int, default=40)
    parser.add_argument("--clients", type=int, default=20, help="clients per round")
    parser.add_argument("--pause-s", type=float, default=20.0, help="between rounds")
    parser.add_argument("--rate-hz", type=float, default=20.0, help="the sim sky's frame rate")
    parser.add_argument("--warmup", type=int, default=5, help="rounds left out of the slope")
    parser.add_argument("--port", type=int, default=8131)
    args = parser.parse_args()
    server = subprocess.Popen(
        [str(DAYLIT), "serve", str(args.build), "--port", str(args.port),
         "--set", f"sky.rate_hz={args.rate_hz}", "--log-level", "warning"],
        stdout=subprocess.DEVNULL)
    try:
        rows = asyncio.run(soak(args, args.port, server.pid))
    finally:
        server.terminate()
        server.wait()
    _, frames, served, rss = (np.array(c, float) for c in zip(*rows[args.warmup:], strict=True))
    per_frame = np.polyfit(frames, rss, 1)[0] * 1024
    per_client = np.polyfit(served, rss, 1)[0] * 1024
    print(f"after {args.warmup} warm-up rounds: RSS {rss[0]:.1f} -> {rss[-1]:.1f} MB over "
          f"{frames[-1] - frames[0]:.0f} frames and {served[-1] - served[0]:.0f} clients; "
          f"slope {per_frame:+.2f} kB per frame, {per_client:+.2f} kB per client")


if __name__ == "__main__":
    main()
