"""Basis stacks on disk: OpenEXR masters holding one RGB image per light.

A stack is an array of shape ``(H, W, n, 3)`` float32: for every texel (or pixel) and every
light ``i`` the RGB irradiance (or radiance) at unit radiance of patch ``i``. The master file
stores light ``i`` as channels ``L{i:04d}.R``, ``.G``, ``.B`` (float32, lossless PIZ), so
light ``i`` is channel group ``i`` (the one index rule) and the file opens in any EXR viewer.

PIZ rather than ZIPS: on the demo's 400-light masters it writes faster and is smaller
(docs/benchmarks.md, "Baking"), reads as fast, and every OpenEXR reader has it (ZSTD,
smaller still, needs OpenEXR 3.4 or later).
"""

from __future__ import annotations

import errno
import os
from pathlib import Path

import numpy as np
import OpenEXR

CHANNEL_PATTERN = "L{index:04d}.{R,G,B}"


def channel_name(index: int, component: str) -> str:
    return f"L{index:04d}.{component}"


def write_stack_exr(path: Path | str, stack: np.ndarray, attributes: dict | None = None) -> None:
    """Write a ``(H, W, n, 3)`` stack as one float32 EXR (write to a temp name, then rename)."""
    stack = np.asarray(stack, dtype=np.float32)
    if stack.ndim != 4 or stack.shape[3] != 3:
        raise ValueError(f"a stack must have shape (H, W, n, 3), got {stack.shape}")
    channels = {
        channel_name(i, c): np.ascontiguousarray(stack[:, :, i, k])
        for i in range(stack.shape[2])
        for k, c in enumerate("RGB")
    }
    header = {"compression": OpenEXR.PIZ_COMPRESSION, "type": OpenEXR.scanlineimage}
    header.update(attributes or {})
    write_exr(path, header, channels)


def write_exr(path: Path | str, header: dict, channels: dict) -> None:
    """Write an OpenEXR file to a temporary name, then rename it into place. A full disk is
    an ``OSError`` (ENOSPC) and leaves no partial file."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    try:
        with OpenEXR.File(header, channels) as f:
            f.write(str(tmp))
    except RuntimeError as exc:
        tmp.unlink(missing_ok=True)
        # OpenEXR reports a full disk as a RuntimeError; callers handle it as the OSError it is.
        if "No space left on device" in str(exc):
            raise OSError(errno.ENOSPC, f"no space left on device writing {path}") from exc
        raise
    os.replace(tmp, path)


def read_stack_exr(path: Path | str) -> np.ndarray:
    """Read a stack written by :func:`write_stack_exr`: ``(H, W, n, 3)`` float32."""
    with OpenEXR.File(str(path), separate_channels=True) as f:
        channels = f.channels()
        names = [name for name in channels if name.startswith("L") and name.endswith(".R")]
        n = len(names)
        first = channels[channel_name(0, "R")].pixels
        out = np.empty((first.shape[0], first.shape[1], n, 3), dtype=np.float32)
        for i in range(n):
            for k, c in enumerate("RGB"):
                out[:, :, i, k] = channels[channel_name(i, c)].pixels
    return out


# Scanlines per chunk of a PIZ-compressed scanline file (OpenEXR's own constant): a chunk is
# compressed from its lines alone.
PIZ_LINES = 32


def write_stack_exr_by_rows(path: Path | str, height: int, width: int, n: int, read_rows,
                            band_bytes: int = 128 << 20) -> None:
    """Write a ``(H, W, n, 3)`` stack as :func:`write_stack_exr` does, byte for byte, while
    holding a band of scanlines at a time: ``read_rows(y0, y1)`` gives lines ``y0 .. y1``
    ``(y1 - y0, W, n, 3)`` float32. Bands of whole PIZ chunks (:data:`PIZ_LINES`), each of
    about ``band_bytes`` (each written by OpenEXR as a file whose data window is the band,
    then their chunks joined under the whole image's header: a chunk's bytes depend only
    on its lines)."""
    path = Path(path)
    line_bytes = width * n * 3 * 4 * 2  # the lines and their channels' contiguous copies
    band = max(PIZ_LINES, band_bytes // max(line_bytes, 1) // PIZ_LINES * PIZ_LINES)
    tmp = path.with_name(path.name + ".tmp")
    band_file = path.with_name(path.name + ".band")
    header_bytes, chunks = None, []
    try:
        with open(tmp, "wb") as out:
            for y0 in range(0, height, band):
                y1 = min(y0 + band, height)
                lines = np.asarray(read_rows(y0, y1), dtype=np.float32)
                channels = {
                    channel_name(i, c): np.ascontiguousarray(lines[:, :, i, k])
                    for i in range(n)
                    for k, c in enumerate("RGB")
                }
                del lines
                header = {
                    "compression": OpenEXR.PIZ_COMPRESSION, "type": OpenEXR.scanlineimage,
                    "dataWindow": (np.array([0, y0], np.int32),
                                   np.array([width - 1, y1 - 1], np.int32)),
                    "displayWindow": (np.array([0, 0], np.int32),
                                      np.array([width - 1, height - 1], np.int32)),
                }
                write_exr(band_file, header, channels)
                del channels
                data = band_file.read_bytes()
                head, band_chunks = _scanline_chunks(data, -(-(y1 - y0) // PIZ_LINES))
                if header_bytes is None:
                    header_bytes = _with_data_window(head, (0, 0, width - 1, height - 1))
                    out.write(header_bytes)
                    # The offset table, filled in once the chunks' sizes are known.
                    out.write(bytes(8 * -(-height // PIZ_LINES)))
                for chunk in band_chunks:
                    chunks.append(len(chunk))
                    out.write(chunk)
            offsets = np.cumsum([len(header_bytes) + 8 * len(chunks)] + chunks[:-1])
            out.seek(len(header_bytes))
            out.write(offsets.astype("<u8").tobytes())
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    finally:
        band_file.unlink(missing_ok=True)
    os.replace(tmp, path)


def _scanline_chunks(data: bytes, count: int) -> tuple[bytes, list[bytes]]:
    """A single-part scanline EXR file's header (magic, version and attributes, up to its
    offset table) and its ``count`` chunks' bytes (each: line, size, data)."""
    pos = 8
    while data[pos] != 0:  # attributes: name\0 type\0 size value
        pos = data.index(b"\0", pos) + 1
        pos = data.index(b"\0", pos) + 1
        size = int.from_bytes(data[pos : pos + 4], "little", signed=True)
        pos += 4 + size
    head = data[: pos + 1]
    offsets = np.frombuffer(data, "<u8", count, pos + 1)
    chunks = []
    for offset in offsets.tolist():
        size = int.from_bytes(data[offset + 4 : offset + 8], "little", signed=True)
        chunks.append(data[offset : offset + 8 + size])
    return head, chunks


def _with_data_window(head: bytes, box: tuple) -> bytes:
    """``head`` (from :func:`_scanline_chunks`) with its ``dataWindow`` set to ``box``
    (xmin, ymin, xmax, ymax)."""
    key = b"dataWindow\0box2i\0" + (16).to_bytes(4, "little")
    at = head.index(key) + len(key)
    return head[:at] + np.array(box, "<i4").tobytes() + head[at + 16 :]
