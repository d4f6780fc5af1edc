"""Occlusion by visitors (issue 6; Kakuta et al. Sec. 3): which pixels of the kiosk's site
camera show a person standing in front of the virtual buildings.

The API the light server and the kiosk client depend on is small:

- :class:`OcclusionProcessor` (pipeline.py): ``OcclusionProcessor.from_build(build_dir,
  view_id)`` or ``OcclusionProcessor(camera, virtual_depth_m, settings)``, then
  ``process(frame, capture_time_s) -> OcclusionResult`` per site-camera frame (never raises);
- :func:`encode_mask` / :func:`decode_mask` / :func:`encode_message` (codec.py): the wire
  format of the mask, the payload of an OCCLUSION_MASK (type 3) message;
- :class:`OcclusionSettings` (settings.py).

docs/occlusion.md describes the method, the settings and the wire format.
"""

from server.occlusion.codec import MaskCodecError, decode_mask, encode_mask, encode_message
from server.occlusion.depth import EquidistantPanorama, Person, PerspectiveCamera
from server.occlusion.pipeline import OcclusionProcessor, OcclusionResult, read_depth_exr
from server.occlusion.settings import OcclusionSettings, camera_constants

__all__ = [
    "EquidistantPanorama",
    "MaskCodecError",
    "OcclusionProcessor",
    "OcclusionResult",
    "OcclusionSettings",
    "Person",
    "PerspectiveCamera",
    "camera_constants",
    "decode_mask",
    "encode_mask",
    "encode_message",
    "read_depth_exr",
]
