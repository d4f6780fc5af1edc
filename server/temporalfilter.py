"""The streaming policy for measured vectors: exponential smoothing of the light vector and
the sun, and the rule that decides when a new vector is worth sending (a change threshold
relative to the sky's mean radiance, a sun direction threshold, a keep-alive interval).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass
class TemporalFilter:
    """Exponential smoothing plus a change threshold for the streamed vector and the sun.

    Parameters
    ----------
    time_constant_s : float
        Each new measurement moves the smoothed vector (and the sun's normal irradiance) by
        ``1 - exp(-dt / tau)``; 0 turns smoothing off. A few seconds hides sensor noise;
        clouds over the sun still come through.
    change_threshold : float
        A new vector is sent only when some light's value has moved by more than this fraction
        of the sky's mean radiance ``L`` since the last vector sent (or its flags changed), or
        the sun's normal irradiance by more than this fraction of ``pi L`` (the horizontal
        irradiance of a uniform sky of that radiance: the sun is weighed against the sky's
        own light), or the sun's direction by more than ``sun_direction_threshold_deg``.
    max_interval_s : float
        Send anyway after this long, so clients see that the server is alive.
    sun_direction_threshold_deg : float
        The sun's direction is not smoothed (the newest is kept); a move larger than this
        since the last vector sent is sent.
    """

    time_constant_s: float = 2.0
    change_threshold: float = 0.002
    max_interval_s: float = 5.0
    sun_direction_threshold_deg: float = 0.05
    value: np.ndarray | None = None
    sun: np.ndarray | None = None  # (3,) smoothed normal irradiance, W/m^2; None: no sun meter
    sun_direction: np.ndarray | None = None  # (3,) the newest, unit (zeros: none)
    _time_s: float = 0.0
    _sent: np.ndarray | None = None
    _sent_sun: np.ndarray | None = None
    _sent_sun_direction: np.ndarray | None = None
    _sent_time_s: float = -math.inf
    _sent_flags: object = None

    def reset(self) -> None:
        self.value = None
        self.sun = None
        self.sun_direction = None
        self._sent = None
        self._sent_sun = None
        self._sent_sun_direction = None
        self._sent_time_s = -math.inf
        self._sent_flags = None

    def update(self, radiance: np.ndarray, time_s: float,
               sun_irradiance: np.ndarray | None = None,
               sun_direction: np.ndarray | None = None) -> np.ndarray:
        """Fold in one measurement (n, 3) taken at ``time_s``, and the sun's normal irradiance
        (3,) W/m^2 and direction (3,) when there is a sun meter; returns the smoothed vector."""
        radiance = np.asarray(radiance, dtype=np.float64)
        fresh = self.value is None or self.value.shape != radiance.shape
        if fresh:
            self.value = radiance.copy()
            alpha = 1.0
        else:
            dt = max(0.0, time_s - self._time_s)
            tau = self.time_constant_s
            alpha = 1.0 - math.exp(-dt / tau) if tau > 0 else 1.0
            self.value += alpha * (radiance - self.value)
        if sun_irradiance is not None:
            e = np.asarray(sun_irradiance, dtype=np.float64).reshape(3)
            if self.sun is None or fresh:
                self.sun = e.copy()
            else:
                self.sun += alpha * (e - self.sun)
            self.sun_direction = (np.zeros(3) if sun_direction is None else
                                  np.asarray(sun_direction, dtype=np.float64).reshape(3))
        self._time_s = time_s
        return self.value

    def should_send(self, now_s: float, flags: object = None) -> bool:
        """Whether the current value differs enough from the last one sent."""
        if self.value is None:
            return False
        if self._sent is None or flags != self._sent_flags:
            return True
        if now_s - self._sent_time_s >= self.max_interval_s:
            return True
        scale = max(float(np.mean(np.abs(self._sent))), 1e-9)
        if float(np.max(np.abs(self.value - self._sent))) > self.change_threshold * scale:
            return True
        if self.sun is None:
            return False
        if self._sent_sun is None or self._sent_sun_direction is None:
            return True
        if float(np.max(np.abs(self.sun - self._sent_sun))) > \
                self.change_threshold * math.pi * scale:
            return True
        had, has = bool(np.any(self._sent_sun_direction)), bool(np.any(self.sun_direction))
        if had != has:  # the sun rose or set
            return True
        if not has:
            return False
        cos = float(np.clip(self.sun_direction @ self._sent_sun_direction, -1.0, 1.0))
        return math.degrees(math.acos(cos)) > self.sun_direction_threshold_deg

    def mark_sent(self, now_s: float, flags: object = None) -> None:
        self._sent = None if self.value is None else self.value.copy()
        self._sent_sun = None if self.sun is None else self.sun.copy()
        self._sent_sun_direction = (None if self.sun_direction is None
                                    else self.sun_direction.copy())
        self._sent_time_s = now_s
        self._sent_flags = flags
