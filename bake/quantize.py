"""8-bit quantization of the layers that are encoded: each layer (a base layer, a light's
image, the gain) quantized to 8 bits per channel with its own scale and offset
(``value = byte / 255 * scale + offset``), refinement layers (signed corrections, byte 127 =
0), and the PNG files the encoder reads.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from bake.basisu import CompressionError


def quantize(values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """8-bit RGB of ``values`` (..., 3) with per-channel ``scale`` and ``offset`` (3,):
    ``value ~ byte / 255 * scale + offset``."""
    values = np.asarray(values, dtype=np.float32)
    # Channel-major copy: numpy reduces a contiguous axis far faster than a
    # strided one (docs/benchmarks.md, "Figures behind choices in the code").
    planes = np.ascontiguousarray(np.moveaxis(values, -1, 0)).reshape(3, -1)
    lo = planes.min(axis=1)
    hi = planes.max(axis=1)
    scale = np.where(hi > lo, hi - lo, 1.0).astype(np.float32)
    q = (values - lo) * (255.0 / scale)
    q += 0.5  # round half up: values are non-negative after the offset
    np.clip(q, 0.0, 255.0, out=q)
    return q.astype(np.uint8), scale.astype(np.float64), lo.astype(np.float64)


@dataclass
class Quantized:
    path: Path
    scale: np.ndarray
    offset: np.ndarray

    @property
    def scale_list(self) -> list[float]:
        return float32_list(self.scale)

    @property
    def offset_list(self) -> list[float]:
        return float32_list(self.offset)

    def entry(self, coefficient: int) -> dict:
        return {"scale": self.scale_list, "offset": self.offset_list, "coefficient": coefficient}

    def value(self, rgba: np.ndarray) -> np.ndarray:
        """Decoded (H, W, 4) uint8 back to values (H, W, 3) float32."""
        return rgba[..., :3].astype(np.float32) / 255.0 * self.scale.astype(
            np.float32
        ) + self.offset.astype(np.float32)


def float32_list(values: np.ndarray) -> list[float]:
    """Scales and offsets for the manifest, as the shortest decimals of their float32 values:
    every decoder (GPU, three.js, :class:`bake.compact_reader.CompactReader`) reads them as
    float32, so nothing is lost (what it saves: docs/compact-assets.md)."""
    return [float(str(np.float32(x))) for x in values]


def quantized_png(values: np.ndarray, path: Path) -> Quantized:
    q, scale, offset = quantize(values)
    write_png(path, q)
    return Quantized(path, scale, offset)


def refinement_png(values: np.ndarray, path: Path, keep: np.ndarray | None) -> Quantized:
    """A refinement layer: signed corrections (H, W, 3) quantized so that a zero correction
    is byte 127 exactly (scale ``a * 255 / 127``, offset ``-a``). Outside ``keep`` (H, W) the
    correction is set to zero: constant blocks, which the codec keeps exact and Zstandard
    shrinks to almost nothing."""
    values = np.asarray(values, dtype=np.float32)
    if keep is not None:
        values = np.where(keep[:, :, None], values, np.float32(0.0))
    planes = np.ascontiguousarray(np.moveaxis(values, -1, 0)).reshape(3, -1)
    a = np.maximum(np.abs(planes).max(axis=1), np.float32(1e-30))  # (3,)
    q = np.clip(np.rint(values / a * 127.0) + 127.0, 0.0, 254.0).astype(np.uint8)
    write_png(path, q)
    return Quantized(path, (a * 255.0 / 127.0).astype(np.float64), (-a).astype(np.float64))


def write_png(path: Path, rgb: np.ndarray) -> None:
    # Stored, not deflated: these are read once by the encoder a moment later.
    if not cv2.imwrite(str(path), rgb[:, :, ::-1], [cv2.IMWRITE_PNG_COMPRESSION, 0]):
        raise CompressionError(f"could not write {path}")
