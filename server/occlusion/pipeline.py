"""The occlusion pipeline for a fixed site camera: frame in, mask of people in front out.

This is the one class the light server calls. Per frame::

    frame --check--> coarse copy --gain (the sky's own: regiongain.py)--> reference
          illumination --shift (register.py)-->
          background's pixel grid --difference--> regions
          --graph cut (segment.py, shadows inside)--> people
          --outlines onto luminance edges (outline.py; block-coded frames)-->
          --foot line (depth.py; regions lying flat on the ground dropped)-->
          depth per person --vs virtual depth--> occlusion mask (+ slow background update)

Usage::

    proc = OcclusionProcessor.from_build(build_dir, view_id="kiosk", frame_size=(1024, 576))
    for frame in camera:                      # (H, W, 3) uint8 BGR, or encoded image bytes
        result = proc.process(frame, capture_time_s=t)      # ~10-20 ms: run it off the loop
        if result.ok and not result.learning:
            send(encode_message(result.mask, seq, t, result.people_in_front))

Frames that cannot be used (None, empty, wrong size or type, bytes that do not decode) are
skipped with one log line on the ``daylit.occlusion`` logger and ``result.ok`` False; nothing
raises out of :meth:`OcclusionProcessor.process`, and the next good frame continues as if the
bad one had not come. The first ``learn_frames`` good frames are taken as the empty site
(``result.learning``); :meth:`OcclusionProcessor.learn_background` may be called instead.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from server.occlusion.background import BackgroundModel, block_any, shrink
from server.occlusion.colour import Transfer, apply_table
from server.occlusion.depth import (
    EquidistantPanorama,
    Person,
    PerspectiveCamera,
    drop_flat_regions,
    find_people,
    occlusion_mask,
)
from server.occlusion.outline import refine_outline
from server.occlusion.regiongain import RegionGain
from server.occlusion.register import Registration, shift_image
from server.occlusion.segment import Segmenter, regions_of_interest
from server.occlusion.settings import OcclusionSettings
from server.throttledlog import ThrottledWarnings

log = logging.getLogger("daylit.occlusion")

_MEAN3 = np.full((1, 3), 1.0 / 3.0, dtype=np.float32)  # cv2.transform: mean of the channels


@dataclass
class OcclusionResult:
    """What one frame gave.

    Attributes
    ----------
    frame_index : count of frames offered to :meth:`OcclusionProcessor.process`, from 0
    capture_time_s : as passed in (Unix seconds), or None
    ok : False when the frame was skipped (``skipped_reason`` says why); then every array is None
    learning : the frame went into the background model; ``mask`` is all zero
    mask : (H, W) uint8, 255 where a person stands in front of the virtual objects: the
        client must not draw virtual pixels there (the paper's stencil). This is what is sent.
    person_mask : (H, W) uint8, 255 on every person (in front or behind)
    shadow_mask : (H, W) uint8, 255 on cast shadows taken out of the foreground
    foreground_mask : (H, W) uint8, 255 on people and their shadows (before shadow removal)
    people : one :class:`~server.occlusion.depth.Person` per region, with depth
    gain_bgr : (3,) daylight gain of this frame over the background model (linear light)
    shift_px : (2,) camera shake ``(dx, dy)``: the scene moved by this against the background
        (pixels; zero when ``register`` is off). The masks are in the frame's own grid.
    regions : the regions of interest the graph cut ran in, (y0, y1, x0, x1) pixels
    timings_ms : wall time of each stage and ``total``, milliseconds
    """

    frame_index: int
    capture_time_s: float | None = None
    ok: bool = True
    skipped_reason: str | None = None
    learning: bool = False
    mask: np.ndarray | None = None
    person_mask: np.ndarray | None = None
    shadow_mask: np.ndarray | None = None
    foreground_mask: np.ndarray | None = None
    people: list[Person] = field(default_factory=list)
    gain_bgr: np.ndarray | None = None
    shift_px: np.ndarray | None = None
    regions: list[tuple[int, int, int, int]] = field(default_factory=list)
    timings_ms: dict[str, float] = field(default_factory=dict)

    @property
    def people_in_front(self) -> int:
        """How many people have pixels in ``mask`` (the codec's informational count)."""
        return sum(1 for p in self.people if p.in_front_px > 0)


class FrameError(ValueError):
    """A frame that cannot be processed; ``str()`` is the reason logged."""


class OcclusionProcessor:
    """Occlusion masks for one fixed, calibrated site camera.

    Parameters
    ----------
    camera : the site camera (``K``, ``world_from_camera``, ``width``, ``height``); anything with
        ``width``, ``height`` and ``foot_depth_m(u_px, v_px) -> depth`` (e.g.
        :class:`~server.occlusion.depth.EquidistantPanorama`) will do.
    virtual_depth_m : (H, W) float32 depth of the virtual surfaces along the optical axis,
        metres, +inf where none (the view's baked ``depth`` image); None: no virtual objects
        known, every person counts as in front.
    settings : :class:`~server.occlusion.settings.OcclusionSettings`
    """

    def __init__(
        self,
        camera: PerspectiveCamera,
        virtual_depth_m: np.ndarray | None = None,
        settings: OcclusionSettings | None = None,
    ):
        self.camera = camera
        self.width, self.height = int(camera.width), int(camera.height)
        self.settings = settings or OcclusionSettings()
        if virtual_depth_m is not None:
            virtual_depth_m = np.asarray(virtual_depth_m, dtype=np.float32)
            if virtual_depth_m.shape != (self.height, self.width):
                raise ValueError(
                    f"virtual depth is {virtual_depth_m.shape[1]}x{virtual_depth_m.shape[0]}, "
                    f"the camera {self.width}x{self.height}"
                )
            virtual_depth_m = np.where(np.isnan(virtual_depth_m), np.inf, virtual_depth_m)
        self.virtual_depth_m = virtual_depth_m
        self.transfer = Transfer(self.settings.response)
        self.background = BackgroundModel(self.width, self.height, self.settings, self.transfer)
        self.segmenter = Segmenter(self.settings, self.background, self.transfer)
        self.registration = Registration(self.settings)
        s = self.settings
        self.region_gain = RegionGain(self.transfer, s.detect_scale, s.region_gain_min_share,
                                      s.region_gain_step_codes)
        self.frame_index = 0
        self._learning: list[np.ndarray] = []
        self._previous_exclude: np.ndarray | None = None  # coarse people + shadows, last frame
        self._previous_people: np.ndarray | None = None  # coarse people alone, last frame
        self._skip_warnings = ThrottledWarnings(log, interval_s=1.0)

    # -------------------------------------------------------------------------- construction

    @classmethod
    def from_build(
        cls, build_dir: Path | str, view_id: str | None = None,
        settings: OcclusionSettings | None = None, frame_size: tuple[int, int] | None = None,
    ) -> OcclusionProcessor:
        """From a baked build: the view's calibrated camera and its virtual depth image.

        ``view_id``: the manifest view (default: the first). ``frame_size`` ``(width,
        height)``: the size of the frames that will be processed when the live camera does not
        deliver the view's baked size (same field of view); the intrinsics are scaled and the
        virtual depth image resampled (nearest) to it.
        """
        from daylit.manifest import load

        manifest = load(build_dir)
        views = manifest["views"]
        if not views:
            raise ValueError(f"{build_dir}: the build has no fixed view (kiosk camera)")
        view = next((v for v in views if v["id"] == view_id), None) if view_id else views[0]
        if view is None:
            raise ValueError(f"{build_dir}: no view {view_id!r}")
        depth = read_depth_exr(Path(build_dir) / view["depth"]) if view.get("depth") else None
        camera = PerspectiveCamera.from_view(view)
        if frame_size is not None and tuple(frame_size) != (camera.width, camera.height):
            camera = camera.scaled(*frame_size)
            if depth is not None:
                depth = cv2.resize(depth, tuple(frame_size), interpolation=cv2.INTER_NEAREST)
        return cls(camera, depth, settings)

    @property
    def ready(self) -> bool:
        """True once the background of the empty site has been learned."""
        return self.background.ready

    def learn_background(self, frames: Iterable[np.ndarray]) -> int:
        """Learn the empty site from frames (H, W, 3) uint8 BGR; bad frames are left out.

        Returns the number of frames used. Resets the label history.
        """
        good = []
        for frame in frames:
            try:
                good.append(self._check(frame))
            except FrameError as exc:
                self._log_skip(str(exc))
        if not good:
            raise ValueError("no usable frame to learn the background from")
        n = self._learn(good)
        self.segmenter.reset()
        self._previous_exclude = None
        self._previous_people = None
        self._learning = []
        return n

    # ---------------------------------------------------------------------------- per frame

    def process(self, frame, capture_time_s: float | None = None) -> OcclusionResult:
        """Process one site-camera frame; never raises.

        ``frame``: (H, W, 3) uint8 BGR array, or the bytes of an encoded image (JPEG, PNG).
        """
        index = self.frame_index
        self.frame_index += 1
        t0 = time.perf_counter()
        try:
            image = self._check(frame)
        except FrameError as exc:
            self._log_skip(f"frame {index} skipped: {exc}")
            return OcclusionResult(index, capture_time_s, ok=False, skipped_reason=str(exc))
        try:
            if not self.background.ready:
                return self._learn_step(image, index, capture_time_s)
            result = self._segment(image, index, capture_time_s)
        except Exception as exc:  # the streaming path must go on; keep the traceback in the log
            log.exception("frame %d skipped: occlusion pipeline failed", index)
            self.segmenter.reset()
            return OcclusionResult(index, capture_time_s, ok=False,
                                   skipped_reason=f"pipeline error: {exc!r}")
        result.timings_ms["total"] = 1e3 * (time.perf_counter() - t0)
        return result

    def _check(self, frame) -> np.ndarray:
        if frame is None:
            raise FrameError("no frame (None)")
        if isinstance(frame, bytes | bytearray | memoryview):
            if len(frame) == 0:
                raise FrameError("empty image bytes")
            data = np.frombuffer(frame, dtype=np.uint8)
            try:
                image = cv2.imdecode(data, cv2.IMREAD_COLOR)
            except cv2.error:
                image = None
            if image is None:
                raise FrameError(f"{len(frame)} bytes that do not decode as an image")
            frame = image
        if not isinstance(frame, np.ndarray):
            raise FrameError(f"unsupported frame type {type(frame).__name__}")
        if frame.size == 0:
            raise FrameError(f"empty frame {frame.shape}")
        if frame.dtype != np.uint8:
            raise FrameError(f"frame dtype {frame.dtype}, expected uint8")
        if frame.shape != (self.height, self.width, 3):
            shape = "x".join(str(s) for s in frame.shape)
            raise FrameError(f"frame is {shape}, expected {self.height}x{self.width}x3 (HxWx3)")
        return np.ascontiguousarray(frame)

    def _log_skip(self, message: str) -> None:
        """Log a skipped frame; the same reason at most once a second (with a count)."""
        self._skip_warnings.warn(message.split(":", 1)[-1], message)

    def _learn_step(self, image: np.ndarray, index: int, t: float | None) -> OcclusionResult:
        self._learning.append(image)
        if len(self._learning) >= self.settings.learn_frames:
            self._learn(self._learning)
            self._learning = []
            log.info("background learned from %d frames", self.settings.learn_frames)
        zero = np.zeros((self.height, self.width), dtype=np.uint8)
        return OcclusionResult(index, t, learning=True, mask=zero, person_mask=zero,
                               shadow_mask=zero, foreground_mask=zero)

    def _learn(self, frames: list[np.ndarray]) -> int:
        """Learn the background; with ``register``, from frames aligned to their first median
        (a shaking camera's learning frames would otherwise blur every edge)."""
        if self.settings.register and len(frames) >= 2:
            first = np.median(np.stack(frames), axis=0).astype(np.float32)
            self.registration.set_reference(first)
            aligned = []
            for frame in frames:
                self.registration.shift_px[:] = 0.0
                self.registration.estimate(frame)
                aligned.append(self.registration.align(frame))
            frames = aligned
        n = self.background.learn(frames)
        self.region_gain.learn(self.background.coarse_mean,
                               self._above_horizon(self.settings.detect_scale),
                               self.background.mean_u8, self._above_horizon(1))
        self.registration.shift_px[:] = 0.0
        if self.settings.register:
            self.registration.set_reference(self.background.mean)
        return n

    def _above_horizon(self, scale: int) -> np.ndarray | None:
        """(H // scale, W // scale) bool: the pixels (blocks of ``scale``) whose centre's ray
        does not meet the ground plane (the sky, far buildings); None for a camera that
        cannot say (then no region gets a gain of its own)."""
        h, w = self.height // scale, self.width // scale
        v, u = np.mgrid[0:h, 0:w]
        u, v = (u.ravel() + 0.5) * scale, (v.ravel() + 0.5) * scale
        if isinstance(self.camera, PerspectiveCamera):
            return (self.camera.ray_directions(u, v)[:, 1] >= 0.0).reshape(h, w)
        if isinstance(self.camera, EquidistantPanorama):  # a level axis: the upper half
            return (v <= 0.5 * self.camera.height).reshape(h, w)
        return None

    def _segment(self, image: np.ndarray, index: int, t: float | None) -> OcclusionResult:
        s = self.settings
        bg = self.background
        timings = {}
        tick = time.perf_counter()

        def lap(name: str) -> None:
            nonlocal tick
            now = time.perf_counter()
            timings[name] = 1e3 * (now - tick)
            tick = now

        # 1. Daylight: gain from the coarse frame, and its table to reference illumination.
        reg = self.registration
        if s.register and s.detect_scale % reg.scale == 0:
            half = reg.shrink(image)  # the registration's copy; halving is OpenCV's fast case
            coarse = shrink(half, s.detect_scale // reg.scale)
        else:
            half = reg.shrink(image) if s.register else None
            coarse = shrink(image, s.detect_scale)
        gain = bg.estimate_gain(coarse, self._previous_exclude)
        table = self.transfer.gain_table(gain)
        coarse_corrected = apply_table(coarse, table)
        lap("gain")
        # 1b. Camera shake: the shift of the frame (shrunk to the registration scale, then
        # corrected) against the background; the coarse copy moved into the background's grid.
        shift = np.zeros(2)
        if s.register:
            shrunk = apply_table(half, table)
            shift = reg.estimate(shrunk, self._previous_exclude, shrunk=True).copy()
            if reg.moved and s.detect_scale % reg.scale == 0:
                # Resampled at the registration scale, then block means: resampling the
                # coarse copy itself blurs edges into candidates (8 regions a frame, not 2).
                k = 1.0 / reg.scale
                coarse_corrected = shrink(shift_image(shrunk, shift[0] * k, shift[1] * k),
                                          s.detect_scale // reg.scale)
            elif reg.moved:
                coarse_corrected = shrink(reg.align_rects(image, [(0, self.height, 0,
                                                                   self.width)], table),
                                          s.detect_scale)
        # 1c. The sky and other large smooth regions above the horizon: gains of their own.
        regional = self.region_gain.count > 0
        if regional:
            self.region_gain.estimate(coarse, coarse_corrected, bg.coarse_linear,
                                      bg.coarse_mean, gain)
            h, w = coarse_corrected.shape[:2]
            self.region_gain.apply(coarse_corrected, coarse, [(0, h, 0, w)], bg.coarse_mean,
                                   bg.coarse_linear, gain, self.region_gain.coarse_labels)
        lap("register")
        # 2. Regions of interest: coarse background difference plus last frame's people.
        if s.full_frame:
            boxes = [(0, self.height, 0, self.width)]
        else:
            diff = cv2.absdiff(coarse_corrected.astype(np.float32), bg.coarse_mean)
            candidates = cv2.transform(diff, _MEAN3) > s.detect_threshold
            if self._previous_people is not None:  # people standing still stay in a region
                candidates |= self._previous_people
            candidates = cv2.dilate(candidates.view(np.uint8), np.ones((3, 3), np.uint8))
            boxes = regions_of_interest(candidates, s.detect_scale, s.roi_pad_px,
                                        s.min_region_px, (self.height, self.width))
        # The frame in reference illumination and the background's grid, computed only where
        # it is read: the regions and the band of rows the slow update visits next.
        y0, y1 = bg.next_band()
        rects = [*boxes, (y0, y1, 0, self.width)]
        corrected = reg.align_rects(image, rects, table)
        if regional:
            self.region_gain.apply(corrected, image, rects, bg.mean_u8, bg.linear, gain)
        lap("regions")
        # 3. Graph cut of Eq. 6 inside the regions, shadows joining the background.
        person, shadow, foreground = self.segmenter.segment(corrected, boxes)
        lap("segment")
        timings.update({f"segment.{k}": v for k, v in self.segmenter.timings_ms.items()})
        # 3b. On block-coded frames, the outlines moved onto the luminance edges (outline.py).
        # Only what is sent changes: the label history, the person colours and next frame's
        # regions keep the cut's labels (fed back, the moved outlines grew frame by frame).
        cut_person = person
        refined = s.outline_radius_px > 0 and self.segmenter.coded()
        if refined:
            person = person.copy()
            for by0, by1, bx0, bx1 in boxes:
                person[by0:by1, bx0:bx1] = refine_outline(
                    cut_person[by0:by1, bx0:bx1], corrected[by0:by1, bx0:bx1],
                    s.outline_radius_px, s.outline_eps)
            shadow = shadow & ~person
            foreground = foreground | person  # people stay inside the foreground
            lap("outline")
        # 4. People, their depth from the foot line, and the mask of those in front.
        labels, people = find_people(person, s.min_person_px, s.foot_min_px, boxes)
        person = labels > 0
        for p in people:
            p.foot_px = (p.foot_px[0] + shift[0], p.foot_px[1] + shift[1])  # frame's grid
        if isinstance(self.camera, PerspectiveCamera) and people:
            # All foot points' rays at once (a call per person cost 0.1 ms each).
            points, depths = self.camera.ground_hit(*np.array([p.foot_px for p in people]).T)
            for p, point, depth in zip(people, points, depths, strict=True):
                p.depth_m = float(depth)
                if np.isfinite(depth):
                    p.foot_world_m = (float(point[0]), float(point[1]), float(point[2]))
        else:
            for p in people:
                p.depth_m = self.camera.foot_depth_m(*p.foot_px)
        # Pieces of cast shadow kept as person lie flat on the ground: not people.
        people = drop_flat_regions(labels, people, self.camera, s.min_person_height_m)
        person = labels > 0
        mask = occlusion_mask(labels, people, self.virtual_depth_m)
        lap("depth")
        # 5. Memory: label history, person colours, slow background update, gain exclusion.
        if not refined:
            cut_person = person
        else:  # the cut's labels in the people kept (their outlines moved by at most r)
            r = 2 * s.outline_radius_px + 1
            kept = cv2.dilate(person.view(np.uint8), np.ones((r, r), np.uint8))
            cut_person = cut_person & kept.view(bool)
        self.segmenter.remember(cut_person, corrected)
        busy = person | cut_person | shadow
        near = cv2.dilate(busy.view(np.uint8), np.ones((2 * s.bg_protect_px + 1,) * 2, np.uint8))
        bg.update(corrected, near == 0)
        self._previous_exclude = block_any(near, s.detect_scale)
        # Regions follow last frame's people, not its shadow labels: a codec's scattered
        # specks taken as shadow would otherwise keep the regions as large as the frame.
        self._previous_people = block_any(cut_person, s.detect_scale)
        u8 = np.uint8(255)
        masks = (mask, person.view(np.uint8) * u8, shadow.view(np.uint8) * u8,
                 foreground.view(np.uint8) * u8)
        if s.register:  # back into the frame's own grid
            masks = reg.to_frame_in(boxes, *masks)  # zero outside the regions
        result = OcclusionResult(
            index, t, mask=masks[0], person_mask=masks[1], shadow_mask=masks[2],
            foreground_mask=masks[3], people=people, gain_bgr=gain.copy(), shift_px=shift,
            regions=boxes, timings_ms=timings,
        )
        lap("update")
        return result


def read_depth_exr(path: Path | str) -> np.ndarray:
    """A view's virtual depth image (OpenEXR, channel ``Z``): (H, W) float32 metres."""
    import OpenEXR

    with OpenEXR.File(str(path), separate_channels=True) as f:
        return np.asarray(f.channels()["Z"].pixels, dtype=np.float32)
