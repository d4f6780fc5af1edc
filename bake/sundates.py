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
from pathlib import Path

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

        def midnight(day: dt.date):
            # Where the clocks change at midnight, the day starts at the first time there is.
            return pd.Timestamp(day).tz_localize(site.timezone, nonexistent="shift_forward",
                                                 ambiguous=True)

        times = pd.date_range(midnight(self.first), midnight(self.last + dt.timedelta(days=1)),
                              freq=SAMPLE_STEP, inclusive="left")
        az, el = skies.sun_positions(site.latitude_deg, site.longitude_deg, site.elevation_m,
                                     times)
        up = el > 0.0
        if not up.any():
            return []
        found = PatchLookup(dome_vertices)(skies.direction_from_azimuth_elevation(az[up], el[up]))
        return sorted({int(p) for p in found if p >= 0})


def lights_for_dates(selectable: np.ndarray, patches: list[int], shared=None) -> np.ndarray:
    """The sun-path lights (``selectable``, sorted) whose sun-bounce images are made and
    judged for the sun in ``patches``: those patches, and with ``shared``
    (:class:`bake.sunshare.SharedImages`) every member of a group any of them is in (a
    group's image is made from all its members' columns, and whether a member shares it is
    judged on each, as in a bake for the whole year; which cheaper encodings are tried
    first is sampled from these lights, so an image's encoding may differ from that bake's).
    What the dates do not need is dropped after
    (:func:`keep_patches`). Sorted indices."""
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


def image_files(compact: dict) -> set[str]:
    """The paths of a sun-bounce entry's image files: those of every light with images
    (:func:`bake.downloads.table_files`)."""
    from bake.downloads import table_files

    return table_files(compact["lights"], range(len(compact["lights"]["scale"])))


def keep_patches(result, patches: set[int], out_dir: Path) -> int:
    """Keep of a compressed sun-bounce stack (``result``: :class:`bake.compress.CompactStack`
    written under ``out_dir``) only what the sun in ``patches`` reads: the other lights'
    ``scale``, ``offset`` and ``image`` become null, and the files no kept light reads (the
    own images of a group's members the dates do not reach) are deleted. Its ``shared``
    counts then say what is kept; its ``error`` is still that of every image judged.
    Returns how many images are kept."""
    entry = result.entry
    table = entry["lights"]
    for i, scale in enumerate(table["scale"]):
        if scale is not None and i not in patches:
            table["scale"][i] = table["offset"][i] = None
            if table.get("image") is not None:
                table["image"][i] = None
    needed = image_files(entry)
    kept = []
    for path in result.files:
        if Path(path).relative_to(out_dir).as_posix() in needed:
            kept.append(path)
        else:
            Path(path).unlink()
    result.files = kept
    result.light_bytes = sum(Path(path).stat().st_size for path in kept)
    from bake.compact_reader import image_holders

    lights = [i for i, scale in enumerate(table["scale"]) if scale is not None]
    holders = image_holders(table)
    images = len({holders[i] for i in lights})
    if "shared" in entry:
        entry["shared"]["images"] = images
        entry["shared"]["lights"] = len(lights)
    return images
