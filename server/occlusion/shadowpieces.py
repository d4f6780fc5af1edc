"""Person regions that are pieces of a cast shadow, given back to it (on every frame; made for
block-coded ones, where they arise).

Through a codec, parts of a cast shadow keep some of the sunlit ground's colour (4:2:0 chroma
at half resolution, motion compensation that has not caught up), fail the shadow test and are
cut as person, apart from any person (issue 18). Two kinds, each given back to the shadow:

- **Slivers** along the shadow's edges, one or two pixels wide: a region at least
  ``shadow_sliver_share`` of whose pixels pass the shadow's hard gates and that an erosion of
  radius ``shadow_sliver_px`` (per 1024 px of frame width, at least 1) leaves at most a tenth
  of. A person, even in dark clothes that pass the gates, is thicker than that somewhere (their
  body), and a far person's legs belong to the same region as the body.
- **Islands** inside the shadow: regions of 30-350 pixels along its edges and at its far end
  (H.264 crf 28 at 1024x512: 33,000 of the 55,000 shadow pixels kept, before this rule). A
  person stands on the ground, which around them is lit, or their own shadow by their feet
  only; a piece of shadow is surrounded by shadow. So a region whose one-pixel ring (the
  pixels 8-adjacent to it) is at least ``shadow_island_share`` shadow joins it. A leg cut off
  from its body and ringed by the shadow's penumbra would go too: at 0.3 it did on the
  held-out all-at-once H.264 sequence (person IoU 0.906 -> 0.879), at 0.5 it does not.

One labelling serves both; it covers the person pixels' bounding rectangle (and the erosion's
margin) only.
"""

from __future__ import annotations

import cv2
import numpy as np


def give_back_pieces(person: np.ndarray, shadow: np.ndarray, gated: np.ndarray,
                     sliver_share: float, sliver_radius_px: int,
                     island_share: float) -> tuple[np.ndarray, np.ndarray]:
    """``(person, shadow)`` (h, w) bool of one region with the shadow's pieces moved from
    ``person`` to ``shadow``.

    ``gated`` (h, w) bool: the pixels that pass the shadow's hard gates (a finite shadow
    cost). ``sliver_share`` <= 0 switches the slivers off, ``island_share`` <= 0 the
    islands; ``sliver_radius_px`` is the erosion's radius in this frame's pixels.
    """
    if sliver_share <= 0.0 and island_share <= 0.0:
        return person, shadow
    x, y, w, h = cv2.boundingRect(person.view(np.uint8))
    if w == 0:
        return person, shadow
    r = max(1, sliver_radius_px)
    rows = slice(max(0, y - r - 1), y + h + r + 1)
    cols = slice(max(0, x - r - 1), x + w + r + 1)
    sub = np.ascontiguousarray(person[rows, cols]).view(np.uint8)
    # Grana's labelling: a third of the time of the default with stats here (depth.py's note)
    count, labels, stats, _ = cv2.connectedComponentsWithStatsWithAlgorithm(
        sub, 8, cv2.CV_32S, cv2.CCL_GRANA)
    if count < 2:
        return person, shadow
    area = stats[:, cv2.CC_STAT_AREA]
    drop = np.zeros(count, dtype=bool)
    if sliver_share > 0.0:
        drop = np.bincount(labels[gated[rows, cols] & (sub > 0)],
                           minlength=count) >= sliver_share * area
        drop[0] = False
        if drop.any():  # thin: an erosion of radius r leaves at most a tenth
            core = cv2.erode(sub, np.ones((2 * r + 1, 2 * r + 1), np.uint8)) > 0
            drop &= np.bincount(labels[core], minlength=count) <= 0.1 * area
    if island_share > 0.0:
        # Each ring pixel's region: the largest label among its neighbours (regions are
        # apart by at least one pixel, so a ring pixel touching two is rare; it counts for one).
        near = cv2.dilate(labels.astype(np.float32), np.ones((3, 3), np.uint8)).astype(np.int32)
        ring = (near > 0) & (sub == 0)
        around = np.bincount(near[ring], minlength=count)
        shaded = np.bincount(near[ring & shadow[rows, cols]], minlength=count)
        island = shaded >= island_share * np.maximum(around, 1)
        island[0] = False
        drop |= island
    if not drop.any():
        return person, shadow
    gone = np.zeros(person.shape, dtype=bool)
    gone[rows, cols] = drop[labels]
    return person & ~gone, shadow | gone
