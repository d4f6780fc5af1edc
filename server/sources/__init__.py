"""Where sky frames come from: the simulated sky, a replay, a live camera, or the site
camera's frames for the estimate from the scene (``scene``).

Every source has ``async run(deliver)``: it calls ``deliver(frame)`` for each new frame, as
fast as its rate allows, and never waits for the consumer (the consumer keeps only the newest
frame). ``run`` returns or raises only when the source cannot go on; the app's supervisor then
starts it again after a pause.
"""

from __future__ import annotations

from server.sources.base import Source
from server.sources.camera import CameraSource
from server.sources.replay import ReplaySource
from server.sources.scene import SceneFrames
from server.sources.sim import SimSource

__all__ = ["CameraSource", "ReplaySource", "SceneFrames", "SimSource", "Source"]
