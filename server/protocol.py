"""The light stream's wire format, protocol version 1 (``GET /ws/light``; docs/protocol.md).

Server -> client
----------------
1. One text message, JSON: the hello (:func:`hello_message`).
2. Binary messages, little-endian, each a 24-byte header and a payload::

       offset size type     field
       0      4    bytes    magic "DLYT"
       4      1    uint8    protocol version (1)
       5      1    uint8    message type (MessageType)
       6      2    uint16   flags (Flags)
       8      4    uint32   sequence number (per message type, wraps at 2^32)
       12     4    uint32   count: lights (LIGHT) or payload bytes (other types)
       16     8    float64  capture time, Unix seconds (UTC)

   LIGHT (1): ``count`` x RGB float32 (light-major: r0 g0 b0 r1 ...), then the saturated
   bitmask, ``ceil(count / 8)`` bytes, bit ``i % 8`` (least significant first) of byte
   ``i // 8`` set when light ``i`` had clipped pixels.
   SITE_CAMERA (2): ``count`` bytes of one JPEG image of the kiosk's site camera.
   OCCLUSION_MASK (3): ``count`` bytes: the mask of visitors standing in front of the virtual
   objects in that site-camera frame (same capture time; payload layout in
   :mod:`server.occlusion.codec`), sent right after the SITE_CAMERA message of its frame.
   Decoders skip types they do not know.

Client -> server
----------------
Text JSON only, at most :data:`MAX_CLIENT_MESSAGE_BYTES` bytes:
``{"type": "subscribe", "streams": ["light", "site-camera", "occlusion"]}`` (the streams
wanted from now on)
and ``{"type": "ping", "id": ...}`` (answered by ``{"type": "pong", "id": ..., "server_time_s"}``).
Anything else closes the connection with code 1008 (policy) or 1003 (binary data).
"""

from __future__ import annotations

import json
import math
import struct
from dataclasses import dataclass, field
from enum import IntEnum, IntFlag

import numpy as np

PROTOCOL_VERSION = 1
MAGIC = b"DLYT"
HEADER = struct.Struct("<4sBBHIId")
HEADER_BYTES = HEADER.size  # 24
MAX_CLIENT_MESSAGE_BYTES = 1024
STREAMS = ("light", "site-camera", "occlusion")


class MessageType(IntEnum):
    LIGHT = 1
    SITE_CAMERA = 2
    OCCLUSION_MASK = 3  # people in front of the virtual objects (server.occlusion.codec)


class Flags(IntFlag):
    NONE = 0
    STALE = 1  # the source has stopped delivering; this is the last good vector
    SATURATED = 2  # at least one light had clipped pixels (see the bitmask)
    SIMULATED = 4  # the built-in simulated sky, not a camera
    REPLAY = 8  # a recording being replayed
    LEARNING = 16  # OCCLUSION_MASK: the empty site is being learned; the mask is all clear


class ProtocolError(ValueError):
    """A message that does not follow the protocol; ``str()`` is a short reason."""


@dataclass
class Message:
    """A decoded binary message."""

    type: int
    version: int
    flags: int
    sequence: int
    capture_time_s: float
    count: int
    rgb: np.ndarray | None = None  # (count, 3) float32 for LIGHT
    saturated: np.ndarray | None = None  # (count,) bool for LIGHT
    payload: bytes = field(default=b"", repr=False)  # other types

    @property
    def type_name(self) -> str:
        try:
            return MessageType(self.type).name.lower().replace("_", "-")
        except ValueError:
            return "unknown"


def bitmask_bytes(count: int) -> int:
    return (count + 7) // 8


def light_message_bytes(count: int) -> int:
    """Size of a LIGHT message with ``count`` lights."""
    return HEADER_BYTES + 12 * count + bitmask_bytes(count)


def encode_light(
    rgb: np.ndarray,
    saturated: np.ndarray,
    sequence: int,
    capture_time_s: float,
    flags: int = 0,
) -> bytes:
    """A LIGHT message: ``rgb`` (n, 3) radiance, ``saturated`` (n,) bool."""
    rgb = np.ascontiguousarray(rgb, dtype="<f4")
    if rgb.ndim != 2 or rgb.shape[1] != 3:
        raise ValueError(f"rgb must have shape (n, 3), got {rgb.shape}")
    n = rgb.shape[0]
    sat = np.asarray(saturated, dtype=bool)
    if sat.shape != (n,):
        raise ValueError(f"saturated must have shape ({n},), got {sat.shape}")
    if sat.any():
        flags |= Flags.SATURATED
    head = HEADER.pack(
        MAGIC, PROTOCOL_VERSION, MessageType.LIGHT, int(flags) & 0xFFFF,
        sequence & 0xFFFFFFFF, n, float(capture_time_s),
    )
    return head + rgb.tobytes() + np.packbits(sat, bitorder="little").tobytes()


def encode_blob(
    message_type: int, payload: bytes, sequence: int, capture_time_s: float, flags: int = 0
) -> bytes:
    """A SITE_CAMERA (JPEG bytes) or other payload message."""
    head = HEADER.pack(
        MAGIC, PROTOCOL_VERSION, int(message_type), int(flags) & 0xFFFF,
        sequence & 0xFFFFFFFF, len(payload), float(capture_time_s),
    )
    return head + bytes(payload)


def decode(data: bytes) -> Message:
    """Decode one binary message; raises :class:`ProtocolError` if it is malformed."""
    if len(data) < HEADER_BYTES:
        raise ProtocolError(f"message of {len(data)} bytes is shorter than the header")
    magic, version, mtype, flags, seq, count, t = HEADER.unpack_from(data, 0)
    if magic != MAGIC:
        raise ProtocolError("bad magic")
    if version != PROTOCOL_VERSION:
        raise ProtocolError(f"unsupported protocol version {version}")
    body = memoryview(data)[HEADER_BYTES:]
    msg = Message(mtype, version, flags, seq, t, count)
    if mtype == MessageType.LIGHT:
        need = 12 * count + bitmask_bytes(count)
        if len(body) != need:
            raise ProtocolError(f"light message of {count} lights needs {need} payload bytes")
        msg.rgb = np.frombuffer(body[: 12 * count], dtype="<f4").reshape(count, 3).copy()
        bits = np.frombuffer(body[12 * count:], dtype=np.uint8)
        msg.saturated = np.unpackbits(bits, bitorder="little")[:count].astype(bool)
    else:
        if len(body) != count:
            raise ProtocolError(f"payload is {len(body)} bytes, header says {count}")
        msg.payload = bytes(body)
    return msg


def hello_message(
    scene_id: str,
    light_count: int,
    manifest_url: str,
    source: str,
    simulated: bool,
    streams: list[str],
    site_camera: dict | None,
    smoothing_s: float,
    server_time_s: float,
    extra: dict | None = None,
    occlusion: dict | None = None,
) -> str:
    """The first (text) message of every connection.

    ``site_camera`` and ``occlusion`` describe those streams when the server has them (else
    None); ``available_streams`` follows from them.
    """
    available = ["light"]
    if site_camera:
        available.append("site-camera")
        if occlusion:
            available.append("occlusion")
    hello = {
        "type": "hello",
        "protocol": PROTOCOL_VERSION,
        "scene": scene_id,
        "lights": light_count,
        "manifest": manifest_url,
        "units": "W/(m^2 sr), mean radiance per light, linear RGB",
        "source": source,
        "simulated": simulated,
        "streams": streams,
        "available_streams": available,
        "site_camera": site_camera,
        "occlusion": occlusion if site_camera else None,
        "smoothing_s": smoothing_s,
        "server_time_s": server_time_s,
        "binary": {
            "endianness": "little",
            "magic": MAGIC.decode(),
            "header_bytes": HEADER_BYTES,
            "types": {t.name.lower().replace("_", "-"): int(t) for t in MessageType},
            "flags": {f.name.lower(): int(f) for f in Flags if f},
        },
    }
    if extra:
        hello.update(extra)
    return json.dumps(hello, separators=(",", ":"))


@dataclass
class ClientMessage:
    type: str
    streams: list[str] | None = None
    id: object = None


def parse_client_message(text: str) -> ClientMessage:
    """Validate a client's text message; raises :class:`ProtocolError` with a reason."""
    if len(text.encode("utf-8")) > MAX_CLIENT_MESSAGE_BYTES:
        raise ProtocolError("message too long")
    try:
        data = json.loads(text)
    except json.JSONDecodeError:
        raise ProtocolError("not JSON") from None
    if not isinstance(data, dict) or not isinstance(data.get("type"), str):
        raise ProtocolError("expected a JSON object with a type")
    kind = data["type"]
    if kind == "subscribe":
        streams = data.get("streams")
        if not isinstance(streams, list) or not all(isinstance(s, str) for s in streams):
            raise ProtocolError("subscribe needs a list of stream names")
        unknown = sorted(set(streams) - set(STREAMS))
        if unknown:
            raise ProtocolError(f"unknown stream {unknown[0][:32]!r}")
        if set(data) - {"type", "streams"}:
            raise ProtocolError("unexpected keys in subscribe")
        return ClientMessage("subscribe", streams=list(dict.fromkeys(streams)))
    if kind == "ping":
        ping_id = data.get("id")
        ok = ping_id is None or isinstance(ping_id, str | int) and not isinstance(ping_id, bool)
        if isinstance(ping_id, float) and math.isfinite(ping_id):
            ok = True
        if not ok or (isinstance(ping_id, str) and len(ping_id) > 64):
            raise ProtocolError("ping id must be a number or a short string")
        if set(data) - {"type", "id"}:
            raise ProtocolError("unexpected keys in ping")
        return ClientMessage("ping", id=ping_id)
    raise ProtocolError(f"unknown message type {kind[:32]!r}")


def parse_streams(text: str | None) -> list[str]:
    """Streams from a query parameter such as ``light,site-camera,occlusion`` (default:
    light)."""
    if not text:
        return ["light"]
    streams = [s.strip() for s in text.split(",") if s.strip()]
    unknown = sorted(set(streams) - set(STREAMS))
    if unknown:
        raise ProtocolError(f"unknown stream {unknown[0][:32]!r}")
    return list(dict.fromkeys(streams))
