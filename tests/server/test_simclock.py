"""The simulated sky's clock: by default ("auto") the demo is in daylight whenever it is run."""

import datetime as dt
from zoneinfo import ZoneInfo

import pytest
from aiohttp import WSMsgType

from server import protocol
from server.app import create_app
from server.config import ConfigError, load_settings
from server.simclock import (
    DAYLIGHT_ELEVATION_DEG,
    daylight_start,
    sun_elevations_deg,
    sunset_after,
)
from server.simsky import SimulatedSky
from tests.server.helpers import settings_for

NARA = (34.4686, 135.8194, 100.0)  # the test build's site
TOKYO = ZoneInfo("Asia/Tokyo")
TROMSO = (69.65, 18.96, 10.0)
OSLO = ZoneInfo("Europe/Oslo")


def local(when_s: float, zone=TOKYO) -> dt.datetime:
    return dt.datetime.fromtimestamp(when_s, zone)


def at(*args, zone=TOKYO) -> float:
    return dt.datetime(*args, tzinfo=zone).timestamp()


@pytest.mark.parametrize(
    ("now", "start"),
    [
        ((2026, 11, 21, 23, 0), (2026, 11, 22, 10, 0)),  # night: the next morning
        ((2026, 11, 21, 3, 30), (2026, 11, 21, 10, 0)),  # before dawn: this morning
        ((2026, 11, 21, 12, 15), (2026, 11, 21, 12, 15)),  # day: now
        ((2026, 6, 21, 18, 0), (2026, 6, 21, 18, 0)),  # a summer evening, sun still up
        ((2026, 12, 31, 17, 30), (2027, 1, 1, 10, 0)),  # dusk on new year's eve
    ],
)
def test_auto_start_is_now_by_day_and_the_next_morning_by_night(now, start):
    assert daylight_start(*NARA, "Asia/Tokyo", at(*now)) == at(*start)


def test_after_sunset_the_auto_clock_goes_on_the_next_morning():
    sim = SimulatedSky.for_site(*NARA, "Asia/Tokyo", start="2026-06-21T17:00",
                                clock_speed=3600.0, size_px=64)
    sim.keep_daylight = True  # what start = "auto" sets
    wall = sim.clock.wall_start_s
    assert local(sim.now(wall)) == dt.datetime(2026, 6, 21, 17, 0, tzinfo=TOKYO)
    sunset = sunset_after(*NARA, at(2026, 6, 21, 17, 0))
    assert 18.5 < (sunset - at(2026, 6, 21, 0, 0)) / 3600 < 19.5  # Nara, midsummer
    assert local(sim.now(wall + 1.0)).hour == 18  # one hour a second
    assert local(sim.now(wall + 3.0)) == dt.datetime(2026, 6, 22, 10, 0, tzinfo=TOKYO)
    assert local(sim.now(wall + 4.0)) == dt.datetime(2026, 6, 22, 11, 0, tzinfo=TOKYO)
    for k in range(5, 60):  # days later: never in the dark
        t = sim.now(wall + k)
        assert sun_elevations_deg(*NARA, [t])[0] > DAYLIGHT_ELEVATION_DEG - 2.0, local(t)
    # "now" and a fixed start do not jump: night is night.
    sim.keep_daylight = False
    assert sim.now(wall + 100.0) == sim.clock.now(wall + 100.0)


def test_polar_night_starts_at_the_brightest_time_and_does_not_jump_about():
    start = daylight_start(*TROMSO, "Europe/Oslo", at(2026, 12, 21, 22, 0, zone=OSLO))
    assert local(start, OSLO).date() == dt.date(2026, 12, 22)
    assert 10 <= local(start, OSLO).hour <= 13  # about noon, the least dark time
    assert sunset_after(*TROMSO, start) == float("inf")  # the sun never rises: nothing to skip


def test_settings_default_to_the_auto_clock():
    s = load_settings()
    assert s.sim.start == "auto" and s.sim.clock_speed == 20.0
    assert load_settings(None, {"sim.start": "now"}).sim.start == "now"
    with pytest.raises(ConfigError, match=r"\[sim\] start must be auto, now or an ISO"):
        load_settings(None, {"sim.start": "tomorrow"})


async def test_the_default_simulated_sky_is_in_daylight_whenever_it_runs(
        aiohttp_client, build_dir, tmp_path):
    app = create_app(build_dir, settings_for(tmp_path, sim__start="auto",
                                             sim__clock_speed=20.0))
    client = await aiohttp_client(app)
    ws = await client.ws_connect("/ws/light")
    await ws.receive(timeout=10)
    while True:
        msg = await ws.receive(timeout=30)
        assert msg.type in (WSMsgType.BINARY, WSMsgType.TEXT)
        if msg.type == WSMsgType.BINARY:
            light = protocol.decode(msg.data)
            break
    status = await (await client.get("/api/status")).json()
    assert status["sun_elevation_deg"] > DAYLIGHT_ELEVATION_DEG - 1.0
    assert status["sim_clock_speed"] == 20.0
    assert float(light.rgb.mean()) > 1.0  # W/(m^2 sr): a daylight sky, not a night one
    await ws.close()
