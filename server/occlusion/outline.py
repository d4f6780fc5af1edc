"""People's outlines moved onto the frame's luminance edges (block-coded frames only).

At 4:2:0 a codec keeps colour at half resolution and blurs it across a person's outline,
so the graph cut, whose colour terms read all three channels, puts the outline a pixel or
two off: it loses low-contrast rims (beige trousers on beige paving) and keeps rims of the
ground and of the shadow's edge (issue 18: 19,000 of 22,000 lost pixels within 2 px of the
outline). Luminance is kept at full resolution. A guided filter (He, Sun and Tang 2013) of
the person mask with the frame's luminance as guide fits, in each small window, the mask as
a linear function of luminance; thresholded at one half it follows the luminance edge that
separates person from ground. Only pixels within the filter's radius of the outline may
change, so the filter cannot invent people away from the cut's.
"""

from __future__ import annotations

import cv2
import numpy as np


def refine_outline(person: np.ndarray, codes: np.ndarray, radius_px: int,
                   eps: float, level: float = 0.5) -> np.ndarray:
    """The person mask of a region with its outline on the luminance edges.

    ``person`` (h, w) bool; ``codes`` (h, w, 3) uint8 BGR, the same region of the frame;
    ``radius_px`` the guided filter's window radius (pixels) and the widest change of the
    outline; ``eps`` its regulariser in squared 8-bit codes (a luminance step well below
    ``sqrt(eps)`` inside a window is smoothed over, one well above it is followed).
    Returns (h, w) bool. Computed over the person pixels' bounding rectangle and a margin
    of three radii (the filter's two box means and the band) only.
    """
    x, y, w, h = cv2.boundingRect(person.view(np.uint8))
    if w == 0 or radius_px <= 0:
        return person
    m = 3 * radius_px + 1
    rows = slice(max(0, y - m), y + h + m)
    cols = slice(max(0, x - m), x + w + m)
    sub = np.ascontiguousarray(person[rows, cols]).view(np.uint8)
    grey = cv2.cvtColor(np.ascontiguousarray(codes[rows, cols]), cv2.COLOR_BGR2GRAY)
    smooth = cv2.ximgproc.guidedFilter(grey, sub.astype(np.float32), radius_px, eps)
    k = np.ones((2 * radius_px + 1,) * 2, np.uint8)
    band = cv2.dilate(sub, k) != cv2.erode(sub, k)  # within the radius of the outline
    out = person.copy()
    out[rows, cols] = np.where(band, smooth > level, sub > 0)
    return out
