"""Pixel codes and linear light: the camera's transfer curve, daylight gain tables, colour bins.

Frames are OpenCV BGR ``uint8``. The segmentation works on codes (where sensor noise is roughly
even), the F-value and the daylight gain on linear values; the tables here convert between
them with one look-up per pixel.
"""

from __future__ import annotations

import cv2
import numba
import numpy as np

from server.photometry import inverse_response_table

_CHANNEL = np.arange(3, dtype=np.intp)


class Transfer:
    """The site camera's response: ``decode`` (code -> linear) and its inverse, per channel.

    Attributes
    ----------
    decode_bgr : (256, 3) float32, linear value in [0, 1] of each code, BGR channel order.
    """

    def __init__(self, response: object = "srgb"):
        rgb = inverse_response_table(response)  # (256, 3) RGB
        self.decode_bgr = np.ascontiguousarray(rgb[:, ::-1], dtype=np.float32)
        self._codes = np.arange(256, dtype=np.float64)
        # For cv2.LUT: (256, 1, 3) tables of the linear value and of its logarithm.
        self.decode_table = self.decode_bgr.reshape(256, 1, 3).copy()
        self.log_table = np.log(np.maximum(self.decode_table, 1e-6)).astype(np.float32)
        # d ln(linear) / d code at each code: turns noise in codes into noise in ln.
        self.log_slope = np.abs(np.gradient(self.log_table[:, 0, :], axis=0)).astype(np.float32)
        # The same three tables flat, (768,) float32, read at channel_index(codes): one
        # np.take each instead of a fancy index per table (a third of the time, same values).
        self.decode_flat = self.decode_bgr.ravel()
        self.log_flat = self.log_table.ravel()
        self.log_slope_flat = self.log_slope.ravel()

    @staticmethod
    def channel_index(codes_bgr: np.ndarray) -> np.ndarray:
        """(..., 3) uint8 codes -> (..., 3) intp ``3 code + channel``, the index of each code
        into the flat tables ``decode_flat``, ``log_flat`` and ``log_slope_flat``."""
        return codes_bgr.astype(np.intp) * 3 + _CHANNEL

    def to_linear(self, codes_bgr: np.ndarray) -> np.ndarray:
        """(..., 3) uint8 codes -> (..., 3) float32 linear values."""
        out = np.empty(codes_bgr.shape, dtype=np.float32)
        for c in range(3):
            out[..., c] = self.decode_bgr[codes_bgr[..., c], c]
        return out

    def image_to_linear(self, codes_bgr: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 codes -> (H, W, 3) float32 linear values, one cv2.LUT."""
        return cv2.LUT(codes_bgr, self.decode_table)

    def to_codes(self, linear_bgr: np.ndarray) -> np.ndarray:
        """(..., 3) linear values -> (..., 3) float32 fractional codes (inverse of decode)."""
        out = np.empty(linear_bgr.shape, dtype=np.float32)
        for c in range(3):
            out[..., c] = np.interp(linear_bgr[..., c], self.decode_bgr[:, c], self._codes)
        return out

    def gain_table(self, gain_bgr: np.ndarray) -> np.ndarray:
        """(256, 1, 3) uint8 table for ``cv2.LUT`` that divides linear light by ``gain_bgr``.

        Maps a frame taken under today's daylight into the background model's reference
        illumination: ``code -> encode(decode(code) / gain)``, per channel.
        """
        lin = self.decode_bgr / np.asarray(gain_bgr, dtype=np.float32)[None, :]
        codes = np.clip(np.rint(self.to_codes(lin)), 0, 255).astype(np.uint8)
        return codes.reshape(256, 1, 3)


def apply_table(frame_bgr: np.ndarray, table: np.ndarray) -> np.ndarray:
    """``cv2.LUT`` of a (H, W, 3) uint8 frame with a (256, 1, 3) per-channel table."""
    return cv2.LUT(frame_bgr, table)


def colour_index(codes_bgr: np.ndarray, bits: int) -> np.ndarray:
    """Bin index of each colour for a ``2^(3 bits)``-entry table: (N, 3) uint8 -> (N,) int32.

    Index ``(b >> s) << 2 bits | (g >> s) << bits | (r >> s)`` with ``s = 8 - bits``.
    """
    shift = 8 - bits
    q = (codes_bgr >> shift).astype(np.int32)
    return (q[:, 0] << (2 * bits)) | (q[:, 1] << bits) | q[:, 2]


def bin_centres(bits: int) -> np.ndarray:
    """(2^(3 bits), 3) float64 centre code of every bin, in :func:`colour_index` order."""
    n = 1 << bits
    width = 256 / n
    centres = (np.arange(n) + 0.5) * width - 0.5
    b, g, r = np.meshgrid(centres, centres, centres, indexing="ij")
    return np.stack([b.ravel(), g.ravel(), r.ravel()], axis=1)


@numba.njit(cache=True, nogil=True)
def table_costs(codes_bgr: np.ndarray, table: np.ndarray, bits: int) -> np.ndarray:
    """``-table[colour_index(codes)]`` of an (h, w, 3) uint8 image (any layout: a view of a
    box, or a whole frame; each is compiled once): (h, w) float32, in one pass (numpy's index
    arithmetic and gather took ten times as long)."""
    h, w = codes_bgr.shape[:2]
    shift = 8 - bits
    out = np.empty((h, w), dtype=np.float32)
    for y in range(h):
        for x in range(w):
            i = ((codes_bgr[y, x, 0] >> shift) << (2 * bits)) | (
                (codes_bgr[y, x, 1] >> shift) << bits) | (codes_bgr[y, x, 2] >> shift)
            out[y, x] = -table[i]
    return out
