"""The sky source ``scene``: the site camera's frames, handed on to the light pipeline.

The site camera has one reader (its :class:`server.sitecamera.SiteCameraFeed`); with ``--sky
scene`` the feed also hands each frame to this source's ``forward``, which delivers it to the
pipeline (whose meter is then a :class:`server.scenemeter.SceneMeter`). ``run`` only waits:
the site camera's own source reconnects and reports.
"""

from __future__ import annotations

import asyncio

from server.measure import Frame
from server.sources.base import Deliver, Source


class SceneFrames(Source):
    """Frames of ``site_source`` as the sky source; ``meter`` (optional) adds its status."""

    def __init__(self, site_source: Source, meter=None):
        self.site_source = site_source
        self.meter = meter
        self.name = f"scene:{site_source.name}"
        self.flags = site_source.flags
        self._deliver: Deliver | None = None

    @property
    def connected(self) -> bool:
        return bool(self.site_source.connected)

    def forward(self, frame: Frame) -> None:
        """Called by the site camera's feed for each frame (before the pipeline runs: drop)."""
        if self._deliver is not None:
            self._deliver(frame)

    async def run(self, deliver: Deliver) -> None:
        self._deliver = deliver
        try:
            await asyncio.Event().wait()  # frames come through forward()
        finally:
            self._deliver = None

    def status(self) -> dict:
        out = {"last_error": self.site_source.status().get("last_error", "")}
        if self.meter is not None:
            out["scene_estimate"] = self.meter.status()
        return out
