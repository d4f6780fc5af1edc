"""Binning a fisheye frame to the measuring resolution: the binning factor for a lens (a power
of two), the lens as binned frames see it, and the bands of a frame that hold used pixels.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from server.fisheye import FisheyeCamera

# Frames are binned (after linearising, by a power of two) to at most this many pixels of the
# image circle's bounding box: at 1 megapixel 320 x 240, a hundred or more pixels per light of
# a 400-light dome, which keeps the per-frame cost near one table look-up per full-resolution
# pixel. Twice as many pixels per side (4 times this) cut the error at the patches' edges for
# more time per frame (docs/benchmarks.md, "Light server"). Setting: [sky] max_working_pixels.
DEFAULT_WORKING_PIXELS = 1 << 17


def band_strips(used: np.ndarray, b: int, full_rows: int = 64) -> tuple:
    """Bands of about ``full_rows`` full-resolution rows over the working-size map of used
    pixels ``used`` (h, w), each ``(r0, r1, c0, c1)`` in full-resolution pixels of the crop,
    narrowed to the columns that hold used pixels; bands without any are left out."""
    rows = max(1, full_rows // b)
    out = []
    for r in range(0, used.shape[0], rows):
        cols = np.flatnonzero(used[r:r + rows].any(axis=0))
        if cols.size:
            r1 = min(used.shape[0], r + rows)
            out.append((r * b, r1 * b, int(cols[0]) * b, (int(cols[-1]) + 1) * b))
    return tuple(out)


def binned_camera(camera: FisheyeCamera, b: int) -> FisheyeCamera:
    """The lens as seen in frames binned ``b x b`` (pixel ``u'`` averages ``b u' ... b u' + b -
    1``): exactly ``1 / b`` the scale, also when the frame's size is not a multiple of ``b``
    (the rest of the rows and columns are left out)."""
    K = camera.K.copy()
    K[0, 0] /= b
    K[0, 1] /= b
    K[1, 1] /= b
    K[0, 2] = (K[0, 2] + 0.5) / b - 0.5  # pixel centres: u' + 0.5 = (u + 0.5) / b
    K[1, 2] = (K[1, 2] + 0.5) / b - 0.5
    return replace(camera, width=camera.width // b, height=camera.height // b, K=K)


def binning_for(camera: FisheyeCamera, max_working_pixels: int) -> int:
    """The binning factor: the smallest power of two ``b`` for which the part of the frame that
    sees the sky (the bounding box of the image circle above the horizon), binned ``b x b``,
    has at most ``max_working_pixels`` pixels.

    Powers of two because OpenCV averages 2 x 2 blocks with SIMD code: two 2 x 2 steps take a
    fifth of the time of one 4 x 4 or 3 x 3 step (docs/benchmarks.md).
    """
    step = max(1, min(camera.width, camera.height) // 256)
    xs = np.arange(step / 2.0, camera.width, step)
    ys = np.arange(step / 2.0, camera.height, step)
    gx, gy = np.meshgrid(xs, ys)
    d, ok = camera.unproject(np.stack([gx.ravel(), gy.ravel()], axis=-1))
    sky = ok & (d[:, 1] >= 0.0)
    if sky.any():
        u, v = gx.ravel()[sky], gy.ravel()[sky]
        width = min(camera.width, u.max() - u.min() + 2 * step)
        height = min(camera.height, v.max() - v.min() + 2 * step)
    else:
        width, height = camera.width, camera.height
    b = 1
    while width * height / (b * b) > max_working_pixels:
        b *= 2
    return b

