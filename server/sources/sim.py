"""The simulated sky as a source: renders a frame every ``1 / rate_hz`` seconds."""

from __future__ import annotations

import asyncio
import datetime as dt
import time
from zoneinfo import ZoneInfo

from server.protocol import Flags
from server.simsky import SimulatedSky
from server.sources.base import Deliver, Source


class SimSource(Source):
    """Frames of :class:`server.simsky.SimulatedSky` at its simulated clock."""

    flags = Flags.SIMULATED

    def __init__(self, sim: SimulatedSky, rate_hz: float = 2.0):
        self.sim = sim
        self.period_s = 1.0 / rate_hz
        self.name = "sim"
        self._last_sky_time_s: float | None = None

    async def run(self, deliver: Deliver) -> None:
        next_s = time.monotonic()
        while True:
            # Rendering takes tens of milliseconds of numpy (and the auto clock's sunset look-up
            # a few more now and then): keep it off the event loop.
            sky_s, frame = await asyncio.to_thread(self._render_now)
            frame.capture_time_s = time.time()  # when the "camera" hands the image over
            self._last_sky_time_s = sky_s
            deliver(frame)
            next_s = max(next_s + self.period_s, time.monotonic())
            await asyncio.sleep(next_s - time.monotonic())

    def _render_now(self):
        sky_s = self.sim.now()
        return sky_s, self.sim.render_at(sky_s)

    def status(self) -> dict:
        if self._last_sky_time_s is None:
            return {}
        tz = ZoneInfo(self.sim.timezone)
        azimuth_deg, elevation_deg = self.sim.sun_at(self._last_sky_time_s)
        return {
            "sim_time": dt.datetime.fromtimestamp(self._last_sky_time_s, tz).isoformat(
                timespec="seconds"),
            "sim_clock_speed": self.sim.clock.speed,
            "sim_cloud_cover": self.sim.clouds.cover,
            "sun_azimuth_deg": round(azimuth_deg, 3),
            "sun_elevation_deg": round(elevation_deg, 3),
        }
