"""The synthetic sequence's people: flat, articulated figures of capsules (head, torso, arms,
legs, shoes), each standing upright in the vertical plane through its feet that faces the
camera; where they walk and pause (:class:`Walker`), which points of that plane they cover
(:func:`inside_figure`) and the pixels around a projected figure (:func:`pixel_box`). Split from
``server/occlusion/synthetic.py``, which draws them into the site. Metres and seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass
class Walker:
    """One person: where and when they walk, how tall, what they wear.

    Attributes
    ----------
    start_m : (x, z) ground position at ``enter_s``
    velocity_mps : (vx, vz) while walking
    height_m : standing height
    shirt, trousers, skin, hair, shoes : RGB reflectances (0-1): coefficients of a smooth
        spectrum (spectralcamera.REFLECTANCE_BASIS); the narrow-band model reads them as the
        reflectances at its three wavelengths
    enter_s, leave_s : visible from / until, seconds
    pauses_s : ((t0, t1), ...) intervals in which they stand still
    """

    start_m: tuple[float, float]
    velocity_mps: tuple[float, float]
    height_m: float = 1.75
    shirt: tuple[float, float, float] = (0.6, 0.1, 0.1)
    trousers: tuple[float, float, float] = (0.1, 0.12, 0.3)
    skin: tuple[float, float, float] = (0.55, 0.4, 0.32)
    hair: tuple[float, float, float] = (0.08, 0.06, 0.05)
    shoes: tuple[float, float, float] = (0.06, 0.06, 0.06)
    enter_s: float = 0.0
    leave_s: float = 1e9
    pauses_s: tuple[tuple[float, float], ...] = ()

    def walked_s(self, t: float) -> float:
        """Seconds spent walking since ``enter_s``."""
        walked = t - self.enter_s
        for t0, t1 in self.pauses_s:
            walked -= max(0.0, min(t, t1) - max(self.enter_s, t0))
        return max(0.0, walked)

    def position(self, t: float) -> tuple[float, float]:
        w = self.walked_s(t)
        vx, vz = self.velocity_mps
        return (self.start_m[0] + w * vx, self.start_m[1] + w * vz)

    def standing(self, t: float) -> bool:
        return any(t0 <= t < t1 for t0, t1 in self.pauses_s)

    def capsules(self, t: float) -> list[tuple[np.ndarray, np.ndarray, float, np.ndarray]]:
        """The figure's parts in its plane: ``(a, b, radius, reflectance)`` with ``a``, ``b`` the
        (x, y) ends in metres (x to the camera's right, y up), front-most part first."""
        s = self.height_m / 1.75
        speed = math.hypot(*self.velocity_mps)
        phase = 2.0 * math.pi * self.walked_s(t) * speed / 1.5
        swing = 0.0 if self.standing(t) else math.sin(phase)
        direction = 1.0 if self.velocity_mps[0] >= 0 else -1.0
        leg_r, arm_r, shoe_r = 0.075 * s, 0.05 * s, 0.045 * s
        hip_y = 0.92 * s
        parts = []

        def cap(ax, ay, bx, by, r, refl):
            parts.append((np.array([ax, ay]), np.array([bx, by]), r, np.asarray(refl, float)))

        cap(0.0, 1.63 * s, 0.0, 1.66 * s, 0.105 * s, self.hair)  # head top
        cap(0.0, 1.55 * s, 0.0, 1.58 * s, 0.1 * s, self.skin)  # face
        for side in (-1.0, 1.0):  # arms swing opposite to the legs
            hand_x = side * (0.24 - 0.18 * swing) * s
            cap(side * 0.21 * s, 1.40 * s, hand_x, 0.92 * s, arm_r, self.shirt)
            cap(hand_x, 0.92 * s, hand_x, 0.86 * s, arm_r * 0.9, self.skin)
        cap(0.0, 1.38 * s, 0.0, 1.0 * s, 0.17 * s, self.shirt)  # torso
        for side in (-1.0, 1.0):
            foot_x = side * (0.06 + 0.28 * swing) * s
            cap(side * 0.09 * s, hip_y, foot_x, shoe_r + 0.06 * s, leg_r, self.trousers)
            cap(foot_x - direction * 0.03 * s, shoe_r, foot_x + direction * 0.08 * s, shoe_r,
                shoe_r, self.shoes)
        return parts


def pixel_box(uv: np.ndarray, margin_px: int, W: int, H: int):
    """The pixels ``(x0, y0, x1, y1)`` (end exclusive) around projected points ``uv`` (m, 2),
    widened by ``margin_px`` and clipped to a W x H frame; None when nothing is left."""
    x0, y0 = np.floor(uv.min(0)).astype(int) - margin_px
    x1, y1 = np.ceil(uv.max(0)).astype(int) + margin_px
    x0, x1 = max(0, x0), min(W, x1)
    y0, y1 = max(0, y0), min(H, y1)
    return None if x1 <= x0 or y1 <= y0 else (x0, y0, x1, y1)


def inside_figure(parts, x: np.ndarray, y: np.ndarray):
    """Which points (x, y) lie in the figure: returns (hit bool, reflectance (N, 3), shade)."""
    hit = np.zeros(x.shape, dtype=bool)
    refl = np.zeros(x.shape + (3,), dtype=np.float64)
    shade = np.ones(x.shape, dtype=np.float64)
    for a, b, r, colour in parts:
        ab = b - a
        denom = max(float(ab @ ab), 1e-12)
        tt = np.clip(((x - a[0]) * ab[0] + (y - a[1]) * ab[1]) / denom, 0.0, 1.0)
        dx = x - (a[0] + tt * ab[0])
        dy = y - (a[1] + tt * ab[1])
        d2 = dx * dx + dy * dy
        new = (d2 < r * r) & ~hit
        if new.any():
            hit |= new
            refl[new] = colour
            # A rounded limb: darker toward its silhouette (the same daylight, less of it).
            shade[new] = 0.7 + 0.3 * np.sqrt(np.clip(1.0 - d2[new] / (r * r), 0.0, 1.0))
    return hit, refl, shade
