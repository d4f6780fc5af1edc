"""Accepting connections for ``daylit serve``: the listening socket, a limit per client
address, a back-off when the process runs out of file descriptors, and refused requests
logged as one warning line.

asyncio's own accept loop (CPython 3.11, ``BaseSelectorEventLoop._accept_connection``) keeps
trying after ``EMFILE``: one wake-up makes up to 100 attempts, each logging "socket.accept()
out of system resource" with a traceback and scheduling its own retry; 1,400 half-open
connections against a 1,300 file limit made 550,000 such lines in 5 minutes. :class:`GuardedSite`
accepts connections itself and hands each to aiohttp through the public
``loop.connect_accepted_socket``: out of descriptors, it stops accepting for a pause that
doubles from 50 ms to 2 s (reset by the next accepted connection) and logs one line per
``log_interval_s`` with how many pauses it held back. Connections the kernel queued meanwhile
wait in the listen backlog.

Each client address may hold ``max_connections_per_address`` connections at once (pages, files
and light streams alike); more are closed as soon as they are accepted, with one log line per
address per interval. Together with the header timeout (aiohttp's ``keepalive_timeout``, which
closes a connection that has not sent a whole request's headers within that long of opening or
of its last answer), one address cannot hold the server's sockets.
"""

from __future__ import annotations

import asyncio
import errno
import logging
import socket
import ssl

from aiohttp import web
from aiohttp.http_exceptions import HttpProcessingError

from server.throttledlog import ThrottledWarnings

log = logging.getLogger("daylit.server")

OUT_OF_RESOURCES = frozenset({errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM})
ACCEPTS_PER_WAKE = 64


class _Counted(asyncio.Protocol):
    """Hands every protocol call to aiohttp's handler and calls ``release`` once when the
    connection ends (the per-address count)."""

    __slots__ = ("inner", "_release")

    def __init__(self, inner: asyncio.Protocol, release):
        self.inner = inner
        self._release = release

    def connection_made(self, transport) -> None:
        self.inner.connection_made(transport)

    def data_received(self, data: bytes) -> None:
        self.inner.data_received(data)

    def eof_received(self) -> bool | None:
        return self.inner.eof_received()

    def pause_writing(self) -> None:
        self.inner.pause_writing()

    def resume_writing(self) -> None:
        self.inner.resume_writing()

    def connection_lost(self, exc: BaseException | None) -> None:
        release, self._release = self._release, None
        if release is not None:
            release()
        self.inner.connection_lost(exc)


class GuardedSite(web.BaseSite):
    """A TCP listening site for an ``aiohttp.web.AppRunner`` (in place of ``web.TCPSite``).

    Parameters
    ----------
    host, port : str, int
        Where to listen (``""``: every interface).
    max_connections_per_address : int
        Open connections one client address may hold.
    reuse_port : bool
        ``SO_REUSEPORT``: several processes may listen on the same port.
    ssl_context : ssl.SSLContext, optional
        Serve TLS (HTTPS and WSS) with it (:func:`server.tls.server_context`).
    log_interval_s : float
        The least time between two log lines of one kind (out of descriptors; one address
        over its limit).
    """

    __slots__ = ("_host", "_port", "_reuse_port", "_max_per_address", "_sock", "_open",
                 "_backoff_s", "_resume", "_warnings", "refused", "pauses", "_tasks")

    MIN_BACKOFF_S = 0.05
    MAX_BACKOFF_S = 2.0

    def __init__(self, runner: web.BaseRunner, host: str, port: int, *,
                 max_connections_per_address: int = 256, backlog: int = 128,
                 reuse_port: bool = False, log_interval_s: float = 10.0,
                 ssl_context: ssl.SSLContext | None = None):
        super().__init__(runner, backlog=backlog, ssl_context=ssl_context)
        self._host = host
        self._port = port
        self._reuse_port = reuse_port
        self._max_per_address = max_connections_per_address
        self._sock: socket.socket | None = None
        self._open: dict[str, int] = {}  # client address -> open connections
        self._backoff_s = self.MIN_BACKOFF_S
        self._resume: asyncio.TimerHandle | None = None
        self._warnings = ThrottledWarnings(log, log_interval_s)
        self._tasks: set[asyncio.Task] = set()
        self.refused = 0  # connections closed for the per-address limit
        self.pauses = 0  # times accepting paused for want of file descriptors

    @property
    def name(self) -> str:
        scheme = "https" if self._ssl_context is not None else "http"
        return f"{scheme}://{self._host or '0.0.0.0'}:{self._port}"

    @property
    def open_connections(self) -> int:
        return sum(self._open.values())

    async def start(self) -> None:
        await super().start()
        loop = asyncio.get_running_loop()
        infos = await loop.getaddrinfo(self._host or None, self._port, type=socket.SOCK_STREAM,
                                       flags=socket.AI_PASSIVE)
        family, kind, proto, _, address = infos[0]
        sock = socket.socket(family, kind, proto)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if self._reuse_port:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
            sock.bind(address)
            sock.listen(self._backlog)
            sock.setblocking(False)
        except OSError:
            sock.close()
            raise
        self._sock = sock
        loop.add_reader(sock.fileno(), self._accept)

    async def stop(self) -> None:
        if self._resume is not None:
            self._resume.cancel()
        if self._sock is not None:
            asyncio.get_running_loop().remove_reader(self._sock.fileno())
            self._sock.close()
            self._sock = None
        await super().stop()

    # ------------------------------------------------------------------------- accepting

    def _accept(self) -> None:
        for _ in range(ACCEPTS_PER_WAKE):
            if self._sock is None:
                return
            try:
                conn, address = self._sock.accept()
            except (BlockingIOError, InterruptedError):
                return
            except ConnectionAbortedError:
                continue
            except OSError as exc:
                if exc.errno in OUT_OF_RESOURCES:
                    self._pause(exc)
                else:
                    log.warning("accepting a connection failed: %s", exc)
                return
            self._backoff_s = self.MIN_BACKOFF_S
            self._admit(conn, address)

    def _pause(self, exc: OSError) -> None:
        loop = asyncio.get_running_loop()
        loop.remove_reader(self._sock.fileno())
        self.pauses += 1
        self._warnings.warn(
            "fds", f"cannot accept connections, out of file descriptors ({exc.strerror}; "
            f"{self.open_connections} connections open; raise `ulimit -n` or lower "
            f"max_clients): accepting again in {self._backoff_s:.2f} s, and at most every "
            f"{self.MAX_BACKOFF_S:.0f} s while it lasts")
        self._resume = loop.call_later(self._backoff_s, self._resume_accepting)
        self._backoff_s = min(2.0 * self._backoff_s, self.MAX_BACKOFF_S)

    def _resume_accepting(self) -> None:
        self._resume = None
        if self._sock is not None:
            asyncio.get_running_loop().add_reader(self._sock.fileno(), self._accept)

    def _admit(self, conn: socket.socket, address) -> None:
        ip = str(address[0]) if isinstance(address, tuple) else str(address)
        held = self._open.get(ip, 0)
        if held >= self._max_per_address:
            self.refused += 1
            conn.close()
            self._warnings.warn(
                f"address {ip}", f"refused a connection from {ip}: {held} open from that "
                "address already (max_connections_per_address)")
            return
        conn.setblocking(False)
        self._open[ip] = held + 1
        server = self._runner.server
        assert server is not None
        protocol = _Counted(server(), lambda: self._release(ip))
        task = asyncio.get_running_loop().create_task(self._connect(conn, protocol))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _connect(self, conn: socket.socket, protocol: _Counted) -> None:
        try:
            await asyncio.get_running_loop().connect_accepted_socket(
                lambda: protocol, conn, ssl=self._ssl_context)
        except OSError as exc:  # the client left before its transport was made
            log.debug("connection lost while accepting: %s", exc)
            conn.close()
            protocol.connection_lost(exc)

    def _release(self, ip: str) -> None:
        left = self._open.get(ip, 0) - 1
        if left > 0:
            self._open[ip] = left
        else:
            self._open.pop(ip, None)


class RefusedRequestLog(logging.Filter):
    """aiohttp logs every request it refuses (a URL or header over its size limit, a malformed
    request line) at ERROR with a traceback, "Error handling request from ADDRESS". These are
    the client's fault, not the server's: this filter turns them into one WARNING line,
    "refused a request from ADDRESS: HTTP 400 ...". Errors of the server's own handlers are
    left as they are."""

    def filter(self, record: logging.LogRecord) -> bool:
        exc = record.exc_info[1] if record.exc_info else None
        if isinstance(exc, HttpProcessingError) and record.levelno >= logging.WARNING:
            remote = record.args[0] if isinstance(record.args, tuple) and record.args else "?"
            record.msg = "refused a request from %s: HTTP %s %s"
            record.args = (remote, exc.code, str(exc.message)[:200])
            record.levelno = logging.WARNING
            record.levelname = logging.getLevelName(logging.WARNING)
            record.exc_info = None
            record.exc_text = None
        return True


def install_refused_request_log() -> None:
    """Add :class:`RefusedRequestLog` to aiohttp's server logger (once)."""
    logger = logging.getLogger("aiohttp.server")
    if not any(isinstance(f, RefusedRequestLog) for f in logger.filters):
        logger.addFilter(RefusedRequestLog())
