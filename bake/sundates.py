"""The dates a build's sun-bounce images are made for (``daylit bake --sun-bounce-dates``).

A build's sun-bounce stacks hold a column for every patch the sun crosses in a year, and
by default each of those patches gets its images (docs/sun.md, item 5): about four fifths of
a final bake's compression time and of what the server offers. A site open for a season, or
a server whose operator makes them again from the masters ahead of the sun, needs only the
patches the sun crosses on the dates it serves: the others keep their columns in the EXR
masters and get no files (``null`` in the manifest's tables, as the patches the sun never
reaches; a client draws no sun bounce there, as before).
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass

import numpy as np

# How often the sun is placed on the dome over each day: it moves about 0.5 degrees in 2
# minutes, so no patch of a dome of 400 lights (about 8 degrees across) is crossed unseen
# except at a corner it leaves within that time.
SAMPLE_STEP = "2min"


@dataclass(frozen=True)
class SunBounceDates:
    """The first and last local dates (inclusive) whose sun patches get their images."""

    first: dt.date
    last: dt.date

    @classmethod
    def parse(cls, text: str) -> SunBounceDates:
        """``"2026-06-01..2026-08-31"`` (or one date, ``"2026-06-21"``). Raises ValueError
        saying what is wrong."""
        parts = text.split("..")
        if len(parts) not in (1, 2) or not all(p.strip() for p in parts):
            raise ValueError(f"expected FIRST..LAST as ISO dates (2026-06-01..2026-08-31), "
                             f"got {text!r}")
        try:
            dates = [dt.date.fromisoformat(p.strip()) for p in parts]
        except ValueError:
            raise ValueError(f"expected ISO dates YYYY-MM-DD (2026-06-01..2026-08-31), "
                             f"got {text!r}") from None
        first, last = dates[0], dates[-1]
        if last < first:
            raise ValueError(f"the last date {last} is before the first {first}")
        if (last - first).days >= 366:  # 366 dates inclusive: a leap year
            raise ValueError(f"{first}..{last} is more than a year: leave the option out for "
                             "every patch the sun crosses in a year")
        return cls(first, last)

    def as_list(self) -> list[str]:
        """``["FIRST", "LAST"]``: the manifest's ``compression.sun_bounce_dates``."""
        return [self.first.isoformat(), self.last.isoformat()]

    def patches(self, site, dome_vertices: np.ndarray) -> list[int]:
        """The dome patches the sun is in while it is up, on these dates in ``site``'s time
        zone (``site``: a :class:`bake.scene.Site`, or anything with its ``timezone``,
        ``latitude_deg``, ``longitude_deg`` and ``elevation_m``), sampled every
        :data:`SAMPLE_STEP`. Sorted indices; empty when the sun is never up then."""
        import pandas as pd

        from daylit import sky as skies
        from daylit.spherical import PatchLookup

        times = pd.date_range(pd.Timestamp(self.first),
                              pd.Timestamp(self.last + dt.timedelta(days=1)),
                              freq=SAMPLE_STEP, inclusive="left", tz=site.timezone)
        az, el = skies.sun_positions(site.latitude_deg, site.longitude_deg, site.elevation_m,
                                     times)
        up = el > 0.0
        if not up.any():
            return []
        found = PatchLookup(dome_vertices)(skies.direction_from_azimuth_elevation(az[up], el[up]))
        return sorted({int(p) for p in found if p >= 0})


def lights_for_dates(selectable: np.ndarray, patches: list[int], shared=None) -> np.ndarray:
    """The sun-path lights (``selectable``, sorted) that get sun-bounce images for the sun
    in ``patches``: those patches, and with ``shared`` (:class:`bake.sunshare.SharedImages`)
    every member of a group any of them is in (a group's image is made from all its
    members' columns, and each member is judged on it). Sorted indices."""
    chosen = set(patches) & {int(i) for i in selectable}
    if shared is not None:
        for members in shared.groups.values():
            if chosen.intersection(members):
                chosen.update(members)
    return np.array(sorted(chosen), dtype=int)


def check_sun_up(site, dates: SunBounceDates) -> None:
    """Refuse (``BakeError``), before any work, dates on which the sun never rises at
    ``site`` (a :class:`bake.scene.Site`): its sun-bounce stacks would have no image."""
    from bake.dome import Dome
    from bake.errors import BakeError

    if not dates.patches(site, Dome.for_light_count(site.settings.lights).vertices):
        first, last = dates.as_list()
        raise BakeError(f"the sun is never up at this site from {first} to {last}: choose "
                        "dates when it is, or leave --sun-bounce-dates out")
