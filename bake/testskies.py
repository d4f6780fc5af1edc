"""The light vectors a build's stacks are fitted to and checked on: the test skies (which
choose each stack's rank and check it after encoding), the held-out skies (tests and
benchmarks only), the prior's broad set of CIE skies, and the lights those skies can select.

All follow the site's real sun path. Since the client draws the sun itself (protocol version
2, docs/sun.md) the skies are *without* the sun's disc by default; ``sun_in_patch`` skies (a
version-1 light vector, the disc in the patch that holds it) remain for measuring older
builds and for :func:`sun_path_selectable`. Light vectors are (n, 3) mean radiances per dome
patch in W/(m^2 sr).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from daylit.selection import select_lights


@dataclass
class TestSky:
    """A named light vector ``r`` (n, 3) in W/(m^2 sr) per dome patch."""

    name: str
    r: np.ndarray  # (n, 3)


def selectable_lights(site, dome_vertices, solid_angles, m, skies) -> np.ndarray:
    """The lights a site's skies can select: every patch the sun passes through in a year
    (every 10 minutes while it is up); the ``m`` brightest lights of a clear sky with the sun
    anywhere on that path (every 5 days, every 20 minutes: the sun's patch and its brightest
    neighbours, which a clear sky selects); and those of each of ``skies`` (light vectors
    (n, 3): the prior's CIE skies, whose overcast types pick lights near the zenith).
    Sorted indices."""
    import pandas as pd

    from daylit import sky as sky_model
    from daylit.spherical import PatchLookup

    def sun_path(freq: str, days: int):
        times = pd.date_range("2025-01-01", "2026-01-01", freq=freq, inclusive="left",
                              tz=site["timezone"])
        times = times[(times.day_of_year - 1) % days == 0]
        az, el = sky_model.sun_positions(
            site["latitude_deg"], site["longitude_deg"], site["elevation_m"], times
        )
        return az[el > 0.0], el[el > 0.0]

    az, el = sun_path("10min", 1)
    chosen = set(PatchLookup(dome_vertices)(sky_model.direction_from_azimuth_elevation(az, el)))
    for az, el in zip(*sun_path("20min", 5), strict=True):
        clear = sky_model.clear_sky(az, el)
        r = sky_model.patch_mean_radiance(clear, dome_vertices, samples_per_side=6)
        chosen |= set(select_lights(r, solid_angles, m).tolist())
    for r in skies:
        chosen |= set(select_lights(r, solid_angles, m).tolist())
    return np.array(sorted(int(i) for i in chosen), dtype=int)


SUN_PATH_SELECTED_LIGHTS = 1  # the sun's patch: what fixes the selectable lights


def sun_path_selectable(site, dome_vertices, solid_angles) -> np.ndarray:
    """The lights the sun-bounce stacks have columns for (``compression.selectable_lights``):
    :func:`selectable_lights` with one selected light on the site's skies with the sun in its
    patch (every patch the sun passes through in a year, and the brightest patch of each
    prior and test sky). The same set the views' selection fixed while they selected the
    sun's patch (builds of 2026-11-24 before the views were fitted without the disc).
    Sorted indices."""
    training = prior_skies(site, dome_vertices, sun_in_patch=True) + [
        s.r for s in test_skies(site, dome_vertices, sun_in_patch=True)
    ]
    return selectable_lights(
        site, dome_vertices, solid_angles, SUN_PATH_SELECTED_LIGHTS, training
    )


def _sun_path(site) -> list[tuple[float, float]]:
    """(azimuth, elevation) of the sun at this site: solstices and equinox at 9, 12, 15 h,
    only where it is at least 5 degrees up."""
    import datetime as dt
    import zoneinfo

    from daylit import sky as skies

    tz = zoneinfo.ZoneInfo(site["timezone"])
    out = []
    for month, day in ((6, 21), (3, 20), (12, 21)):
        for hour in (9, 12, 15):
            when = dt.datetime(2025, month, day, hour, 0, tzinfo=tz)
            az, el = skies.sun_position(
                site["latitude_deg"], site["longitude_deg"], site["elevation_m"], when
            )
            if el >= 5.0:
                out.append((az, el))
    return out


def _cie_sky(sky_type: int, az: float, el: float):
    """A CIE general sky with a sun disk whose strength follows the type (none if overcast)."""
    from daylit import sky as skies

    clear = skies.clear_sky(az, el)
    sun = None if sky_type <= 5 else tuple(np.asarray(clear.sun_radiance) * (sky_type - 5) / 10)
    return skies.CIESky(
        sky_type=sky_type,
        sun_azimuth_deg=az,
        sun_elevation_deg=el,
        zenith_radiance=(18.0, 22.0, 30.0),
        sun_radiance=sun,
    )


def _vector(sky, dome_vertices, sun_in_patch: bool, samples_per_side: int = 12) -> np.ndarray:
    """A sky's light vector: with its sun's disc in the patch that holds it (a version-1
    vector, the kiosk's) or without it (the sky a version-2 client relights with)."""
    from daylit import sky as skies

    return skies.patch_mean_radiance(
        sky, dome_vertices, samples_per_side=samples_per_side, include_sun=sun_in_patch
    )


def _sky_name(name: str, sun_in_patch: bool) -> str:
    return name if sun_in_patch or name in ("uniform", "overcast") else f"{name} sky"


def test_skies(site, dome_vertices, sun_in_patch: bool = False) -> list[TestSky]:
    """Skies that choose k and are checked after encoding: uniform, CIE overcast, clear skies
    with the sun where it really goes at this site, and partly cloudy CIE skies (types 7, 9
    and 10) with the sun at a third of those positions.

    Without ``sun_in_patch`` (the default) the skies are what a client relights the basis
    stacks with now that it draws the sun itself (protocol version 2, docs/sun.md): the sky
    *without* the sun's disc (the circumsolar glow stays), named ``"clear 94,50 sky"``. With
    it, the sun's disc is in its patch, as a version-1 light vector carries it (the fixed
    views' skies: ``"clear 94,50"``)."""
    from daylit import sky as skies

    def sky(name, model):
        return TestSky(_sky_name(name, sun_in_patch), _vector(model, dome_vertices, sun_in_patch))

    out = [sky("uniform", skies.UniformSky()), sky("overcast", skies.overcast_sky())]
    path = _sun_path(site)
    for az, el in path:
        out.append(sky(f"clear {az:.0f},{el:.0f}", skies.clear_sky(az, el)))
    for j, sky_type in enumerate((7, 9, 10)):
        for az, el in path[j::3]:
            out.append(sky(f"CIE {sky_type} {az:.0f},{el:.0f}", _cie_sky(sky_type, az, el)))
    if not sun_in_patch:
        # Without its disc a clear sky is brightest in the sun's aureole, whose soft shadows
        # move with the sun: checked along its whole yearly path, not at nine positions (a
        # rank chosen on the nine alone missed the ground's shadow ratio on a held-out clear
        # sky: docs/benchmarks.md, "Figures behind choices in the code").
        for when, az, el in _yearly_sun_path(site, days=30, hours=2.0, named=True):
            out.append(TestSky(f"clear {when} sky", _vector(
                skies.clear_sky(az, el), dome_vertices, False, samples_per_side=6)))
    return out


def held_out_skies(site, dome_vertices, sun_in_patch: bool = False) -> list[TestSky]:
    """Skies that did *not* choose k, to check a build against (tests, benchmarks): a clear
    sky with the sun where it really is at the site at a time no test sky used (10 May,
    10:40), the same hour under an intermediate sky (CIE type 9) and a turbid clear one
    (type 7), and a partly cloudy sky (CIE type 7, the sun at azimuth 205, elevation 27 as
    in a January afternoon). Without or with the sun's disc, as :func:`test_skies`."""
    import pandas as pd

    from daylit import sky as skies

    when = pd.DatetimeIndex([pd.Timestamp("2025-05-10 10:40", tz=site["timezone"])])
    az, el = skies.sun_positions(
        site["latitude_deg"], site["longitude_deg"], site["elevation_m"], when
    )
    az, el = float(az[0]), float(el[0])
    partly = skies.CIESky(
        sky_type=7,
        sun_azimuth_deg=205.0,
        sun_elevation_deg=27.0,
        zenith_radiance=(26.0, 28.0, 33.0),
        sun_radiance=tuple(np.array([520.0, 500.0, 470.0]) / skies.SUN_SOLID_ANGLE_SR),
    )
    models = {
        "clear 10 May 10:40": skies.clear_sky(az, el),
        "intermediate 10 May 10:40": _cie_sky(9, az, el),
        "turbid 10 May 10:40": skies.clear_sky(az, el, turbid=True),
        "partly cloudy": partly,
    }
    return [
        TestSky(_sky_name(name, sun_in_patch), _vector(model, dome_vertices, sun_in_patch))
        for name, model in models.items()
    ]


def prior_skies(site, dome_vertices, sun_in_patch: bool = False) -> list[np.ndarray]:
    """The broad set of light vectors the low-rank base is fitted to: all 15 CIE general sky
    types with the sun at every position of the site's sun path (about 135 skies), without
    or with the sun's disc as :func:`test_skies`; without it, also the 15 types with the sun
    all along its yearly path (:func:`_yearly_sun_path`): a sky without the disc is brightest
    in the sun's aureole, and a base fitted to a few sun positions draws the aureole's
    shadows poorly elsewhere."""
    positions = _sun_path(site)
    if not sun_in_patch:
        positions = positions + _yearly_sun_path(site, days=30, hours=2.0)
    return [
        _vector(_cie_sky(t, az, el), dome_vertices, sun_in_patch, samples_per_side=6)
        for t in range(1, 16)
        for az, el in positions
    ]


def _yearly_sun_path(site, days: int = 15, hours: float = 1.0, named: bool = False) -> list:
    """(azimuth, elevation) of the sun every ``days`` days of a year (from 1 January), every
    ``hours`` hours of local time (from midnight), where it is at least 2 degrees up; with
    ``named``, (``"Mar 02 10:00"``, azimuth, elevation)."""
    import pandas as pd

    from daylit import sky as skies

    times = pd.date_range("2025-01-01", "2026-01-01", freq=f"{int(hours * 60)}min",
                          inclusive="left", tz=site["timezone"])
    times = times[(times.day_of_year - 1) % days == 0]
    az, el = skies.sun_positions(
        site["latitude_deg"], site["longitude_deg"], site["elevation_m"], times
    )
    up = el >= 2.0
    if named:
        return [(t.strftime("%b %d %H:%M"), float(a), float(e))
                for t, a, e in zip(times[up], az[up], el[up], strict=True)]
    return [(float(a), float(e)) for a, e in zip(az[up], el[up], strict=True)]
