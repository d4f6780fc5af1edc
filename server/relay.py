"""What passes from the measuring process to the fan-out workers, and each side's end of it.

The measuring process encodes every light vector and frame bundle once (per protocol version,
:mod:`server.lightstream`); the relay carries those bytes unchanged, with their sequence
numbers, so a fan-out worker never encodes a vector. A relay message is::

    b"DLR1" | u32 little-endian n | n bytes of JSON header | the blobs, one after another

The header is ``{"kind": ..., "seq": int, "blobs": [[name, bytes], ...], ...}``; kinds:

- ``light``: blobs ``"1"``, ``"2"``: the LIGHT message for protocol 1 and 2; ``seq`` its
  sequence number;
- ``frame``: blobs ``"1/site-camera"``, ``"1/occlusion"``, ``"2/site-camera"``, ...: one site-
  camera frame bundle; ``seq`` the bundle's number;
- ``status``: no blobs; ``"status"`` is the measuring process's ``/api/status`` (its source,
  measuring, site camera, occlusion) and ``"hello"`` what a client's hello says of them
  (source, simulated, site camera, occlusion), every :data:`STATUS_PERIOD_S`;
- ``sky``: blob ``"jpeg"``: the newest sky frame, at most 320 px, every
  :data:`SKY_PERIOD_S` while frames come.

:class:`Outbox` (measuring side) keeps the newest message of each kind and tells the
transports (:mod:`server.localfeed`, :mod:`server.broker`); :class:`Inbox` (worker side)
applies what arrives to the worker's hub and keeps the measuring process's status.
"""

from __future__ import annotations

import asyncio
import json
import logging
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass

from server import protocol
from server.lightstream import FRAME, LIGHT, LightHub

log = logging.getLogger("daylit.relay")

MAGIC = b"DLR1"
KINDS = ("status", "light", "frame", "sky")  # the order a new worker is sent them in
MAX_MESSAGE_BYTES = 64 << 20
STATUS_PERIOD_S = 1.0
SKY_PERIOD_S = 2.0
SKY_JPEG_PX = 320


class RelayError(ValueError):
    """A relay message that is not one (wrong magic, lengths, JSON or kind)."""


@dataclass
class Message:
    kind: str
    seq: int
    header: dict
    blobs: dict[str, bytes]


def encode(kind: str, seq: int, blobs: dict[str, bytes] | None = None, **extra) -> bytes:
    """One relay message (module docstring); ``extra`` goes into the JSON header."""
    blobs = blobs or {}
    header = {"kind": kind, "seq": int(seq), "blobs": [[k, len(v)] for k, v in blobs.items()],
              **extra}
    head = json.dumps(header, separators=(",", ":")).encode()
    return b"".join([MAGIC, struct.pack("<I", len(head)), head, *blobs.values()])


def decode(data: bytes) -> Message:
    """The :class:`Message` in ``data``; raises :class:`RelayError` if it is not one."""
    if len(data) < 8 or data[:4] != MAGIC:
        raise RelayError("not a daylit relay message (bad magic)")
    (n,) = struct.unpack_from("<I", data, 4)
    if 8 + n > len(data):
        raise RelayError("relay message shorter than its header")
    try:
        header = json.loads(data[8:8 + n])
        kind, seq, sizes = header["kind"], int(header["seq"]), header["blobs"]
    except (ValueError, KeyError, TypeError) as exc:
        raise RelayError(f"relay message header unreadable: {exc}") from None
    if kind not in KINDS:
        raise RelayError(f"unknown relay message kind {kind!r}")
    blobs, at = {}, 8 + n
    for name, size in sizes:
        if size < 0 or at + size > len(data):
            raise RelayError("relay message shorter than its blobs")
        blobs[str(name)] = bytes(data[at:at + size])
        at += size
    if at != len(data):
        raise RelayError("relay message longer than its blobs")
    return Message(kind, seq, header, blobs)


class Outbox:
    """The measuring side: the newest relay message of each kind.

    Attach it to the hub (:meth:`attach`); every light vector and frame bundle the hub
    publishes becomes a relay message, given to each ``listeners`` callback
    (``callback(kind, message_bytes)``); :meth:`run_status` adds the status and the sky frame.
    """

    def __init__(self):
        self.latest: dict[str, bytes] = {}
        self.listeners: list[Callable[[str, bytes], None]] = []
        self.messages = 0

    def attach(self, hub: LightHub) -> None:
        hub.listeners.append(self._from_hub)

    def _from_hub(self, stream: str, number: int, data) -> None:
        if stream == LIGHT:
            self.put("light", encode("light", number, {str(v): m for v, m in data.items()}))
        elif stream == FRAME:
            blobs = {f"{v}/{s}": m for v, parts in data.items() for s, m in parts.items()}
            self.put("frame", encode("frame", number, blobs))

    def put(self, kind: str, message: bytes) -> None:
        self.latest[kind] = message
        self.messages += 1
        for listener in self.listeners:
            listener(kind, message)

    async def run_status(self, status: Callable[[], dict], hello: Callable[[], dict],
                         sky_jpeg: Callable[[], bytes | None],
                         frame_time: Callable[[], float | None]) -> None:
        """Publish the status every :data:`STATUS_PERIOD_S` and the sky frame (made off the
        event loop) every :data:`SKY_PERIOD_S` when there is a new one."""
        sky_sent_for: float | None = None
        sky_due = 0.0
        while True:
            self.put("status", encode("status", 0, status=status(), hello=hello(),
                                      sent_s=time.time()))
            now = time.monotonic()
            latest = frame_time()
            if latest is not None and latest != sky_sent_for and now >= sky_due:
                jpeg = await asyncio.to_thread(sky_jpeg)
                if jpeg is not None:
                    self.put("sky", encode("sky", 0, {"jpeg": jpeg}))
                sky_sent_for, sky_due = latest, now + SKY_PERIOD_S
            await asyncio.sleep(STATUS_PERIOD_S)


class Inbox:
    """The worker side: applies relay messages to the worker's hub.

    ``stale_after_s``: no message for this long (the status alone comes every second) and the
    worker calls its light stale in ``/api/status``.
    """

    def __init__(self, hub: LightHub, stale_after_s: float):
        self.hub = hub
        self.stale_after_s = stale_after_s
        self.status: dict = {}  # the measuring process's, as last received
        self.hello: dict = {}
        self.sky_jpeg: bytes | None = None
        self.messages = 0
        self.bad_messages = 0
        self.last_message_s: float | None = None  # time.monotonic()
        self.connected = False  # the transport's view: linked to the broker or feed
        self.connects = 0  # links made (the first and each reconnection)
        self.last_error = ""
        self.has_status = asyncio.Event()  # a status (and so the hello's sources) came
        self.marked_stale = False  # the last vector was re-sent STALE since the last one came

    def apply(self, data: bytes) -> None:
        """Apply one relay message; a malformed one is counted and logged, never raised."""
        try:
            m = decode(data)
            if m.kind == "light":
                by_version = {int(v): b for v, b in m.blobs.items()}
                latest = self.hub.latest.get(LIGHT)
                # The same message again (a resubscription's GET of the newest) is not news.
                if latest is None or latest[0] != m.seq or latest[1] != by_version:
                    self.hub.publish(LIGHT, by_version, m.seq)
                self.marked_stale = False
            elif m.kind == "frame":
                by_version: dict[int, dict[str, bytes]] = {}
                for name, blob in m.blobs.items():
                    version, _, stream = name.partition("/")
                    by_version.setdefault(int(version), {})[stream] = blob
                self.hub.publish_bundle(m.seq, by_version)
            elif m.kind == "status":
                self.status = dict(m.header.get("status") or {})
                self.hello = dict(m.header.get("hello") or {})
                self.hub.site_camera_available = bool(self.hello.get("site_camera"))
                self.hub.occlusion_available = (self.hub.site_camera_available
                                                and bool(self.hello.get("occlusion")))
                self.has_status.set()
            elif m.kind == "sky":
                self.sky_jpeg = m.blobs.get("jpeg")
        except (RelayError, ValueError) as exc:
            self.bad_messages += 1
            if self.bad_messages == 1 or self.bad_messages % 1000 == 0:
                log.warning("ignored a malformed relay message (%d so far): %s",
                            self.bad_messages, exc)
            return
        self.messages += 1
        self.last_message_s = time.monotonic()

    def mark_stale_if_lost(self) -> bool:
        """If the link has been silent past ``stale_after_s``, re-publish the last vector with
        the STALE flag (same sequence number), once until a vector comes again, so the
        clients show the light as stale as they would for a camera that stopped. True if it
        did."""
        entry = self.hub.latest.get(LIGHT)
        if self.marked_stale or entry is None or not self.stale:
            return False
        seq, by_version = entry
        self.hub.publish(LIGHT, {v: protocol.with_flags(message, protocol.Flags.STALE)
                                 for v, message in by_version.items()}, seq)
        self.marked_stale = True
        log.warning("nothing from the measuring process for %.1f s (%s): the last vector "
                    "re-sent to the clients marked stale", self.age_s,
                    self.last_error or "no error reported")
        return True

    async def watch_link(self, period_s: float = 0.5) -> None:
        """Run :meth:`mark_stale_if_lost` every ``period_s``."""
        while True:
            await asyncio.sleep(period_s)
            self.mark_stale_if_lost()

    @property
    def age_s(self) -> float | None:
        """Seconds since the last message (None before the first)."""
        return None if self.last_message_s is None else time.monotonic() - self.last_message_s

    @property
    def stale(self) -> bool:
        age = self.age_s
        return age is None or age > self.stale_after_s

    def link_status(self) -> dict:
        age = self.age_s
        return {
            "connected": self.connected,
            "last_message_age_s": None if age is None else round(age, 3),
            "stale": self.stale,
            "messages": self.messages,
            "bad_messages": self.bad_messages,
            "connects": self.connects,
            "last_error": self.last_error or None,
        }
