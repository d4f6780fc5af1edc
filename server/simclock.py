"""The simulated sky's clock (``[sim] start`` and ``clock_speed``, docs/server.md).

``auto``, the default, keeps the demo in daylight whenever it is run: it starts now if the sun
is up at the site (at least ``DAYLIGHT_ELEVATION_DEG``), else at the next ``MORNING_HOUR``
o'clock local time there, and when the simulated sun sets it goes on at the next morning's
``MORNING_HOUR`` again. ``now`` and an ISO date-time follow the clock through the night.
"""

from __future__ import annotations

import datetime as dt
import math
import time
from dataclasses import dataclass, field
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

import numpy as np

# The "auto" clock: the sun counts as up from this elevation (the simulated sky is in full
# daylight from 2 degrees), and a new day starts at this local hour.
DAYLIGHT_ELEVATION_DEG = 5.0
MORNING_HOUR = 10


@dataclass
class SimClock:
    """Simulated time: ``start_s`` (Unix seconds) at wall time ``wall_start_s``, running at
    ``speed`` simulated seconds per wall second."""

    start_s: float
    speed: float = 1.0
    wall_start_s: float = field(default_factory=time.time)

    def now(self, wall_s: float | None = None) -> float:
        wall = time.time() if wall_s is None else wall_s
        return self.start_s + self.speed * (wall - self.wall_start_s)

    def jump(self, sky_time_s: float, wall_s: float | None = None) -> None:
        """Go on from ``sky_time_s`` at wall time ``wall_s`` (now), at the same speed."""
        self.start_s = sky_time_s
        self.wall_start_s = time.time() if wall_s is None else wall_s


def site_zone(timezone: str) -> ZoneInfo:
    try:
        return ZoneInfo(timezone)
    except (ZoneInfoNotFoundError, ValueError):
        raise ValueError(f"unknown time zone {timezone!r} in the manifest") from None


def sun_elevations_deg(latitude_deg: float, longitude_deg: float, elevation_m: float,
                times_s: np.ndarray) -> np.ndarray:
    """Apparent sun elevation (degrees) at the site at Unix times (vectorised SPA)."""
    import pandas as pd

    from daylit.sky import sun_positions

    times = pd.DatetimeIndex(pd.to_datetime(np.asarray(times_s, dtype=np.float64), unit="s",
                                            utc=True))
    return sun_positions(latitude_deg, longitude_deg, elevation_m, times)[1]


def next_morning(latitude_deg: float, longitude_deg: float, elevation_m: float,
                 timezone: str, after_s: float) -> float:
    """The first ``MORNING_HOUR`` o'clock local time at the site after ``after_s``.

    Where the sun is below ``DAYLIGHT_ELEVATION_DEG`` then (a polar winter), the time of that
    day's highest sun instead: the brightest the day gets.
    """
    zone = site_zone(timezone)
    local = dt.datetime.fromtimestamp(after_s, zone)
    morning = dt.datetime.combine(local.date(), dt.time(MORNING_HOUR), zone)
    if morning.timestamp() <= after_s:
        morning = dt.datetime.combine(local.date() + dt.timedelta(days=1), dt.time(MORNING_HOUR),
                                      zone)
    start_s = morning.timestamp()
    if sun_elevations_deg(latitude_deg, longitude_deg, elevation_m, [start_s])[0] >= \
            DAYLIGHT_ELEVATION_DEG:
        return start_s
    midnight_s = dt.datetime.combine(morning.date(), dt.time(0), zone).timestamp()
    times = midnight_s + np.arange(0.0, 86400.0, 600.0)
    elevations_deg = sun_elevations_deg(latitude_deg, longitude_deg, elevation_m, times)
    return float(times[np.argmax(elevations_deg)])


def daylight_start(latitude_deg: float, longitude_deg: float, elevation_m: float,
                   timezone: str, now_s: float | None = None) -> float:
    """``start = "auto"``: now if the sun is up at the site, else the next morning there."""
    now_s = time.time() if now_s is None else now_s
    if sun_elevations_deg(latitude_deg, longitude_deg, elevation_m, [now_s])[0] >= \
            DAYLIGHT_ELEVATION_DEG:
        return now_s
    return next_morning(latitude_deg, longitude_deg, elevation_m, timezone, now_s)


def sunset_after(latitude_deg: float, longitude_deg: float, elevation_m: float,
                 start_s: float, horizon_s: float = 2 * 86400.0, step_s: float = 300.0) -> float:
    """When the sun, up at some time after ``start_s``, next goes below
    ``DAYLIGHT_ELEVATION_DEG`` (to ``step_s``); +inf when it does not set within ``horizon_s``
    (midnight sun) or never rises (polar night)."""
    times = start_s + np.arange(0.0, horizon_s, step_s)
    elevations_deg = sun_elevations_deg(latitude_deg, longitude_deg, elevation_m, times)
    up = elevations_deg >= DAYLIGHT_ELEVATION_DEG
    if not up.any():
        return math.inf
    first_up = int(np.argmax(up))
    down = np.flatnonzero(~up[first_up:])
    return math.inf if down.size == 0 else float(times[first_up + down[0]])


def parse_start(text: str | None, timezone: str) -> float:
    """Unix time from ``"now"``/None or an ISO date-time; a naive time is local at the site.

    (``"auto"`` depends on the site's sun: :func:`daylight_start`.)
    """
    if text is None or text == "now":
        return time.time()
    try:
        when = dt.datetime.fromisoformat(text)
    except ValueError:
        raise ValueError(
            f"sim start {text!r} is not an ISO date-time such as 2026-06-21T10:00"
        ) from None
    if when.tzinfo is None:
        when = when.replace(tzinfo=site_zone(timezone))
    return when.timestamp()
