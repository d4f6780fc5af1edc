"""The processes of ``daylit serve`` beyond one: the measuring process and its fan-out workers.

``daylit serve BUILD --workers N`` (or with ``--broker``): this process measures (sky source,
meter, site camera, occlusion: :func:`server.app.create_app`), listens on no port, and feeds
its relay (:mod:`server.relay`) to the broker or to its own Unix socket; it starts N fan-out
workers (``daylit serve BUILD --role fanout``, :mod:`server.fanout`), each on the same port
with SO_REUSEPORT, so the kernel spreads new connections over them. ``--role measure`` is the
measuring process without workers (the workers run elsewhere, fed by Redis).

A worker that dies is started again (after 1 s, doubling to 30 s); one that dies before it
ever listened stops everything (it said why, e.g. the port is taken). Workers exit when their
parent dies (``PR_SET_PDEATHSIG``). SIGTERM or Ctrl-C: the workers get SIGTERM (each closes its
clients with 1001), those still running after :data:`STOP_WORKERS_S` are killed, then
measuring stops.
"""

from __future__ import annotations

import asyncio
import contextlib
import ctypes
import logging
import os
import signal
import sys
import tempfile
import time
from pathlib import Path

from aiohttp import web

log = logging.getLogger("daylit.workers")

STOP_WORKERS_S = 4.0
PR_SET_PDEATHSIG = 1
PARENT_ENV = "DAYLIT_PARENT_PID"  # set for a worker: its parent's pid
WORKER_ENV = "DAYLIT_WORKER"  # set for a worker: its number, 1..N


def die_with_parent() -> None:
    """In a worker: exit (SIGTERM) when the parent that started it dies."""
    parent = os.environ.get(PARENT_ENV)
    if not parent:
        return
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    if os.getppid() != int(parent):  # it died before prctl
        os.kill(os.getpid(), signal.SIGTERM)


class Worker:
    def __init__(self, number: int):
        self.number = number
        self.proc: asyncio.subprocess.Process | None = None
        self.ready = asyncio.Event()
        self.ever_ready = False
        self.starts = 0


class WorkerPool:
    """N fan-out worker processes (``argv``: the ``daylit serve`` arguments of one)."""

    def __init__(self, count: int, argv: list[str]):
        self.workers = [Worker(i + 1) for i in range(count)]
        self.argv = argv
        self.stopping = False
        self.failed = asyncio.Event()  # a worker died before it ever listened
        self._tasks: list[asyncio.Task] = []

    async def start(self) -> None:
        for worker in self.workers:
            self._tasks.append(asyncio.create_task(self._keep(worker),
                                                   name=f"worker {worker.number}"))

    async def wait_ready(self) -> bool:
        """True when every worker listens; False if one failed first."""
        ready = asyncio.gather(*(w.ready.wait() for w in self.workers))
        failed = asyncio.ensure_future(self.failed.wait())
        done, _ = await asyncio.wait({ready, failed}, return_when=asyncio.FIRST_COMPLETED)
        for future in (ready, failed):
            future.cancel()
        return not self.failed.is_set()

    async def _keep(self, worker: Worker) -> None:
        backoff_s = 1.0
        while not self.stopping:
            started = time.monotonic()
            code = await self._run(worker)
            if self.stopping:
                return
            if not worker.ever_ready:
                log.error("fan-out worker %d exited with code %s before it listened",
                          worker.number, code)
                self.failed.set()
                return
            if time.monotonic() - started > 60.0:
                backoff_s = 1.0
            log.warning("fan-out worker %d exited with code %s; starting another in %.0f s",
                        worker.number, code, backoff_s)
            await asyncio.sleep(backoff_s)
            backoff_s = min(2 * backoff_s, 30.0)

    async def _run(self, worker: Worker) -> int | None:
        env = dict(os.environ, **{PARENT_ENV: str(os.getpid()), WORKER_ENV: str(worker.number),
                                  "PYTHONUNBUFFERED": "1"})
        worker.ready.clear()
        worker.starts += 1
        worker.proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "daylit.cli", "serve", *self.argv,
            stdout=asyncio.subprocess.PIPE, stdin=asyncio.subprocess.DEVNULL, env=env)
        log.info("fan-out worker %d: pid %d", worker.number, worker.proc.pid)
        async for raw in worker.proc.stdout:
            line = raw.decode(errors="replace").rstrip()
            if "open http://" in line:
                worker.ready.set()
                worker.ever_ready = True
            else:  # its banner would repeat ours; its log lines go to the shared stderr
                log.debug("worker %d: %s", worker.number, line)
        return await worker.proc.wait()

    def status(self) -> list[dict]:
        return [{"worker": w.number, "pid": None if w.proc is None else w.proc.pid,
                 "running": w.proc is not None and w.proc.returncode is None,
                 "starts": w.starts} for w in self.workers]

    async def stop(self, timeout_s: float = STOP_WORKERS_S) -> None:
        self.stopping = True
        running = [w.proc for w in self.workers if w.proc and w.proc.returncode is None]
        for proc in running:
            with contextlib.suppress(ProcessLookupError):
                proc.send_signal(signal.SIGTERM)
        if running:
            _, late = await asyncio.wait([asyncio.ensure_future(p.wait()) for p in running],
                                         timeout=timeout_s)
            for proc in running:
                if proc.returncode is None:
                    log.warning("fan-out worker pid %d did not stop in %.0f s: killed",
                                proc.pid, timeout_s)
                    with contextlib.suppress(ProcessLookupError):
                        proc.kill()
            for future in late:
                await future
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)


def worker_argv(args, settings, broker: str) -> list[str]:
    """The ``daylit serve`` arguments of one fan-out worker of this command."""
    argv = [str(args.build), "--role", "fanout", "--workers", "1",
            "--host", settings.server.host, "--port", str(settings.server.port),
            "--log-level", args.log_level]
    # A broker from the settings file (which the worker reads too) stays off the command line:
    # no password in `ps`.
    from_file = settings.origin.get("server.broker") not in (None, "command line")
    if not (from_file and broker == settings.server.broker):
        argv += ["--broker", broker]
    if args.config:
        argv += ["--config", args.config]
    for flag in ("tls_cert", "tls_key"):
        if getattr(args, flag, None):
            argv += ["--" + flag.replace("_", "-"), getattr(args, flag)]
    for name in getattr(args, "allow_host", None) or ():
        argv += ["--allow-host", name]
    for text in args.set:
        argv += ["--set", text]
    return argv


def local_feed_url() -> tuple[str, Path]:
    """A fresh ``local:PATH`` in a private temporary folder (and the folder)."""
    folder = Path(tempfile.mkdtemp(prefix="daylit-feed-"))
    return f"local:{folder / 'feed.sock'}", folder


async def serve_measuring(app: web.Application, settings, link, pool: WorkerPool | None,
                          stop: asyncio.Event) -> int:
    """Run the measuring process: its background tasks, the relay ``link`` (a publisher of
    :mod:`server.localfeed` or :mod:`server.broker`, started) and the workers, until
    ``stop``; 1 if a worker could not start."""
    from server.app import HUB, PIPELINE, hello_info, status_body
    from server.relay import Outbox

    outbox: Outbox = link.outbox
    outbox.attach(app[HUB])
    runner = web.AppRunner(app, handle_signals=False, access_log=None)
    await runner.setup()  # starts measuring (cleanup_ctx), listens nowhere
    pipeline = app[PIPELINE]

    def status() -> dict:
        body = status_body(app)
        body["relay"] = {"role": "measure", "pid": os.getpid(), **link.status()}
        if pool is not None:
            body["relay"]["workers"] = pool.status()
        return body

    tasks = [
        asyncio.create_task(link.run(), name="relay link"),
        asyncio.create_task(outbox.run_status(
            status, lambda: hello_info(app), lambda: pipeline.sky_jpeg(320),
            lambda: pipeline.last_frame_wall_s), name="relay status"),
    ]
    code = 0
    try:
        if pool is not None:
            await pool.start()
            if not await pool.wait_ready():
                code = 1
                return code
            host, port = settings.server.host, settings.server.port
            shown = "localhost" if host in ("0.0.0.0", "::", "") else host
            print(f"daylit: {len(pool.workers)} fan-out workers on port {port}, fed by "
                  f"{link.status().get('broker') or link.status().get('feed')}", flush=True)
            print(f"daylit: open http://{shown}:{port}/", flush=True)
        else:
            where = link.status().get("broker") or link.status().get("feed")
            print(f"daylit: measuring, publishing to {where} (Ctrl-C to stop)", flush=True)
        failed = asyncio.ensure_future(pool.failed.wait() if pool else asyncio.Event().wait())
        stopped = asyncio.ensure_future(stop.wait())
        await asyncio.wait({failed, stopped}, return_when=asyncio.FIRST_COMPLETED)
        failed.cancel()
        stopped.cancel()
        if pool is not None and pool.failed.is_set():
            code = 1
        return code
    finally:
        if pool is not None:
            await pool.stop()
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        await link.close()
        await runner.cleanup()

