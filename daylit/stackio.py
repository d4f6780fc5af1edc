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
