"""The one-machine feed from the measuring process to its fan-out workers: a Unix socket.

``daylit serve --workers N`` without a broker: the measuring process listens on a Unix socket
(``local:PATH``) and writes every relay message (:mod:`server.relay`) to each connected
worker, prefixed with its length (u32 little-endian). A worker that connects is sent the newest
message of each kind at once. Writing never waits: a worker whose socket has taken nothing
while :data:`MAX_BUFFER_BYTES` piled up is disconnected (it reconnects and gets the newest).

Why not Redis here: the workers are the measuring process's own children, the kernel carries
the bytes, and there is nothing to install, run or monitor besides ``daylit serve``; a
Unix socket (unlike a ``multiprocessing`` pipe) lets a worker that restarts connect again.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import struct
from pathlib import Path

from server.backoff import Backoff
from server.relay import KINDS, MAX_MESSAGE_BYTES, Inbox, Outbox
from server.throttledlog import ThrottledWarnings

log = logging.getLogger("daylit.relay")

MAX_BUFFER_BYTES = 16 << 20
PREFIX = struct.Struct("<I")
RECONNECT_S = (0.05, 2.0)  # the worker's reconnection back-off: first and longest wait


class FeedError(RuntimeError):
    """The local feed cannot be opened or reached."""


def socket_path(url: str) -> Path:
    """``local:PATH`` -> PATH."""
    return Path(url.removeprefix("local:"))


class LocalFeedPublisher:
    """The measuring side: a Unix socket server fed by an :class:`server.relay.Outbox`."""

    def __init__(self, url: str, outbox: Outbox):
        self.path = socket_path(url)
        self.outbox = outbox
        self.writers: set[asyncio.StreamWriter] = set()
        self.dropped = 0
        self._server: asyncio.base_events.Server | None = None
        outbox.listeners.append(self._send_all)

    async def start(self) -> None:
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()
        try:
            self._server = await asyncio.start_unix_server(self._serve, str(self.path))
        except OSError as exc:
            raise FeedError(f"cannot open the workers' feed {self.path}: {exc.strerror}") from None
        os.chmod(self.path, 0o600)

    async def run(self) -> None:
        await asyncio.Event().wait()  # the server runs on its own; this task holds it

    async def close(self) -> None:
        if self._server is not None:
            self._server.close()
        for writer in list(self.writers):
            writer.close()
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()

    def status(self) -> dict:
        return {"feed": f"local:{self.path}", "workers_connected": len(self.writers),
                "workers_dropped": self.dropped}

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.writers.add(writer)
        for kind in KINDS:
            if kind in self.outbox.latest:
                self._send(writer, self.outbox.latest[kind])
        try:
            await reader.read()  # workers send nothing; EOF when one goes away
        except ConnectionError:
            pass
        finally:
            self.writers.discard(writer)
            writer.close()

    def _send_all(self, kind: str, message: bytes) -> None:
        for writer in list(self.writers):
            self._send(writer, message)

    def _send(self, writer: asyncio.StreamWriter, message: bytes) -> None:
        if writer.transport.is_closing():
            return
        if writer.transport.get_write_buffer_size() > MAX_BUFFER_BYTES:
            self.dropped += 1
            log.warning("a fan-out worker took nothing while %d MB waited for it: "
                        "disconnected (it reconnects)", MAX_BUFFER_BYTES >> 20)
            self.writers.discard(writer)
            writer.transport.abort()
            return
        writer.write(PREFIX.pack(len(message)) + message)


class LocalFeedSubscriber:
    """The worker side: reads the measuring process's Unix socket into an
    :class:`server.relay.Inbox`, reconnecting (:data:`RECONNECT_S`) when it goes away."""

    def __init__(self, url: str):
        self.url = url
        self.path = socket_path(url)
        self._warnings = ThrottledWarnings(log, 10.0)

    async def check(self, timeout_s: float = 10.0) -> None:
        """Wait for the feed's socket to accept; :class:`FeedError` if it does not in time."""
        loop = asyncio.get_running_loop()
        end = loop.time() + timeout_s
        while True:
            try:
                _, writer = await asyncio.open_unix_connection(str(self.path))
                writer.close()
                return
            except OSError as exc:
                if loop.time() > end:
                    raise FeedError(f"cannot reach the measuring process's feed {self.path}: "
                                    f"{exc.strerror}; start the measuring process first "
                                    "(daylit serve BUILD --workers N starts both)") from None
                await asyncio.sleep(0.1)

    async def run(self, inbox: Inbox) -> None:
        backoff = Backoff(*RECONNECT_S)
        while True:
            try:
                reader, writer = await asyncio.open_unix_connection(str(self.path))
            except OSError as exc:
                inbox.last_error = f"feed {self.path}: {exc.strerror}"
                self._warnings.warn("connect", f"cannot reach the measuring process's feed "
                                    f"{self.path}: {exc.strerror}; retrying")
                await backoff.wait()
                continue
            inbox.connected = True
            inbox.connects += 1
            backoff.reset()
            try:
                while True:
                    size = PREFIX.unpack(await reader.readexactly(PREFIX.size))[0]
                    if size > MAX_MESSAGE_BYTES:
                        raise ConnectionError(f"a message of {size} bytes on the feed")
                    inbox.apply(await reader.readexactly(size))
            except (asyncio.IncompleteReadError, ConnectionError) as exc:
                inbox.last_error = f"feed {self.path}: closed ({exc})"
                self._warnings.warn("lost", f"the measuring process's feed {self.path} "
                                    "closed; reconnecting")
            finally:
                inbox.connected = False
                writer.close()
