"""The light-stream clients of ``bench_stream.py``: aiohttp's, or picows' on uvloop.

Both libraries hand every complete binary message to the same :class:`Receipts`, whose
:meth:`Receipts.receive` takes the receipt time (``time.time()``) as its first statement, so
the two client kinds differ only in the work done before a message reaches Python: aiohttp
parses frames in its reader and wakes one ``async for`` task per connection per message;
picows (Cython) parses them in the transport's ``data_received`` and calls ``on_ws_frame``
directly, with no task per connection (docs/benchmarks.md, "Fast clients").

Used by ``bench_stream.py --client-lib {aiohttp,picows}`` and by
``tests/server/test_bench_clients.py`` (both kinds on the same server get the same sequence
numbers).
"""

from __future__ import annotations

import asyncio
import struct
import time

HEADER = struct.Struct("<4sBBHIId")  # server.protocol.HEADER: magic, version, type, flags,
# sequence, count, capture time (s since the epoch)
LIGHT = 1  # server.protocol.MessageType.LIGHT
CONNECT_BATCH = 100  # connections opened at once (the server's accept backlog is finite)
CLIENT_LIBS = ("aiohttp", "picows")


class Receipts:
    """What ``clients`` connections received while ``measuring`` is True.

    ``latencies_s[k]``: client k's capture-to-receipt latency of each LIGHT message (s);
    ``sequences[k]`` (only with ``keep_sequences``): their sequence numbers; ``sizes``: the
    message sizes seen (bytes).
    """

    def __init__(self, clients: int, keep_sequences: bool = False):
        self.measuring = False
        self.latencies_s: list[list[float]] = [[] for _ in range(clients)]
        self.sequences: list[list[int]] | None = \
            [[] for _ in range(clients)] if keep_sequences else None
        self.sizes: set[int] = set()

    def receive(self, k: int, data) -> None:
        """Client ``k`` got the binary message ``data`` (bytes or memoryview)."""
        now_s = time.time()  # first: the same receipt instant for both client kinds
        if not self.measuring:
            return
        _, _, mtype, _, sequence, _, captured_s = HEADER.unpack_from(data)
        if mtype == LIGHT:
            self.latencies_s[k].append(now_s - captured_s)
            self.sizes.add(len(data))
            if self.sequences is not None:
                self.sequences[k].append(sequence)


class AiohttpClients:
    """``clients`` light streams through one aiohttp session, a listening task each."""

    def __init__(self, url: str, receipts: Receipts):
        self.url = url
        self.receipts = receipts
        self.session = None
        self.sockets: list = []
        self.tasks: list[asyncio.Task] = []

    async def open(self, clients: int) -> None:
        import aiohttp

        async def listen(ws, k):
            async for msg in ws:
                if msg.type == aiohttp.WSMsgType.BINARY:
                    self.receipts.receive(k, msg.data)

        self.session = aiohttp.ClientSession(connector=aiohttp.TCPConnector(limit=0))
        for start in range(0, clients, CONNECT_BATCH):
            batch = range(start, min(start + CONNECT_BATCH, clients))
            self.sockets += await asyncio.gather(*(self.session.ws_connect(self.url)
                                                   for _ in batch))
        self.tasks = [asyncio.create_task(listen(ws, k)) for k, ws in enumerate(self.sockets)]

    async def close(self) -> None:
        await asyncio.gather(*(ws.close() for ws in self.sockets), return_exceptions=True)
        for task in self.tasks:
            task.cancel()
        await asyncio.gather(*self.tasks, return_exceptions=True)
        if self.session is not None:
            await self.session.close()


class PicowsClients:
    """``clients`` light streams through picows: one listener object each, no tasks.

    A listener's ``on_ws_frame`` is called from the connection's ``data_received`` for each
    frame parsed; the server sends every message as one unfragmented frame
    (``server/wsframe.py``), and a fragmented one would be counted in ``fragments``.
    """

    def __init__(self, url: str, receipts: Receipts):
        self.url = "ws" + url.removeprefix("http")  # picows takes ws:// (wss://) alone
        self.receipts = receipts
        self.transports: list = []
        self.fragments = 0

    async def open(self, clients: int) -> None:
        from picows import WSListener, WSMsgType, ws_connect

        receipts, owner = self.receipts, self

        class Listener(WSListener):
            def __init__(self, k: int):
                self.k = k

            def on_ws_frame(self, transport, frame):
                if frame.msg_type == WSMsgType.BINARY:
                    if frame.fin:
                        receipts.receive(self.k, frame.get_payload_as_memoryview())
                    else:
                        owner.fragments += 1
                elif frame.msg_type == WSMsgType.CLOSE:
                    transport.send_close(frame.get_close_code())
                    transport.disconnect()

        async def connect(k: int):
            transport, _ = await ws_connect(lambda: Listener(k), self.url,
                                            websocket_handshake_timeout=60)
            return transport

        for start in range(0, clients, CONNECT_BATCH):
            batch = range(start, min(start + CONNECT_BATCH, clients))
            self.transports += await asyncio.gather(*(connect(k) for k in batch))

    async def close(self) -> None:
        for transport in self.transports:
            transport.send_close()
        await asyncio.gather(*(asyncio.wait_for(t.wait_disconnected(), 10)
                               for t in self.transports), return_exceptions=True)
        for transport in self.transports:
            transport.disconnect()


def make_clients(lib: str, url: str, receipts: Receipts):
    """An unopened client set of library ``lib`` (one of :data:`CLIENT_LIBS`)."""
    if lib == "aiohttp":
        return AiohttpClients(url, receipts)
    if lib == "picows":
        return PicowsClients(url, receipts)
    raise ValueError(f"client library {lib!r} is not one of {CLIENT_LIBS}")


def run_loop(lib: str, main):
    """``asyncio.run(main)``, on uvloop for picows (its fast path; aiohttp on asyncio's own
    loop, as the earlier runs)."""
    if lib == "picows":
        import uvloop

        return uvloop.run(main)
    return asyncio.run(main)
