"""The occlusion mask on the wire: the payload of an OCCLUSION_MASK message (type 3).

Layout, little-endian (docs/occlusion.md has the same table and the test vectors)::

    offset size type    field
    0      1    uint8   mask codec version, 1
    1      1    uint8   encoding, 1 = raster run lengths (below)
    2      2    uint16  width, pixels (>= 1)
    4      2    uint16  height, pixels (>= 1)
    6      2    uint16  people in front (informational; saturates at 65535)
    8      ...          run lengths, each an unsigned LEB128 varint

The mask is read in raster order, top row first, each row left to right. The runs alternate
between clear (0) and set (1) pixels, starting with a clear run, which is 0 when the first
pixel is set; every later run is at least 1, and the runs add up to ``width * height`` exactly,
with no byte after the last. An all-clear mask is one varint. A set pixel is one the kiosk
client must not draw virtual objects on. The mask spans the whole site-camera image whatever
its own size (a mask of half the camera's width covers two camera columns per pixel).

LEB128: seven bits per byte, least significant group first, the high bit set on every byte but
the last; at most 5 bytes (values below 2^35, of which only those up to 2^32 can occur).
"""

from __future__ import annotations

import struct

import numpy as np

CODEC_VERSION = 1
ENCODING_RUNS = 1
HEADER = struct.Struct("<BBHHH")
HEADER_BYTES = HEADER.size  # 8
MAX_VARINT_BYTES = 5


class MaskCodecError(ValueError):
    """A mask payload that does not follow the layout; ``str()`` is a short reason."""


def runs_of(mask: np.ndarray) -> np.ndarray:
    """Alternating run lengths of a (H, W) mask (nonzero = set), starting with a clear run.

    Returns (R,) int64 with ``R >= 1``; the first run may be 0, the others are >= 1.
    """
    flat = np.asarray(mask).ravel() != 0
    n = flat.size
    change = np.flatnonzero(flat[1:] != flat[:-1]) + 1
    bounds = np.concatenate([[0], change, [n]])
    runs = np.diff(bounds)
    if n and flat[0]:
        runs = np.concatenate([[0], runs])
    return runs.astype(np.int64)


def leb128(values: np.ndarray) -> bytes:
    """Unsigned LEB128 encoding of (N,) non-negative integers, vectorised."""
    v = np.asarray(values, dtype=np.uint64)
    bits = np.maximum(1, np.ceil(np.log2(v.astype(np.float64) + 1.0)).astype(np.int64))
    nbytes = (bits + 6) // 7
    out = np.zeros((len(v), MAX_VARINT_BYTES), dtype=np.uint8)
    for k in range(MAX_VARINT_BYTES):
        group = (v >> np.uint64(7 * k)) & np.uint64(0x7F)
        more = (k < nbytes - 1).astype(np.uint64) << np.uint64(7)
        out[:, k] = (group | more).astype(np.uint8)
    keep = np.arange(MAX_VARINT_BYTES)[None, :] < nbytes[:, None]
    return out[keep].tobytes()


def parse_leb128(data: bytes | memoryview) -> np.ndarray:
    """(N,) int64 values of a byte string of consecutive LEB128 varints.

    Raises :class:`MaskCodecError` for a truncated last varint or one longer than 5 bytes.
    """
    b = np.frombuffer(data, dtype=np.uint8)
    if b.size == 0:
        return np.zeros(0, dtype=np.int64)
    last = (b & 0x80) == 0
    if not last[-1]:
        raise MaskCodecError("truncated varint at the end of the runs")
    ends = np.flatnonzero(last)
    starts = np.concatenate([[0], ends[:-1] + 1])
    lengths = ends - starts + 1
    if lengths.max() > MAX_VARINT_BYTES:
        raise MaskCodecError(f"varint longer than {MAX_VARINT_BYTES} bytes")
    # Position of every byte inside its varint: 7-bit group index.
    group = np.arange(b.size) - np.repeat(starts, lengths)
    parts = (b & 0x7F).astype(np.int64) << (7 * group)
    return np.add.reduceat(parts, starts)


def encode_mask(mask: np.ndarray, people_in_front: int = 0) -> bytes:
    """The payload for a (H, W) mask (nonzero = a person in front), sizes 1..65535."""
    mask = np.asarray(mask)
    if mask.ndim != 2 or not (1 <= mask.shape[0] <= 0xFFFF and 1 <= mask.shape[1] <= 0xFFFF):
        raise ValueError(f"a mask must be 2-D with sides 1..65535, got shape {mask.shape}")
    height, width = mask.shape
    head = HEADER.pack(CODEC_VERSION, ENCODING_RUNS, width, height,
                       min(max(int(people_in_front), 0), 0xFFFF))
    return head + leb128(runs_of(mask))


def decode_mask(payload: bytes | memoryview) -> tuple[np.ndarray, int]:
    """``(mask (H, W) uint8 0/255, people_in_front)`` of a payload; :class:`MaskCodecError`
    when it does not follow the layout."""
    data = memoryview(payload)
    if len(data) < HEADER_BYTES:
        raise MaskCodecError(f"payload of {len(data)} bytes is shorter than the 8-byte header")
    version, encoding, width, height, people = HEADER.unpack_from(data, 0)
    if version != CODEC_VERSION:
        raise MaskCodecError(f"unsupported mask codec version {version}")
    if encoding != ENCODING_RUNS:
        raise MaskCodecError(f"unknown mask encoding {encoding}")
    if width == 0 or height == 0:
        raise MaskCodecError(f"empty mask size {width}x{height}")
    runs = parse_leb128(data[HEADER_BYTES:])
    if runs.size == 0:
        raise MaskCodecError("no runs")
    if np.any(runs[1:] == 0):
        raise MaskCodecError("zero-length run after the first")
    total = int(runs.sum())
    if total != width * height:
        raise MaskCodecError(f"runs cover {total} pixels, the mask has {width * height}")
    values = (np.arange(runs.size) % 2).astype(np.uint8) * np.uint8(255)
    return np.repeat(values, runs).reshape(height, width), people


def encode_message(mask: np.ndarray, sequence: int, capture_time_s: float,
                   people_in_front: int = 0, flags: int = 0) -> bytes:
    """A whole OCCLUSION_MASK message (the light stream's 24-byte header + the payload)."""
    from server.protocol import MessageType, encode_blob

    return encode_blob(MessageType.OCCLUSION_MASK, encode_mask(mask, people_in_front),
                       sequence, capture_time_s, flags)
