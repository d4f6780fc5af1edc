"""Whether the build's sun-bounce images cover today (``daylit bake --sun-bounce-dates``,
``daylit sun-bounce``; docs/sun.md, "The sun's bounce for the dates served").

A build made for some dates has no sun-bounce images for the patches the sun crosses only on
other dates: a client then draws the sun, the sky and their shadows but not the light the sun
throws off the ground and walls. The operator is told at start and in ``/api/status``, ahead
of the last date, so that the images for the next dates are made in time.
"""

from __future__ import annotations

import datetime as dt
import zoneinfo

# Days before the last date from which the server warns at start.
WARN_DAYS = 7


def coverage(manifest: dict, now_s: float) -> dict:
    """``sun_bounce`` of ``/api/status``: ``dates`` (``[first, last]``, local dates of the
    site, or None: every patch of the year) and ``days_left``, the days from today (the
    site's local date at ``now_s``, seconds since the epoch) to the last date, the last one
    counted (0: today is past it or before the first; None with no dates)."""
    dates = manifest.get("compression", {}).get("sun_bounce_dates")
    if dates is None:
        return {"dates": None, "days_left": None}
    today = dt.datetime.fromtimestamp(now_s, zoneinfo.ZoneInfo(manifest["scene"]["timezone"]))
    today = today.date()
    first, last = (dt.date.fromisoformat(d) for d in dates)
    days_left = (last - today).days + 1 if first <= today <= last else 0
    return {"dates": list(dates), "days_left": days_left}


def warning(manifest: dict, now_s: float) -> str | None:
    """The operator's warning at start, or None when today is covered for more than
    :data:`WARN_DAYS` days (or every date is)."""
    state = coverage(manifest, now_s)
    if state["dates"] is None or state["days_left"] > WARN_DAYS:
        return None
    first, last = state["dates"]
    what = ("today is not among them: visitors see no sun bounce"
            if state["days_left"] == 0 else
            f"{state['days_left']} day{'s' if state['days_left'] != 1 else ''} left")
    return (f"the build's sun-bounce images are for {first} to {last}, {what}; make them for "
            "the next dates (daylit sun-bounce SCENE BUILD --dates FIRST..LAST) and restart "
            "the server")
