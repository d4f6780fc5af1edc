"""The few EXIF tags a bracket needs, read from JPEG (APP1 ``Exif``), TIFF and PNG (``eXIf``)
files without an imaging library: a TIFF-structure walk of IFD0 and its Exif sub-IFD.

Tags read: ``ExposureTime`` (0x829A, seconds), ``DateTimeOriginal`` (0x9003, local
"YYYY:MM:DD HH:MM:SS") and ``OffsetTimeOriginal`` (0x9011, "+09:00"). Anything malformed reads
as absent: a camera's odd EXIF must never stop a replay.
"""

from __future__ import annotations

import datetime as dt
import struct
from pathlib import Path

EXPOSURE_TIME = 0x829A
DATE_TIME_ORIGINAL = 0x9003
OFFSET_TIME_ORIGINAL = 0x9011
_EXIF_IFD = 0x8769
_WANTED = {EXPOSURE_TIME, DATE_TIME_ORIGINAL, OFFSET_TIME_ORIGINAL}
_SIZES = {1: 1, 2: 1, 3: 2, 4: 4, 5: 8, 7: 1, 9: 4, 10: 8}


def exif_block(data: bytes) -> bytes | None:
    """The TIFF-structured EXIF block of a JPEG, TIFF or PNG file's bytes, or None."""
    if data[:2] == b"\xff\xd8":  # JPEG: walk the markers up to the image data
        i = 2
        while i + 4 <= len(data) and data[i] == 0xFF:
            marker = data[i + 1]
            if marker in (0xD9, 0xDA):  # end of image, start of scan
                return None
            length = struct.unpack(">H", data[i + 2:i + 4])[0]
            body = data[i + 4:i + 2 + length]
            if marker == 0xE1 and body[:6] == b"Exif\x00\x00":
                return body[6:]
            i += 2 + length
        return None
    if data[:4] in (b"II*\x00", b"MM\x00*"):
        return data
    if data[:8] == b"\x89PNG\r\n\x1a\n":
        i = 8
        while i + 8 <= len(data):
            length, kind = struct.unpack(">I4s", data[i:i + 8])
            if kind == b"eXIf":
                return data[i + 8:i + 8 + length]
            if kind == b"IDAT":
                break
            i += 12 + length
    return None


def read_tags(block: bytes) -> dict[int, object]:
    """The wanted tags of a TIFF-structured EXIF block (rationals as float, ASCII as str)."""
    order = {b"II": "<", b"MM": ">"}.get(block[:2])
    if order is None:
        return {}
    tags: dict[int, object] = {}
    try:
        ifd0 = struct.unpack(order + "I", block[4:8])[0]
        for tag, value in _entries(block, order, ifd0):
            if tag == _EXIF_IFD and isinstance(value, int):
                tags.update(dict(t for t in _entries(block, order, value) if t[0] in _WANTED))
            elif tag in _WANTED:
                tags[tag] = value
    except (struct.error, IndexError, ValueError):
        return tags
    return tags


def _entries(block: bytes, order: str, offset: int):
    count = struct.unpack(order + "H", block[offset:offset + 2])[0]
    for k in range(count):
        at = offset + 2 + 12 * k
        tag, kind, n = struct.unpack(order + "HHI", block[at:at + 8])
        size = _SIZES.get(kind, 0) * n
        raw = block[at + 8:at + 12] if size <= 4 else _at(block, order, at + 8, size)
        if kind == 2:
            yield tag, raw[:size].split(b"\x00", 1)[0].decode("ascii", "replace").strip()
        elif kind in (5, 10) and n >= 1:
            num, den = struct.unpack(order + ("II" if kind == 5 else "ii"), raw[:8])
            if den:
                yield tag, num / den
        elif kind in (3, 4) and n == 1:
            yield tag, struct.unpack(order + ("H" if kind == 3 else "I"), raw[:_SIZES[kind]])[0]


def _at(block: bytes, order: str, pointer_at: int, size: int) -> bytes:
    offset = struct.unpack(order + "I", block[pointer_at:pointer_at + 4])[0]
    raw = block[offset:offset + size]
    if len(raw) != size:
        raise ValueError("EXIF value outside the block")
    return raw


def read_exif(path: Path | str) -> dict[int, object]:
    """The wanted tags of an image file ({} without EXIF or when it cannot be read)."""
    try:
        data = Path(path).read_bytes()
    except OSError:
        return {}
    block = exif_block(data)
    return read_tags(block) if block else {}


def exposure_time_s(tags: dict[int, object]) -> float | None:
    value = tags.get(EXPOSURE_TIME)
    return float(value) if isinstance(value, float) and value > 0 else None


def capture_time_s(tags: dict[int, object]) -> float | None:
    """Unix seconds of ``DateTimeOriginal`` with ``OffsetTimeOriginal``; None unless both
    are there and well formed (a local time without its offset is not a time)."""
    text, offset = tags.get(DATE_TIME_ORIGINAL), tags.get(OFFSET_TIME_ORIGINAL)
    if not isinstance(text, str) or not isinstance(offset, str):
        return None
    try:
        return dt.datetime.strptime(f"{text.strip()}{offset.strip()}",
                                    "%Y:%m:%d %H:%M:%S%z").timestamp()
    except ValueError:
        return None
