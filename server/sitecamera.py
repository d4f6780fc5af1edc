"""The kiosk's site camera (Sato's Camera A): frames re-encoded as JPEG for kiosk clients,
each with the mask of the visitors standing in front of the virtual buildings.

Only clients that subscribe to the ``site-camera`` stream receive the frames, and to the
``occlusion`` stream the masks (``?streams=light,site-camera,occlusion`` or a subscribe
message); like the light vector, each gets the newest frame. With occlusion on, the JPEG
encoding (a thread) and the occlusion pipeline (a worker process, :mod:`server.occlusionfeed`)
run side by side on the newest frame, and the frame is published only with its mask, as one
bundle: SITE_CAMERA then OCCLUSION_MASK, same capture time. A frame that either cannot handle
is skipped with a log line; the next frame goes on.
"""

from __future__ import annotations

import asyncio
import logging
import time

import cv2
import numpy as np

from server.lightstream import LightHub
from server.measure import Frame
from server.newest import Newest
from server.occlusionfeed import OcclusionRunner
from server.protocol import Flags
from server.sources.base import Source

log = logging.getLogger("daylit.sitecamera")


class SiteCameraFeed:
    """Encodes the newest site-camera frame and publishes it on the hub."""

    def __init__(self, source: Source, hub: LightHub, jpeg_quality: int = 80,
                 max_width: int = 1280, occlusion: OcclusionRunner | None = None):
        self.source = source
        self.hub = hub
        self.jpeg_quality = jpeg_quality
        self.max_width = max_width
        self.occlusion = occlusion
        self._frames: Newest[Frame] = Newest()
        self.ready = asyncio.Event()
        self.frames = 0
        self.frames_in = 0
        self.frames_replaced = 0  # newer frames came before the older ones were done
        self.frames_skipped = 0
        self.size: tuple[int, int] | None = None
        self.last_frame_wall_s: float | None = None
        self._last_skip_log_s = -1e9
        # Also handed every frame as it comes (``--sky scene``: the light pipeline).
        self.listeners: list = []

    def deliver(self, frame: Frame) -> None:
        for listener in self.listeners:
            listener(frame)
        if self._frames.put(frame):
            self.frames_replaced += 1
        self.frames_in += 1

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

    async def run_source(self) -> None:
        """Run the source once the feed is ready (the occlusion worker started), so the first
        frames, which occlusion learns as the empty site, are not the ones dropped meanwhile."""
        await self.ready.wait()
        await self.source.run(self.deliver)

    async def run_forever(self) -> None:
        if self.occlusion is not None:
            await self.occlusion.start()
        self.ready.set()
        while True:
            await self.handle(await self._frames.take())

    async def handle(self, frame: Frame) -> bool:
        """Encode one frame (and find its mask) and publish it; False if it was skipped."""
        encoding = asyncio.to_thread(self.encode, frame)
        mask = None
        if self.occlusion is None:
            jpeg = await self._encoded(encoding)
        else:
            jpeg, mask = await asyncio.gather(
                self._encoded(encoding),
                self.occlusion.process(frame.image, frame.capture_time_s, frame.bgr))
        if jpeg is None or (self.occlusion is not None and mask is None):
            self.frames_skipped += 1  # both sides log why
            return False
        self.frames += 1
        self.last_frame_wall_s = time.time()
        flags = int(self.source.flags)
        if mask is None:
            self.hub.publish_frame(jpeg, frame.capture_time_s, flags)
        else:
            mask_flags = flags | (Flags.LEARNING if mask.learning else 0)
            self.hub.publish_frame(jpeg, frame.capture_time_s, flags, mask.payload,
                                   int(mask_flags))
        return True

    async def _encoded(self, encoding) -> bytes | None:
        try:
            return await encoding
        except (ValueError, cv2.error) as exc:
            now = time.monotonic()
            if now - self._last_skip_log_s > 10.0:  # one line per 10 s, not one per frame
                log.warning("skipping a site camera frame: %s (%d skipped so far)", exc,
                            self.frames_skipped + 1)
                self._last_skip_log_s = now
            return None

    def status(self) -> dict:
        return {
            "source": self.source.name,
            "connected": bool(self.source.connected),
            "frames": self.frames,
            "frames_skipped": self.frames_skipped,
            "frames_replaced": self.frames_replaced,
            "sequence": self.hub.sequence["site-camera"],
            "size": self.size,
            "last_frame_time_s": self.last_frame_wall_s,
        }
