"""The sun as its own light: where it is, how bright a clear sky lets it be, what colour.

- :func:`sun_position`: NREL SPA (Reda & Andreas 2004) through pvlib, with the site's
  pressure, temperature and delta T: azimuth (degrees clockwise from north), apparent
  (refracted) zenith and elevation (degrees).
- :func:`clear_sky_irradiance`: the Ineichen-Perez clear-sky model (pvlib.clearsky.ineichen)
  at a given Linke turbidity (3 by default; pvlib's monthly turbidity table is *not* used, so
  the answer needs no data files): the direct normal irradiance (DNI) and the diffuse
  horizontal irradiance (DHI), W/m^2.
- :func:`sun_colour`: the sun's RGB colour, warming with air mass (the law of
  ``daylit.sky.clear_sky``), scaled to luminance 1, so ``dni_rgb = dni * sun_colour(...)``.
- :class:`SunPath`: the same, cached per site for a stream of frame times (SPA costs about
  4 ms a call; positions are interpolated between 30-second knots, well under 0.001 degrees).
- :class:`SunSource`: how a frame's sun was obtained (on the wire: docs/protocol.md).

Directions follow docs/architecture.md, "Frames, units, the index rule": site
frame +X east, +Y up, -Z north.
"""

from __future__ import annotations

import datetime as dt
import math
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from daylit.sky import direction_from_azimuth_elevation, sun_warmth

DEFAULT_LINKE_TURBIDITY = 3.0
DEFAULT_TEMPERATURE_C = 12.0
DEFAULT_DELTA_T_S = 67.0
LUMINANCE_RGB = np.array([0.2126, 0.7152, 0.0722])  # Rec. 709 / sRGB primaries
ATMOSPHERIC_REFRACTION_DEG = 0.5667  # SPA's refraction at the apparent sunrise/sunset


class SunSource(IntEnum):
    """Where a frame's sun came from (the LIGHT message's ``sun source`` byte)."""

    NONE = 0  # below the horizon: no sun
    MEASURED = 1  # an HDR frame saw the disc unclipped: measured
    MODEL = 2  # the camera clipped it: clear-sky model times the visible fraction
    SCENE = 3  # estimated from the site camera's view of the scene (server.sceneestimate)

    @property
    def label(self) -> str:
        return self.name.lower()


def _unix_seconds(when) -> np.ndarray:
    """Unix seconds (float64 array) from a tz-aware datetime, a pandas index or numbers."""
    if isinstance(when, dt.datetime):
        if when.tzinfo is None:
            raise ValueError("sun_position needs a timezone-aware datetime")
        return np.array([when.timestamp()])
    if hasattr(when, "tz"):  # a pandas DatetimeIndex
        if when.tz is None:
            raise ValueError("sun_position needs timezone-aware times")
        return np.array([t.timestamp() for t in when], dtype=np.float64)
    return np.atleast_1d(np.asarray(when, dtype=np.float64))


@dataclass(frozen=True)
class SunPosition:
    """Arrays ``(m,)`` in degrees: azimuth (clockwise from north), apparent zenith and
    apparent elevation (refracted); ``direction`` (m, 3): unit site directions."""

    azimuth_deg: np.ndarray
    apparent_zenith_deg: np.ndarray
    apparent_elevation_deg: np.ndarray

    @property
    def direction(self) -> np.ndarray:
        return direction_from_azimuth_elevation(self.azimuth_deg, self.apparent_elevation_deg)


def site_pressure_mbar(elevation_m: float) -> float:
    """Standard-atmosphere pressure at a height (pvlib.atmosphere.alt2pres), millibar."""
    from pvlib import atmosphere

    return float(atmosphere.alt2pres(elevation_m)) / 100.0


def sun_position(
    latitude_deg: float,
    longitude_deg: float,
    elevation_m: float,
    when,
    pressure_mbar: float | None = None,
    temperature_c: float = DEFAULT_TEMPERATURE_C,
    delta_t_s: float = DEFAULT_DELTA_T_S,
) -> SunPosition:
    """The sun's position by NREL SPA (pvlib's numpy implementation).

    Parameters
    ----------
    when : tz-aware datetime, pandas DatetimeIndex (tz-aware), or Unix seconds (m,)
    pressure_mbar : float, optional
        Air pressure for refraction; None: the standard atmosphere at ``elevation_m``.
    temperature_c : float
        Air temperature for refraction.
    delta_t_s : float
        TT - UT1, seconds (67 s around 2003, 69 s in the 2020s).
    """
    from pvlib import spa

    times_s = _unix_seconds(when)
    pressure = site_pressure_mbar(elevation_m) if pressure_mbar is None else pressure_mbar
    theta, _, elev, _, azimuth = spa.solar_position(
        times_s, latitude_deg, longitude_deg, elevation_m, pressure, temperature_c,
        delta_t_s, ATMOSPHERIC_REFRACTION_DEG, numthreads=0,
    )[:5]
    return SunPosition(np.asarray(azimuth, float), np.asarray(theta, float),
                       np.asarray(elev, float))


def clear_sky_irradiance(
    apparent_zenith_deg, day_of_year, elevation_m: float,
    linke_turbidity: float = DEFAULT_LINKE_TURBIDITY,
) -> tuple[np.ndarray, np.ndarray]:
    """Ineichen-Perez clear-sky DNI and DHI, W/m^2, arrays like ``apparent_zenith_deg``.

    Air mass: Kasten-Young (1989) on the apparent zenith, times the site's standard pressure;
    extraterrestrial irradiance: Spencer (1971) for the day of the year. Zero with the sun
    below the horizon.
    """
    from pvlib import atmosphere, clearsky, irradiance

    zenith = np.atleast_1d(np.asarray(apparent_zenith_deg, dtype=float))
    doy = np.broadcast_to(np.asarray(day_of_year, dtype=float), zenith.shape)
    relative = atmosphere.get_relative_airmass(zenith)
    absolute = atmosphere.get_absolute_airmass(relative, atmosphere.alt2pres(elevation_m))
    extra = irradiance.get_extra_radiation(doy)
    with np.errstate(invalid="ignore", divide="ignore"):
        cs = clearsky.ineichen(zenith, absolute, linke_turbidity, altitude=elevation_m,
                               dni_extra=extra)
    dni = np.nan_to_num(np.asarray(cs["dni"], float))
    dhi = np.nan_to_num(np.asarray(cs["dhi"], float))
    up = zenith < 90.0
    return np.where(up, dni, 0.0), np.where(up, dhi, 0.0)


def sun_colour(apparent_elevation_deg: float) -> np.ndarray:
    """The direct sun's RGB colour (3,) at this elevation, luminance ``0.2126 R + 0.7152 G +
    0.0722 B = 1``: whiter high up, redder through more air mass (``daylit.sky.sun_warmth``)."""
    warm = sun_warmth(apparent_elevation_deg)
    return warm / float(LUMINANCE_RGB @ warm)


def day_of_year(times_s: np.ndarray) -> np.ndarray:
    """Day of the year (1-366, fractional) of Unix times, UTC."""
    times_s = np.atleast_1d(np.asarray(times_s, dtype=float))
    out = np.empty_like(times_s)
    for i, t in enumerate(times_s):
        d = dt.datetime.fromtimestamp(t, dt.UTC)
        out[i] = d.timetuple().tm_yday + (d.hour + d.minute / 60.0) / 24.0
    return out


@dataclass
class ClearSun:
    """The sun at one time: position, clear-sky DNI (scalar and RGB) and DHI.

    direction : (3,) unit site direction; dni_w_m2, dhi_w_m2 : float; colour : (3,) RGB of
    luminance 1; ``dni_rgb_w_m2 = dni_w_m2 * colour``.
    """

    azimuth_deg: float
    apparent_elevation_deg: float
    direction: np.ndarray
    dni_w_m2: float
    dhi_w_m2: float
    colour: np.ndarray

    @property
    def dni_rgb_w_m2(self) -> np.ndarray:
        return self.dni_w_m2 * self.colour


@dataclass
class SunPath:
    """The sun over one site, for frame after frame: :meth:`at` a Unix time.

    SPA and Ineichen are evaluated at knots every ``knot_s`` seconds and interpolated
    linearly between them (direction renormalised): the sun moves 0.125 degrees in 30 s along
    an arc whose sagitta is far below 0.001 degrees, and each knot pair is computed once.
    """

    latitude_deg: float
    longitude_deg: float
    elevation_m: float
    linke_turbidity: float = DEFAULT_LINKE_TURBIDITY
    knot_s: float = 30.0
    _knots: dict = field(default_factory=dict, repr=False)

    def _knot(self, k: int) -> tuple[np.ndarray, float, float]:
        if k not in self._knots:
            if len(self._knots) > 64:
                self._knots.clear()
            t = k * self.knot_s
            pos = sun_position(self.latitude_deg, self.longitude_deg, self.elevation_m, [t])
            dni, dhi = clear_sky_irradiance(pos.apparent_zenith_deg, day_of_year([t]),
                                            self.elevation_m, self.linke_turbidity)
            self._knots[k] = (pos.direction[0], float(dni[0]), float(dhi[0]))
        return self._knots[k]

    def at(self, time_s: float) -> ClearSun:
        """The sun at Unix time ``time_s`` (interpolated between knots)."""
        from daylit.sky import azimuth_elevation_from_direction

        k = math.floor(time_s / self.knot_s)
        w = time_s / self.knot_s - k
        d0, dni0, dhi0 = self._knot(k)
        d1, dni1, dhi1 = self._knot(k + 1)
        d = (1.0 - w) * d0 + w * d1
        d = d / np.linalg.norm(d)
        az, el = azimuth_elevation_from_direction(d)
        dni = (1.0 - w) * dni0 + w * dni1
        dhi = (1.0 - w) * dhi0 + w * dhi1
        return ClearSun(float(az), float(el), d, dni, dhi, sun_colour(float(el)))
