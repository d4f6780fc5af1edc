"""daylit.sun against answers it did not produce: the NREL SPA paper's test vector, pvlib's
Ineichen through its own Location API, and a colour law written out here."""

import datetime as dt

import numpy as np
import pandas as pd
import pytest

from daylit import sky, sun


def test_spa_reproduces_the_nrel_test_vector():
    # Reda & Andreas (2004), Table A5.1: Golden, Colorado, 2003-10-17 12:30:30 at UTC-7.
    when = dt.datetime(2003, 10, 17, 12, 30, 30, tzinfo=dt.timezone(dt.timedelta(hours=-7)))
    pos = sun.sun_position(39.742476, -105.1786, 1830.14, when, pressure_mbar=820.0,
                           temperature_c=11.0, delta_t_s=67.0)
    assert pos.apparent_zenith_deg[0] == pytest.approx(50.111622, abs=3e-4)
    assert pos.azimuth_deg[0] == pytest.approx(194.340241, abs=3e-4)
    assert pos.apparent_elevation_deg[0] == pytest.approx(90.0 - 50.111622, abs=3e-4)


def test_sky_sun_position_still_answers_in_azimuth_and_elevation():
    when = dt.datetime(2003, 10, 17, 19, 30, 30, tzinfo=dt.UTC)
    az, el = sky.sun_position(39.742476, -105.1786, 1830.14, when)
    # At the site's standard pressure (about 812 mbar) and 12 C refraction differs from the
    # paper's 820 mbar and 11 C by well under 0.001 degrees this high up.
    assert az == pytest.approx(194.340241, abs=1e-3)
    assert el == pytest.approx(90.0 - 50.111622, abs=1e-3)
    with pytest.raises(ValueError, match="timezone"):
        sky.sun_position(0.0, 0.0, 0.0, dt.datetime(2026, 1, 1))


def test_clear_sky_irradiance_is_pvlibs_ineichen_at_the_given_turbidity():
    from pvlib.location import Location

    site = Location(34.4686, 135.8194, altitude=100.0, tz="Asia/Tokyo")
    times = pd.date_range("2026-06-21 05:00", "2026-06-21 19:00", freq="90min",
                          tz="Asia/Tokyo")
    expected = site.get_clearsky(times, model="ineichen", linke_turbidity=4.0)
    pos = sun.sun_position(34.4686, 135.8194, 100.0, times)
    dni, dhi = sun.clear_sky_irradiance(pos.apparent_zenith_deg,
                                        times.day_of_year.to_numpy(), 100.0, 4.0)
    np.testing.assert_allclose(dni, expected["dni"].to_numpy(), rtol=2e-3, atol=0.5)
    np.testing.assert_allclose(dhi, expected["dhi"].to_numpy(), rtol=2e-3, atol=0.5)
    assert dni.max() > 800.0 and dni[0] < dni.max() / 3  # noon bright, early morning dim


def test_clear_sky_is_dark_below_the_horizon():
    dni, dhi = sun.clear_sky_irradiance([95.0, 120.0], [172, 172], 0.0)
    assert dni.tolist() == [0.0, 0.0] and dhi.tolist() == [0.0, 0.0]


def test_sun_colour_has_unit_luminance_and_reddens_toward_the_horizon():
    for elevation in (60.0, 10.0, 3.0):
        c = sun.sun_colour(elevation)
        assert 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2] == pytest.approx(1.0)
    # Written out: air mass 1 / sin(10 deg), extinction 0.02, 0.05, 0.11 beyond air mass 1.
    m = 1.0 / np.sin(np.radians(10.0))
    warm = np.exp(-np.array([0.02, 0.05, 0.11]) * (m - 1.0))
    np.testing.assert_allclose(sun.sun_colour(10.0), warm / (warm @ [0.2126, 0.7152, 0.0722]))
    assert sun.sun_colour(3.0)[2] < sun.sun_colour(10.0)[2] < sun.sun_colour(60.0)[2]


def test_sun_path_interpolates_spa_between_knots():
    path = sun.SunPath(34.4686, 135.8194, 100.0)
    t0 = dt.datetime(2026, 6, 21, 0, 0, 17, tzinfo=dt.UTC).timestamp()
    for t in t0 + np.array([0.0, 13.7, 29.9, 600.0]):
        exact = sun.sun_position(34.4686, 135.8194, 100.0, [t])
        got = path.at(float(t))
        angle = np.degrees(np.arccos(np.clip(exact.direction[0] @ got.direction, -1, 1)))
        assert angle < 1e-3
        assert got.apparent_elevation_deg == pytest.approx(exact.apparent_elevation_deg[0],
                                                           abs=1e-3)
    assert sun.SunSource.MODEL == 2 and sun.SunSource.MEASURED.label == "measured"
