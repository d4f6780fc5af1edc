"""Broadcasting the light vector (and kiosk camera frames) to every WebSocket client.

The hub keeps only the newest encoded message of each stream. Each client has its own sender
task that wakes when something new is published and sends the newest message at that moment;
while a client's connection is slow, newer messages simply replace older ones, so nothing queues
up and no client waits for another. Publishing is a plain function call that never waits.

A site-camera frame and its occlusion mask are published together as one *frame bundle*: a
client subscribed to both streams gets the SITE_CAMERA message and then, next on the wire, the
OCCLUSION_MASK message of the same frame (same capture time), never a mask of another frame.

Every message is encoded once per protocol version (:data:`server.protocol.VERSIONS`) when it
is published, and each client is sent its connection's version: ``?protocol=3`` gets version 3
(the sun apart, the sky in float16), ``?protocol=2`` version 2 (the sun apart, float32), no
parameter or ``protocol=1`` version 1 (the sun folded into its patch by the publisher), any
other value HTTP 400. A light vector's WebSocket frame is built once per version too
(:mod:`server.wsframe`) and written straight to the transport of every client that is idle (its
sender task waiting, nothing in its write buffer beyond the low-water mark): no task wakes for
it. A client that is busy or slow is woken instead and its task sends the newest message through
aiohttp (``send_bytes``), so ordering and the slow-client rules stay as they were.

Per connection (``GET /ws/light``):
- the Origin must be the page's own or in ``allowed_origins`` (else HTTP 403);
- the ``site-camera`` and ``occlusion`` streams go only to an operator's connection (the kiosk
  URL's ``?token=``, :mod:`server.access`); others get the light alone (their hello's
  ``streams`` says so);
- beyond ``max_clients`` the connection is accepted and closed at once with 1013;
- the first message is the JSON hello, then binary messages (:mod:`server.protocol`);
- the client may send small JSON messages (subscribe, ping); anything else closes that client
  alone: 1003 for binary data, 1008 for text outside the protocol or too many messages,
  1009 for a message over the size limit;
- a client whose connection has accepted nothing for ``slow_client_timeout_s`` is dropped,
  and one that does not answer the WebSocket ping (every ``heartbeat_s``) within half of it
  too; both are logged;
- when the server stops, :meth:`LightHub.close_all` closes every client with 1001 and aborts
  the connections that do not take the close frame within ``CLOSE_CLIENTS_S``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from urllib.parse import urlsplit

from aiohttp import WSCloseCode, WSMsgType, web

from server import protocol
from server.access import OPERATOR, PRIVATE_STREAMS
from server.protocol import MessageType, ProtocolError
from server.wsframe import binary_frame

log = logging.getLogger("daylit.stream")

LIGHT = "light"
SITE_CAMERA = "site-camera"
OCCLUSION = "occlusion"
FRAME_STREAMS = (SITE_CAMERA, OCCLUSION)  # the parts of a frame bundle, in wire order
FRAME = "frame"  # a frame bundle, to LightHub.listeners
CLOSE_CLIENTS_S = 2.0  # at shutdown, the longest wait for clients to take the 1001 close


@dataclass(eq=False)  # identity: each connection is its own client
class Client:
    """One connected viewer."""

    ws: web.WebSocketResponse
    remote: str
    streams: set[str]
    version: int = 1  # the connection's protocol version
    operator: bool = False  # may receive the private streams (server.access)
    transport: asyncio.BaseTransport | None = None
    wake: asyncio.Event = field(default_factory=asyncio.Event)
    # The hub's LIGHT entry last sent, by identity: the same vector re-published marked STALE
    # (by a fan-out worker that lost its link) is a new entry with the same sequence number.
    sent_light: tuple[int, dict[int, bytes]] | None = None
    sent_frame: int | None = None  # the last frame bundle sent
    connected_at_s: float = field(default_factory=time.time)
    tokens: float = 0.0
    token_time_s: float = field(default_factory=time.monotonic)
    messages_sent: int = 0
    skipped: int = 0  # newer messages that replaced older ones while the client was slow
    # The sender task is waiting for something new (not in the middle of a send): a new light
    # vector may be written for it straight away (LightHub._write_light).
    idle: bool = False


def _flowing(transport) -> bool:
    """Whether a write to ``transport`` goes out without waiting: its buffer is at or below the
    low-water mark. False for no transport or one without write-buffer limits."""
    try:
        return transport.get_write_buffer_size() <= transport.get_write_buffer_limits()[0]
    except (AttributeError, NotImplementedError):
        return False


class LightHub:
    """The newest message of each stream and the clients that receive them.

    Parameters
    ----------
    hello : callable
        ``hello(streams, version) -> str``: the JSON hello for a client with those streams
        and that protocol version.
    max_clients : int
    allowed_origins : list of str
        Extra allowed ``Origin`` values, or ``["*"]``.
    slow_client_timeout_s : float
    client_max_messages_per_s : float
    heartbeat_s : float
        WebSocket ping period; a client that does not answer within half of it is dropped.
    """

    def __init__(
        self,
        hello: Callable[[list[str]], str],
        max_clients: int = 1000,
        allowed_origins: list[str] | None = None,
        slow_client_timeout_s: float = 30.0,
        client_max_messages_per_s: float = 10.0,
        site_camera_available: bool = False,
        occlusion_available: bool = False,
        heartbeat_s: float = 30.0,
    ):
        self.hello = hello
        self.max_clients = max_clients
        self.allowed_origins = {o.rstrip("/") for o in (allowed_origins or [])}
        self.slow_client_timeout_s = slow_client_timeout_s
        self.client_rate = client_max_messages_per_s
        self.heartbeat_s = heartbeat_s
        self.closing = False  # the server is stopping: new clients are closed with 1001
        self._all_closed = asyncio.Event()  # close_all is done
        self.dropped_heartbeat = 0
        self.dropped_slow = 0
        self.written_direct = 0  # light messages written without waking a sender task
        self.site_camera_available = site_camera_available
        self.occlusion_available = occlusion_available and site_camera_available
        self.clients: set[Client] = set()
        # The newest message of each stream: (sequence, {protocol version: message}).
        self.latest: dict[str, tuple[int, dict[int, bytes]]] = {}
        # The newest site-camera frame: (bundle number, {version: {stream: message}}), see
        # publish_frame.
        self.latest_frame: tuple[int, dict[int, dict[str, bytes]]] | None = None
        self.frames_published = 0
        self.sequence: dict[str, int] = {LIGHT: 0, SITE_CAMERA: 0, OCCLUSION: 0}
        self.refused = 0
        self.closed_for_protocol = 0
        # Called with (stream, sequence or bundle number, encoded data) after each publication
        # (the measuring process forwards them to fan-out workers: server.relay).
        self.listeners: list[Callable[[str, int, object], None]] = []

    # --------------------------------------------------------------------------- publishing

    def publish(self, stream: str, data: dict[int, bytes] | bytes, sequence: int) -> None:
        """Make ``data`` ({protocol version: message}, or one message for every version) the
        newest message of ``stream`` (``light``) and wake its subscribers.

        Site-camera frames and masks go through :meth:`publish_frame` instead.
        """
        if isinstance(data, bytes | bytearray):
            data = dict.fromkeys(protocol.VERSIONS, bytes(data))
        entry = self.latest[stream] = (sequence, data)
        self.sequence[stream] = sequence
        frames = {version: binary_frame(message) for version, message in data.items()} \
            if stream == LIGHT else None
        for client in self.clients:
            if stream in client.streams and (
                    frames is None or not self._write_light(client, entry, frames)):
                client.wake.set()
        for listener in self.listeners:
            listener(stream, sequence, data)

    def publish_light(self, rgb, saturated, capture_time_s: float, flags: int,
                      sun: object = None, folded_rgb=None) -> int:
        """Encode and publish a light vector; returns its sequence number.

        ``rgb`` (n, 3): the sky without the sun's disc, sent to version-2 and version-3 clients
        with ``sun`` (see :func:`server.protocol.encode_light`); ``folded_rgb`` (n, 3): the
        vector for version-1 clients, with the sun in its patch
        (:func:`server.protocol.fold_sun`; default ``rgb``).
        """
        seq = self.sequence[LIGHT] = (self.sequence[LIGHT] + 1) & 0xFFFFFFFF
        v1 = rgb if folded_rgb is None else folded_rgb
        data = {
            1: protocol.encode_light(v1, saturated, seq, capture_time_s, flags, version=1),
            **{version: protocol.encode_light(rgb, saturated, seq, capture_time_s, flags,
                                              version=version, sun=sun)
               for version in protocol.VERSIONS if version >= 2},
        }
        self.publish(LIGHT, data, seq)
        return seq

    def publish_frame(
        self,
        jpeg: bytes,
        capture_time_s: float,
        flags: int = 0,
        mask_payload: bytes | None = None,
        mask_flags: int = 0,
    ) -> int:
        """Publish one site-camera frame and, when given, its occlusion mask, as one bundle.

        ``mask_payload`` is :func:`server.occlusion.codec.encode_mask`'s output; its message
        carries the frame's capture time. Returns the SITE_CAMERA sequence number.
        """
        seq = self.sequence[SITE_CAMERA] = (self.sequence[SITE_CAMERA] + 1) & 0xFFFFFFFF
        if mask_payload is not None:
            mseq = self.sequence[OCCLUSION] = (self.sequence[OCCLUSION] + 1) & 0xFFFFFFFF
        by_version = {}
        for version in protocol.VERSIONS:  # the same but for the version byte
            parts = {SITE_CAMERA: protocol.encode_blob(MessageType.SITE_CAMERA, jpeg, seq,
                                                       capture_time_s, flags, version)}
            if mask_payload is not None:
                parts[OCCLUSION] = protocol.encode_blob(MessageType.OCCLUSION_MASK,
                                                        mask_payload, mseq, capture_time_s,
                                                        mask_flags, version)
            by_version[version] = parts
        self.publish_bundle(self.frames_published + 1, by_version)
        return seq

    def publish_bundle(self, number: int, by_version: dict[int, dict[str, bytes]]) -> None:
        """Make an encoded frame bundle ({version: {stream: message}}, see
        :meth:`publish_frame`) the newest, as number ``number``, and wake its subscribers (a
        fan-out worker publishes what the measuring process encoded)."""
        self.frames_published = number
        self.latest_frame = (number, by_version)
        streams = set().union(*by_version.values()) if by_version else set()
        for client in self.clients:
            if not client.streams.isdisjoint(streams):
                client.wake.set()
        for listener in self.listeners:
            listener(FRAME, number, by_version)

    # ----------------------------------------------------------------------------- clients

    def origin_allowed(self, request: web.Request) -> bool:
        origin = request.headers.get("Origin")
        if origin is None or "*" in self.allowed_origins:
            return True  # non-browser clients send none
        if origin.rstrip("/") in self.allowed_origins:
            return True
        try:
            authority = urlsplit(origin).netloc
        except ValueError:
            return False
        # Same origin: the page was served by this server under the same host and port.
        return bool(authority) and authority.lower() == request.host.lower()

    async def handle(self, request: web.Request) -> web.StreamResponse:
        """The ``GET /ws/light`` handler."""
        remote = request.remote or "?"
        if not self.origin_allowed(request):
            log.warning("refused light stream from %s: origin %s not allowed", remote,
                        request.headers.get("Origin"))
            raise web.HTTPForbidden(text="origin not allowed\n")
        try:
            streams = protocol.parse_streams(request.query.get("streams"))
            version = protocol.parse_protocol(request.query.get("protocol"))
        except ProtocolError as exc:
            raise web.HTTPBadRequest(text=f"{exc}\n") from None
        ws = web.WebSocketResponse(
            # aiohttp refuses a message of max_msg_size bytes or more; the protocol allows
            # MAX_CLIENT_MESSAGE_BYTES (parse_client_message checks it exactly).
            max_msg_size=protocol.MAX_CLIENT_MESSAGE_BYTES + 1,
            compress=False,  # float vectors and JPEG do not deflate; spare the CPU
            heartbeat=self.heartbeat_s,
        )
        await ws.prepare(request)
        if self.closing:
            await ws.close(code=WSCloseCode.GOING_AWAY, message=b"server shutting down")
            return ws
        if len(self.clients) >= self.max_clients:
            self.refused += 1
            log.warning("refused light stream from %s: %d clients already (max_clients)",
                        remote, len(self.clients))
            await ws.close(code=WSCloseCode.TRY_AGAIN_LATER, message=b"server full")
            return ws
        client = Client(ws, remote, set(streams), version, request.get(OPERATOR, False),
                        request.transport, tokens=5.0 * self.client_rate)
        if not client.operator and not client.streams.isdisjoint(PRIVATE_STREAMS):
            log.warning("light stream of %s: %s withheld (no operator token)", remote,
                        ", ".join(sorted(client.streams & PRIVATE_STREAMS)))
        self._filter_streams(client)
        await ws.send_str(self.hello(sorted(client.streams), version))
        self.clients.add(client)
        client.wake.set()  # send the newest vector right away
        sender = asyncio.create_task(self._send_loop(client), name=f"send {remote}")
        try:
            await self._read_loop(client)
            if self.closing:
                # close_all's close is waiting for the client's close frame: returning now
                # would close the connection before it comes (the client would see 1006).
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self._all_closed.wait(), CLOSE_CLIENTS_S + 1.0)
        finally:
            self.clients.discard(client)
            sender.cancel()
            # aiohttp's "No PONG received": it closes the connection, which cancels this
            # handler, so this is said here.
            if isinstance(ws.exception(), TimeoutError):
                self.dropped_heartbeat += 1
                log.warning("dropped light stream of %s: no answer to the heartbeat ping "
                            "within %.1f s", remote, self.heartbeat_s / 2)
            with contextlib.suppress(asyncio.CancelledError):
                await sender
        return ws

    def _filter_streams(self, client: Client) -> None:
        if not client.operator:
            client.streams -= PRIVATE_STREAMS
        if not self.site_camera_available:
            client.streams.discard(SITE_CAMERA)
        if not self.occlusion_available:
            client.streams.discard(OCCLUSION)

    async def _close(self, client: Client, code: int, reason: str) -> None:
        self.closed_for_protocol += 1
        log.warning("closing light stream of %s: %s (%d)", client.remote, reason, code)
        with contextlib.suppress(Exception):
            await asyncio.wait_for(
                client.ws.close(code=code, message=reason.encode()[:120]), timeout=5.0
            )

    async def _read_loop(self, client: Client) -> None:
        ws = client.ws
        async for msg in ws:
            if msg.type == WSMsgType.BINARY:
                await self._close(client, WSCloseCode.UNSUPPORTED_DATA,
                                  "binary messages are not part of the protocol")
                return
            if msg.type != WSMsgType.TEXT:
                return  # errors (e.g. 1009 too big) are answered and closed by aiohttp
            if not self._take_token(client):
                await self._close(client, WSCloseCode.POLICY_VIOLATION, "too many messages")
                return
            try:
                request = protocol.parse_client_message(msg.data)
            except ProtocolError as exc:
                await self._close(client, WSCloseCode.POLICY_VIOLATION, str(exc))
                return
            if request.type == "subscribe":
                client.streams = set(request.streams)
                self._filter_streams(client)
                client.wake.set()
            elif request.type == "ping":
                pong = {"type": "pong", "id": request.id, "server_time_s": time.time()}
                await ws.send_json(pong)

    def _take_token(self, client: Client) -> bool:
        """Token bucket: ``client_rate`` per second, bursts up to five seconds' worth."""
        now = time.monotonic()
        capacity = 5.0 * self.client_rate
        client.tokens = min(capacity, client.tokens + (now - client.token_time_s) *
                            self.client_rate)
        client.token_time_s = now
        if client.tokens < 1.0:
            return False
        client.tokens -= 1.0
        return True

    def _write_light(self, client: Client, entry: tuple[int, dict[int, bytes]],
                     frames: dict[int, bytes]) -> bool:
        """Write a light vector's pre-built frame to an idle client's transport; False (its
        sender task must send it) when the client is busy, closing or its buffer is filling.

        Its sender task is waiting and has sent everything before, so the frame goes out in
        order; ``transport.write`` takes it whole or buffers it."""
        transport = client.transport
        if not client.idle or transport is None or client.ws.closed or transport.is_closing():
            return False
        if not _flowing(transport):
            return False
        transport.write(frames[client.version])
        self.written_direct += 1
        client.sent_light = entry
        client.messages_sent += 1
        return True

    async def _send(self, client: Client, message: bytes) -> None:
        """Send one message; past ``slow_client_timeout_s`` of waiting, TimeoutError.

        ``send_bytes`` waits only while the connection's write buffer is paused (above its
        high-water mark until it drains to the low one): below the low mark it returns at
        once, so it is awaited bare; ``asyncio.wait_for`` starts a task of its own each call,
        which cost more than the send itself (docs/benchmarks.md)."""
        if _flowing(client.transport):
            await client.ws.send_bytes(message)
        else:
            await asyncio.wait_for(client.ws.send_bytes(message), self.slow_client_timeout_s)

    async def _send_loop(self, client: Client) -> None:
        ws = client.ws
        try:
            while not ws.closed:
                client.idle = True
                await client.wake.wait()
                client.idle = False
                client.wake.clear()
                entry = self.latest.get(LIGHT) if LIGHT in client.streams else None
                if entry is not None and entry is not client.sent_light:
                    seq, by_version = entry
                    if client.sent_light is not None:
                        client.skipped += max(
                            0, ((seq - client.sent_light[0]) & 0xFFFFFFFF) - 1)
                    await self._send(client, by_version[client.version])
                    client.sent_light = entry
                    client.messages_sent += 1
                frame = self.latest_frame
                if (frame is not None and frame[0] != client.sent_frame
                        and not client.streams.isdisjoint(FRAME_STREAMS)):
                    number, by_version = frame  # held: a newer bundle cannot split this one
                    parts = by_version[client.version]
                    if client.sent_frame is not None:
                        client.skipped += max(0, number - client.sent_frame - 1)
                    for stream in FRAME_STREAMS:
                        if stream in client.streams and stream in parts:
                            await self._send(client, parts[stream])
                            client.messages_sent += 1
                    client.sent_frame = number
        except TimeoutError:
            self.dropped_slow += 1
            log.warning("dropping light stream of %s: nothing accepted for %.0f s",
                        client.remote, self.slow_client_timeout_s)
            if client.transport is not None:
                client.transport.abort()  # a close frame could not get through either
        except (ConnectionError, RuntimeError):
            pass  # the client went away; the read loop ends the connection

    async def close_all(self, timeout_s: float = CLOSE_CLIENTS_S) -> None:
        """Close every client with 1001 (server shutting down), and refuse new ones so.

        Waits at most ``timeout_s`` for the clients' closing handshakes; connections still
        open then (a client that never reads) are aborted.
        """
        self.closing = True

        async def close(client: Client) -> None:
            with contextlib.suppress(TimeoutError, ConnectionError, RuntimeError):
                await asyncio.wait_for(client.ws.close(code=WSCloseCode.GOING_AWAY,
                                                       message=b"server shutting down"),
                                       timeout_s)
            if not client.ws.closed and client.transport is not None:
                client.transport.abort()

        clients = list(self.clients)
        if clients:
            log.info("closing %d light streams (1001, server shutting down)", len(clients))
        await asyncio.gather(*(close(c) for c in clients), return_exceptions=True)
        self._all_closed.set()

    def status(self) -> dict:
        return {
            "clients": len(self.clients),
            "clients_protocol_1": sum(c.version == 1 for c in self.clients),
            "clients_site_camera": sum(SITE_CAMERA in c.streams for c in self.clients),
            "clients_occlusion": sum(OCCLUSION in c.streams for c in self.clients),
            "clients_refused": self.refused,
            "clients_closed_for_protocol": self.closed_for_protocol,
            "clients_dropped_heartbeat": self.dropped_heartbeat,
            "clients_dropped_slow": self.dropped_slow,
        }
