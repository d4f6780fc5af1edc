"""The light stream's wire format, protocol versions 1, 2 and 3 (``GET /ws/light``;
docs/protocol.md). A client asks for version 3 with ``?protocol=3`` (the sun apart, the sky
in float16), for version 2 with ``?protocol=2`` (the sun apart, the sky in float32); without a
parameter (or with ``protocol=1``) it gets version 1, in which the sun is folded back into its
patch.

Server -> client
----------------
1. One text message, JSON: the hello (:func:`hello_message`).
2. Binary messages, little-endian, each a 24-byte header and a payload::

       offset size type     field
       0      4    bytes    magic "DLYT"
       4      1    uint8    protocol version (1, 2 or 3)
       5      1    uint8    message type (MessageType)
       6      2    uint16   flags (Flags)
       8      4    uint32   sequence number (per message type, wraps at 2^32)
       12     4    uint32   count: lights (LIGHT) or payload bytes (other types)
       16     8    float64  capture time, Unix seconds (UTC)

   LIGHT (1), version 1: ``count`` x RGB float32 (light-major: r0 g0 b0 r1 ...), then the
   saturated bitmask, ``ceil(count / 8)`` bytes, bit ``i % 8`` (least significant first) of
   byte ``i // 8`` set when light ``i`` had clipped pixels.
   LIGHT, version 2: first the sun (28 bytes: direction float32[3], unit, site frame, zero
   when none; normal irradiance float32[3] RGB W/m^2; source uint8 (daylit.sun.SunSource);
   three reserved zero bytes), then the sky as in version 1 but *without* the sun's disc.
   LIGHT, version 3: as version 2, but the sky values are IEEE float16 (:mod:`server.float16`,
   6 bytes a light) instead of float32; a value above 65504 is sent as 65504 and its light
   marked saturated (a lower bound).
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

from server import float16

PROTOCOL_VERSION = 3  # the newest; the server also speaks every version in VERSIONS
VERSIONS = (1, 2, 3)
MAGIC = b"DLYT"
HEADER = struct.Struct("<4sBBHIId")
HEADER_BYTES = HEADER.size  # 24
SUN = struct.Struct("<3f3fB3x")
SUN_BYTES = SUN.size  # 28
SUN_SOURCES = ("none", "measured", "model", "scene")  # daylit.sun.SunSource by value
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
    SUN_ESTIMATED = 32  # LIGHT of version 2 or 3: the sun's irradiance is a model's


# Flags a version-1 message may carry (an older client knows no others).
VERSION1_FLAGS = 31


class ProtocolError(ValueError):
    """A message that does not follow the protocol; ``str()`` is a short reason."""


@dataclass
class WireSun:
    """The sun of a LIGHT message of version 2 or 3.

    direction : (3,) float32, unit, site frame (+X east, +Y up, -Z north); zero when none.
    normal_irradiance_w_m2 : (3,) float32, RGB direct normal irradiance, W/m^2.
    source : int, a ``daylit.sun.SunSource`` value (0 none, 1 measured, 2 model, 3 scene).
    estimated : bool, the SUN_ESTIMATED flag of the message.
    """

    direction: np.ndarray
    normal_irradiance_w_m2: np.ndarray
    source: int
    estimated: bool = False

    @property
    def source_name(self) -> str:
        return SUN_SOURCES[self.source] if 0 <= self.source < len(SUN_SOURCES) else "unknown"


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
    sun: WireSun | None = None  # LIGHT of version 2 or 3; None in version 1
    payload: bytes = field(default=b"", repr=False)  # other types

    @property
    def type_name(self) -> str:
        try:
            return MessageType(self.type).name.lower().replace("_", "-")
        except ValueError:
            return "unknown"


def bitmask_bytes(count: int) -> int:
    return (count + 7) // 8


def sky_bytes_per_light(version: int) -> int:
    """Bytes of one light's sky value: 12 (RGB float32) in versions 1 and 2, 6 (RGB float16)
    in version 3."""
    return 6 if version >= 3 else 12


def light_message_bytes(count: int, version: int = PROTOCOL_VERSION) -> int:
    """Size of a LIGHT message with ``count`` lights."""
    sun = SUN_BYTES if version >= 2 else 0
    return HEADER_BYTES + sun + sky_bytes_per_light(version) * count + bitmask_bytes(count)


def check_version(version: int) -> int:
    if version not in VERSIONS:
        raise ValueError(f"protocol version {version!r} is not one of {VERSIONS}")
    return int(version)


def encode_light(
    rgb: np.ndarray,
    saturated: np.ndarray,
    sequence: int,
    capture_time_s: float,
    flags: int = 0,
    version: int = 1,
    sun: object = None,
) -> bytes:
    """A LIGHT message: ``rgb`` (n, 3) radiance W/(m^2 sr), ``saturated`` (n,) bool.

    Versions 2 and 3 take ``sun``: any object with ``direction`` (3,), ``normal_irradiance_w_m2``
    (3,) and ``source`` (int), or None for no sun (source 0, zeros). Version 1 drops ``sun``
    (fold it into ``rgb`` first: :func:`fold_sun`) and the flags version 1 does not have.
    Version 3 sends ``rgb`` as float16 (:func:`server.float16.encode`: values above 65504
    become 65504 and their lights are marked saturated).
    """
    check_version(version)
    rgb = np.ascontiguousarray(rgb, dtype="<f4")
    if rgb.ndim != 2 or rgb.shape[1] != 3:
        raise ValueError(f"rgb must have shape (n, 3), got {rgb.shape}")
    n = rgb.shape[0]
    sat = np.asarray(saturated, dtype=bool)
    if sat.shape != (n,):
        raise ValueError(f"saturated must have shape ({n},), got {sat.shape}")
    flags = int(flags)
    if version >= 3:
        halves, clipped = float16.encode(rgb)
        sat = sat | clipped
        sky = halves.tobytes()
    else:
        sky = rgb.tobytes()
    if sat.any():
        flags |= Flags.SATURATED
    sun_bytes = b""
    if version == 1:
        flags &= VERSION1_FLAGS
    else:
        if sun is None:
            sun_bytes = SUN.pack(0, 0, 0, 0, 0, 0, 0)
        else:
            d = np.asarray(sun.direction, dtype=np.float64).reshape(3)
            e = np.asarray(sun.normal_irradiance_w_m2, dtype=np.float64).reshape(3)
            source = int(sun.source)
            if not 0 <= source <= 255:
                raise ValueError(f"sun source {source} does not fit a byte")
            sun_bytes = SUN.pack(*d, *e, source)
    head = HEADER.pack(
        MAGIC, version, MessageType.LIGHT, flags & 0xFFFF,
        sequence & 0xFFFFFFFF, n, float(capture_time_s),
    )
    return head + sun_bytes + sky + np.packbits(sat, bitorder="little").tobytes()


def fold_sun(rgb: np.ndarray, sun: object, sun_patch: int | None,
             patch_solid_angle_sr: np.ndarray) -> np.ndarray:
    """The version-1 vector: the sky ``rgb`` (n, 3) with the sun's normal irradiance spread
    over the patch that holds its direction, ``r_p += E_sun / omega_p`` (omega: (n,) sr).
    ``sun_patch`` None (or no sun): ``rgb`` unchanged."""
    out = np.array(rgb, dtype=np.float32)
    if sun is None or sun_patch is None or sun_patch < 0:
        return out
    e = np.asarray(sun.normal_irradiance_w_m2, dtype=np.float64)
    out[sun_patch] += (e / float(patch_solid_angle_sr[sun_patch])).astype(np.float32)
    return out


def encode_blob(
    message_type: int, payload: bytes, sequence: int, capture_time_s: float, flags: int = 0,
    version: int = 1,
) -> bytes:
    """A SITE_CAMERA (JPEG bytes) or other payload message (the same in every version but
    for the version byte)."""
    check_version(version)
    head = HEADER.pack(
        MAGIC, version, int(message_type), int(flags) & 0xFFFF,
        sequence & 0xFFFFFFFF, len(payload), float(capture_time_s),
    )
    return head + bytes(payload)


FLAGS = struct.Struct("<H")  # HEADER's flags field, at FLAGS_OFFSET
FLAGS_OFFSET = 6


def with_flags(message: bytes, flags: int) -> bytes:
    """An encoded binary ``message`` (any type and version) with ``flags`` set besides its
    own; the rest unchanged (a fan-out worker marks the vector it relays STALE this way)."""
    (own,) = FLAGS.unpack_from(message, FLAGS_OFFSET)
    out = bytearray(message)
    FLAGS.pack_into(out, FLAGS_OFFSET, (own | int(flags)) & 0xFFFF)
    return bytes(out)


def decode(data: bytes) -> Message:
    """Decode one binary message of version 1, 2 or 3; raises :class:`ProtocolError` if it is
    malformed. LIGHT values come back as float32 whatever the encoding."""
    if len(data) < HEADER_BYTES:
        raise ProtocolError(f"message of {len(data)} bytes is shorter than the header")
    magic, version, mtype, flags, seq, count, t = HEADER.unpack_from(data, 0)
    if magic != MAGIC:
        raise ProtocolError("bad magic")
    if version not in VERSIONS:
        raise ProtocolError(f"unsupported protocol version {version}")
    body = memoryview(data)[HEADER_BYTES:]
    msg = Message(mtype, version, flags, seq, t, count)
    if mtype == MessageType.LIGHT:
        sun_bytes = SUN_BYTES if version >= 2 else 0
        per_light = sky_bytes_per_light(version)
        need = sun_bytes + per_light * count + bitmask_bytes(count)
        if len(body) != need:
            raise ProtocolError(f"light message of {count} lights needs {need} payload bytes")
        if sun_bytes:
            values = SUN.unpack_from(body, 0)
            msg.sun = WireSun(np.array(values[0:3], np.float32), np.array(values[3:6], np.float32),
                              values[6], bool(flags & Flags.SUN_ESTIMATED))
            body = body[sun_bytes:]
        if version >= 3:
            halves = np.frombuffer(body[: 6 * count], dtype="<f2").reshape(count, 3)
            msg.rgb = float16.decode(halves)
        else:
            msg.rgb = np.frombuffer(body[: 12 * count], dtype="<f4").reshape(count, 3).copy()
        bits = np.frombuffer(body[per_light * count:], dtype=np.uint8)
        msg.saturated = np.unpackbits(bits, bitorder="little")[:count].astype(bool)
    else:
        if len(body) != count:
            raise ProtocolError(f"payload is {len(body)} bytes, header says {count}")
        msg.payload = bytes(body)
    return msg


def parse_protocol(text: str | None) -> int:
    """The version a client asks for with ``?protocol=`` (none: 1, the oldest)."""
    if text is None or text == "":
        return 1
    if text.strip() in {str(v) for v in VERSIONS}:
        return int(text)
    raise ProtocolError(f"unsupported protocol {text[:16]!r}: this server speaks "
                        f"{', '.join(map(str, VERSIONS))}")


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
    version: int = 1,
) -> str:
    """The first (text) message of every connection.

    ``site_camera`` and ``occlusion`` describe those streams when the server has them (else
    None); ``available_streams`` follows from them. ``version``: the connection's protocol.
    """
    check_version(version)
    available = ["light"]
    if site_camera:
        available.append("site-camera")
        if occlusion:
            available.append("occlusion")
    hello = {
        "type": "hello",
        "protocol": version,
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
            "flags": {f.name.lower(): int(f) for f in Flags
                      if f and (version >= 2 or f & VERSION1_FLAGS)},
        },
    }
    hello["sky_encoding"] = "float16" if version >= 3 else "float32"
    if version >= 2:
        hello["sun"] = {"units": "W/m^2, direct normal irradiance, linear RGB",
                        "frame": "+X east, +Y up, -Z north", "sources": list(SUN_SOURCES)}
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
