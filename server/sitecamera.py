"""The kiosk's site camera (Sato's Camera A): frames re-encoded as JPEG for kiosk clients.

Only clients that subscribe to the ``site-camera`` stream receive them (``?streams=light,
site-camera`` or a subscribe message); like the light vector, each gets the newest frame.
"""

from __future__ import annotations

import asyncio
import logging
import time

import cv2
import numpy as np

from server.lightstream import LightHub
from server.measure import Frame
from server.sources.base import Source

log = logging.getLogger("daylit.sitecamera")


class SiteCameraFeed:
    """Encodes the newest site-camera frame and publishes it on the hub."""

    def __init__(self, source: Source, hub: LightHub, jpeg_quality: int = 80,
                 max_width: int = 1280):
        self.source = source
        self.hub = hub
        self.jpeg_quality = jpeg_quality
        self.max_width = max_width
        self._pending: Frame | None = None
        self._new = asyncio.Event()
        self.frames = 0
        self.size: tuple[int, int] | None = None
        self.last_frame_wall_s: float | None = None

    def deliver(self, frame: Frame) -> None:
        self._pending = frame
        self._new.set()

    def encode(self, frame: Frame) -> bytes:
        image = frame.image
        if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
            raise ValueError(f"site camera frame of shape {image.shape} and type {image.dtype}")
        if not frame.bgr:
            image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
        h, w = image.shape[:2]
        if w > self.max_width:
            image = cv2.resize(image, (self.max_width, round(h * self.max_width / w)),
                               interpolation=cv2.INTER_AREA)
        ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
        if not ok:
            raise ValueError("JPEG encoding failed")
        self.size = (image.shape[1], image.shape[0])
        return buf.tobytes()

    async def run_forever(self) -> None:
        while True:
            await self._new.wait()
            self._new.clear()
            frame, self._pending = self._pending, None
            if frame is None:
                continue
            try:
                jpeg = await asyncio.to_thread(self.encode, frame)
            except ValueError as exc:
                log.warning("skipping a site camera frame: %s", exc)
                continue
            self.frames += 1
            self.last_frame_wall_s = time.time()
            self.hub.publish_site_camera(jpeg, frame.capture_time_s, int(self.source.flags))

    def status(self) -> dict:
        return {
            "source": self.source.name,
            "connected": bool(self.source.connected),
            "frames": self.frames,
            "sequence": self.hub.sequence["site-camera"],
            "size": self.size,
            "last_frame_time_s": self.last_frame_wall_s,
        }
