"""Person regions that lie inside a cast shadow, given back to it.

Through a video codec, pieces of a cast shadow keep part of the sunlit ground's colour
(chroma at half resolution, motion compensation that has not yet caught up), fail the shadow
test and are cut as person: regions of 30-350 pixels along the shadow's edges and at its far
end (issue 18, H.264 crf 28 at 1024x512: 33,000 of the 55,000 shadow pixels kept were in
such regions, apart from any person). A person stands on the ground, which around them is lit
or in their own shadow by their feet only; a piece of shadow is surrounded by shadow. So a
person region whose one-pixel ring is at least ``share`` shadow is given to the shadow.
"""

from __future__ import annotations

import cv2
import numpy as np


def give_back_islands(person: np.ndarray, shadow: np.ndarray,
                      share: float) -> tuple[np.ndarray, np.ndarray]:
    """``(person, shadow)`` (h, w) bool of one region, with the person regions (8-connected)
    whose ring (the pixels 8-adjacent to them, outside them) is at least ``share`` shadow
    moved to ``shadow``. ``share`` <= 0: off. Computed over the person pixels' bounding
    rectangle (and a one-pixel margin) only."""
    if share <= 0.0:
        return person, shadow
    x, y, w, h = cv2.boundingRect(person.view(np.uint8))
    if w == 0:
        return person, shadow
    rows = slice(max(0, y - 1), y + h + 1)
    cols = slice(max(0, x - 1), x + w + 1)
    sub = np.ascontiguousarray(person[rows, cols]).view(np.uint8)
    count, labels = cv2.connectedComponents(sub, connectivity=8)
    k = np.ones((3, 3), np.uint8)
    # Each ring pixel's region: the largest label among its neighbours (regions are apart
    # by at least one pixel, so a ring pixel touching two is rare and counts for one).
    near = cv2.dilate(labels.astype(np.float32), k).astype(np.int32)
    ring = (near > 0) & (sub == 0)
    around = np.bincount(near[ring], minlength=count)
    shaded = np.bincount(near[ring & shadow[rows, cols]], minlength=count)
    drop = shaded >= share * np.maximum(around, 1)
    drop[0] = False
    if not drop.any():
        return person, shadow
    gone = np.zeros(person.shape, dtype=bool)
    gone[rows, cols] = drop[labels]
    return person & ~gone, shadow | gone
