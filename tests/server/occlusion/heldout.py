"""A held-out site-camera sequence drawn with another camera model than the detector's.

The occlusion detector (server/occlusion/shadow.py) assumes a narrow-band camera under Wien
illuminants; server/occlusion/synthetic.py drew its frames with exactly that model until
2026-11-25 (now with spectralcamera.py's daylight spectra). This module shares none of the
detector's model, so that accuracy measured on its frames is not the detector grading
its own assumptions:

- Background: a procedural "photograph" (sky gradient, a facade band with windows and noise
  texture, tree blobs, paving with perspective joints and multi-scale noise), in linear light.
- Light: a **broadband** camera (Gaussian sensitivities, FWHM ~100 nm, peaks 600/540/455 nm)
  integrating *exact* Planck spectra (not Wien's approximation) over 400-700 nm (the
  integration code is server/occlusion/spectralcamera.py's, shared with the synthetic
  sequence; the sensitivities and illuminants are this module's own). A cast shadow
  multiplies the background per channel by ``fraction * (sky response) / (sun+sky response)``:
  ``"neutral"`` (the sky has the direct light's colour: ratio equal on all channels) or
  ``"bluish"`` (sun plus sky 5500 K, sky alone 8000 K: a mild blue shift).
- Penumbra: the shadow's coverage is blurred with a width that grows away from the feet.
- People: walkers at several depths (pinhole camera, 1.6-1.85 m tall), head, torso, two
  swinging legs, drawn 3x supersampled (anti-aliased edges), clothes from a fixed palette,
  shaded darker on one side.
- Sensor: shot plus read noise in linear light (``noise``: 0.15 codes at mid-grey per unit),
  sRGB encoding to 8 bits.
- A passing cloud: a global gain (down to 0.55, slightly bluer) and cast shadows that fade
  while it covers the sun.
- Camera: +-``jitter_px`` sub-pixel shake per frame (``cv2.warpAffine``, applied to the image
  and to the ground truth alike); ``awb_jump``: its auto white balance and exposure jump at
  half the sequence (per-channel gains on linear light).
- Codec: JPEG (``cv2.imencode``) at ``jpeg_quality``, a video codec through OpenCV's
  FFmpeg backend (``video_fourcc``), or H.264 at ``h264_crf`` through imageio-ffmpeg's
  FFmpeg (OpenCV's has no libx264), each decoded by OpenCV's FFmpeg.

Ground truth per frame: ``person`` (H, W) bool (covered >= 0.5 after the shake) and
``shadow`` (H, W) bool (shadow coverage >= 0.5, not person), ``people`` how many are in view.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from server.occlusion.spectralcamera import gaussian_sensitivities, planck, response
from tests.server.occlusion.codecs import h264_round_trip, jpeg_round_trip, video_round_trip

SSAA = 3  # supersampling of the people and shadows
ACROSS, TOWARD = 0.5, 1.3  # a cast shadow per metre of height: metres right, toward the camera
_WAVELENGTHS_NM = np.arange(400.0, 701.0, 5.0)


# This camera's own sensitivities (BGR order), not the synthetic sequence's
# (spectralcamera.SITE_CAMERA_RGB): the two generators share the integration code only.
_SENSITIVITIES_BGR = gaussian_sensitivities((455.0, 540.0, 600.0), (40.0, 45.0, 45.0),
                                            wavelengths_nm=_WAVELENGTHS_NM)


def camera_response(temperature_k: float) -> np.ndarray:
    """(3,) BGR response of the broadband camera to a Planckian illuminant (unit G)."""
    out = response(planck(_WAVELENGTHS_NM, temperature_k), _SENSITIVITIES_BGR)
    return out / out[1]


def shadow_ratio(kind: str, fraction: float = 0.4) -> np.ndarray:
    """(3,) BGR factor of shadowed over sunlit ground: ``"neutral"`` or ``"bluish"``."""
    if kind == "neutral":
        return np.full(3, fraction)
    if kind == "bluish":
        r = camera_response(8000.0) / camera_response(5500.0)
        return fraction * r / r[1]
    raise ValueError(f"shadow kind must be neutral or bluish, got {kind!r}")


def _srgb(linear: np.ndarray) -> np.ndarray:
    x = np.clip(linear, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def _value_noise(rng: np.random.Generator, h: int, w: int, cells: int) -> np.ndarray:
    """Smooth noise in [-1, 1]: random values on a ``cells``-wide grid, bicubic upsampled."""
    gh, gw = max(2, h * cells // w), cells
    grid = rng.uniform(-1, 1, (gh, gw)).astype(np.float32)
    return cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC)


@dataclass(frozen=True)
class HeldoutWalker:
    depth_m: float
    x0_m: float  # lateral position at enter_s, metres right of the optical axis
    speed_mps: float
    enter_s: float
    height_m: float = 1.75
    clothes_bgr: tuple[tuple[float, float, float], tuple[float, float, float]] = (
        (0.15, 0.2, 0.5), (0.2, 0.15, 0.1))  # (shirt, trousers) linear reflectances


@dataclass(frozen=True)
class HeldoutConditions:
    shadow: str = "bluish"  # neutral | bluish
    # sensor noise scale: read noise (noise / 255) * 0.1 in linear light plus shot noise of
    # the same size at linear 0.25; at mid-grey (linear 0.2) the standard deviation is
    # 0.15 * noise codes (noise 1: 0.15 codes, 3: 0.45, 19.6: 3.0)
    noise: float = 0.0
    cloud: bool = False
    jpeg_quality: int | None = None
    video_fourcc: str | None = None  # e.g. "mp4v"; frames go through an FFmpeg encode/decode
    # H.264 (libx264, 4:2:0, this constant rate factor; x264's default 23, 28 a site camera's
    # low-bit-rate stream) through imageio-ffmpeg's FFmpeg, decoded by OpenCV's as the server is
    h264_crf: int | None = None
    jitter_px: float = 0.0
    # the camera's auto white balance and exposure jump at half the sequence, people in view:
    # per-channel gains on linear light (B, G, R) x0.82, x1.0, x1.15, all x1.2
    awb_jump: bool = False

    def label(self) -> str:
        return self.__class__.__name__


CONDITIONS: dict[str, HeldoutConditions] = {
    "neutral shadows": HeldoutConditions(shadow="neutral", noise=1.0),
    "bluish shadows": HeldoutConditions(shadow="bluish", noise=1.0),
    "noise 0.45 codes": HeldoutConditions(noise=3.0),
    "noise 3 codes": HeldoutConditions(noise=19.6),
    "passing cloud": HeldoutConditions(noise=1.0, cloud=True),
    "JPEG 75": HeldoutConditions(noise=1.0, jpeg_quality=75),
    "video mp4v": HeldoutConditions(noise=1.0, video_fourcc="mp4v"),
    "video H.264": HeldoutConditions(noise=1.0, h264_crf=28),
    "jitter 0.5 px": HeldoutConditions(noise=1.0, jitter_px=0.5),
    "white balance jump": HeldoutConditions(noise=1.0, awb_jump=True),
    "all at once": HeldoutConditions(shadow="neutral", noise=3.0, cloud=True, jpeg_quality=75,
                                     jitter_px=0.5),
    # a camera sends JPEG or H.264, not both: all at once again with H.264 for the JPEG
    "all at once, H.264": HeldoutConditions(shadow="neutral", noise=3.0, cloud=True,
                                            h264_crf=28, jitter_px=0.5),
}


@dataclass
class HeldoutFrame:
    image: np.ndarray  # (H, W, 3) uint8 BGR, as decoded
    person: np.ndarray  # (H, W) bool
    shadow: np.ndarray  # (H, W) bool
    people: int
    shift_px: tuple[float, float] = (0.0, 0.0)  # camera shake: the scene moved by (dx, dy)


@dataclass
class HeldoutSequence:
    """``frames`` at ``fps``; the first ``empty_frames`` show the empty site (learn 10)."""

    width: int = 512
    height: int = 256
    fps: float = 10.0
    duration_s: float = 8.0
    empty_frames: int = 16
    conditions: HeldoutConditions = field(default_factory=HeldoutConditions)
    seed: int = 18
    hfov_deg: float = 60.0
    horizon_frac: float = 0.38  # the horizon's row as a fraction of the height
    camera_height_m: float = 2.5
    walkers: tuple[HeldoutWalker, ...] = ()

    def __post_init__(self):
        if not self.walkers:
            t0 = self.empty_frames / self.fps
            self.walkers = (
                HeldoutWalker(8.0, -4.0, 1.1, t0),
                HeldoutWalker(14.0, 5.0, -1.3, t0 + 0.5, 1.65,
                              ((0.45, 0.4, 0.35), (0.3, 0.3, 0.3))),
                HeldoutWalker(22.0, -7.0, 1.4, t0 + 1.0, 1.85,
                              ((0.1, 0.45, 0.1), (0.05, 0.05, 0.08))),
            )
        self.focal_px = 0.5 * self.width / math.tan(math.radians(self.hfov_deg) / 2)
        self.horizon_px = self.horizon_frac * self.height
        self._rng = np.random.default_rng(self.seed)
        self.background_linear = self._background()

    @property
    def frame_count(self) -> int:
        return int(round(self.duration_s * self.fps))

    def with_conditions(self, conditions: HeldoutConditions) -> HeldoutSequence:
        return replace(self, conditions=conditions, walkers=self.walkers)

    # ----------------------------------------------------------------------------- scene

    def _background(self) -> np.ndarray:
        """(H, W, 3) float32 linear BGR of the empty, sunlit site."""
        rng = np.random.default_rng(self.seed)
        h, w = self.height, self.width
        hz = int(self.horizon_px)
        img = np.zeros((h, w, 3), np.float32)
        rows = np.arange(h, dtype=np.float32)[:, None]
        # sky
        t = rows[:hz] / max(hz, 1)
        img[:hz] = np.stack([0.75 - 0.2 * t, 0.55 - 0.1 * t, 0.35 + 0.05 * t], -1) * np.ones(
            (1, w, 1), np.float32)
        # facades: a band of buildings with windows
        top = max(2, int(0.12 * h))
        x = 0
        while x < w:
            bw = int(rng.integers(w // 10, w // 4))
            by = int(rng.integers(top, hz - 4))
            colour = rng.uniform(0.15, 0.5, 3).astype(np.float32) * [0.8, 0.9, 1.1]
            img[by:hz, x:x + bw] = colour
            for wy in range(by + 4, hz - 6, 9):
                for wx in range(x + 3, x + bw - 5, 8):
                    img[wy:wy + 4, wx:wx + 4] = colour * 0.35
            x += bw
        tex = _value_noise(rng, h, w, 60)[..., None]
        img[:hz] *= 1.0 + 0.15 * tex[:hz]
        # trees
        for _ in range(6):
            cx, cy = int(rng.integers(0, w)), int(rng.integers(top, hz))
            r = int(rng.integers(h // 20, h // 8))
            blob = np.zeros((h, w), np.float32)
            cv2.circle(blob, (cx, cy), r, 1.0, -1)
            blob *= (0.5 + 0.5 * _value_noise(rng, h, w, 90)) > 0.3
            leaf = np.array([0.05, 0.2, 0.08], np.float32) * (1 + 0.4 * _value_noise(rng, h, w,
                                                                                   120))[..., None]
            img = img * (1 - blob[..., None]) + leaf * blob[..., None]
        # ground: paving with perspective joints, multi-scale noise, a lighter path
        g = np.array([0.22, 0.3, 0.38], np.float32)  # warm grey stone (BGR)
        ground = np.ones((h - hz, w, 1), np.float32) * g
        noise = sum(a * _value_noise(rng, h - hz, w, c) for a, c in ((0.12, 16), (0.1, 64),
                                                                     (0.08, 256)))
        ground *= (1 + noise)[..., None]
        gy = np.arange(hz, h, dtype=np.float32) - self.horizon_px + 0.5
        dist_m = self.focal_px * self.camera_height_m / gy  # distance of each ground row
        line_z = np.abs((dist_m / 0.8) - np.round(dist_m / 0.8)) < 0.8 / np.maximum(gy, 1.0)
        ground[line_z] *= 0.7
        xs = (np.arange(w, dtype=np.float32) - w / 2 + 0.5)[None, :] * dist_m[:, None] / \
            self.focal_px
        line_x = np.abs(xs / 0.8 - np.round(xs / 0.8)) < 0.03 * dist_m[:, None] / 4 + 0.02
        ground[line_x] *= 0.75
        img[hz:] = ground
        return np.clip(img, 0.0, 1.0)

    def _walker_layers(self, t_s: float):
        """Coverage of people, their linear colour times coverage, and their cast shadows'
        coverage, each (H, W) or (H, W, 3) float32 at the frame's size (drawn ``SSAA`` times
        larger in a box around each walker, then area-averaged); and how many are in view."""
        H, W = self.height, self.width
        people_cov = np.zeros((H, W), np.float32)
        colour = np.zeros((H, W, 3), np.float32)
        shadow_cov = np.zeros((H, W), np.float32)
        count = 0
        for wk in sorted(self.walkers, key=lambda k: -k.depth_m):  # far first
            if t_s < wk.enter_s:
                continue
            x_m = wk.x0_m + wk.speed_mps * (t_s - wk.enter_s)
            s = self.focal_px / wk.depth_m  # px per metre at the walker's depth
            u = 0.5 * W + x_m * s
            v = self.horizon_px + self.camera_height_m * s  # foot line
            hm = wk.height_m
            # box (frame pixels) holding the figure and its shadow
            x0, x1 = int(math.floor(u - 0.6 * s)), int(math.ceil(u + (0.6 + ACROSS * hm) * s))
            y0 = int(math.floor(v - 1.05 * hm * s))
            y1 = int(math.ceil(v + (TOWARD + 0.2) * hm * s * self.camera_height_m / wk.depth_m
                               + 0.1 * s))
            bx0, bx1, by0, by1 = max(x0, 0), min(x1, W), max(y0, 0), min(y1, H)
            if bx1 <= bx0 or by1 <= by0:
                continue
            if 0 <= u < W:
                count += 1
            S = SSAA
            bw, bh = (bx1 - bx0) * S, (by1 - by0) * S

            def p(x, y, x0=bx0, y0=by0):  # frame coordinates -> box pixel (supersampled)
                return int(round((x - x0) * SSAA)), int(round((y - y0) * SSAA))

            ss = s * S
            phase = 2 * math.pi * 0.9 * (t_s - wk.enter_s)
            legs = np.zeros((bh, bw), np.uint8)
            shirt = np.zeros((bh, bw), np.uint8)
            hip = (u, v - 0.5 * hm * s)
            for swing in (math.sin(phase), -math.sin(phase)):
                cv2.line(legs, p(*hip), p(u + 0.28 * swing * s, v - 0.05 * s), 255,
                         max(1, int(0.14 * ss)))
            cv2.ellipse(shirt, p(u, v - 0.72 * hm * s),
                        (max(1, int(0.2 * ss)), max(1, int(0.2 * hm * ss))), 0, 0, 360, 255, -1)
            cv2.line(shirt, p(u - 0.2 * s, v - 0.85 * hm * s),
                     p(u - 0.2 * s - 0.15 * math.sin(phase) * s, v - 0.5 * hm * s), 255,
                     max(1, int(0.08 * ss)))
            cv2.circle(shirt, p(u, v - 0.93 * hm * s), max(1, int(0.11 * ss)), 255, -1)
            body = (legs | shirt) > 0
            xs_box = bx0 + (np.arange(bw, dtype=np.float32) + 0.5) / S
            shade = (1.0 - 0.25 * np.clip((xs_box - u) / (0.3 * s), -1, 1))[None, :]
            col = np.zeros((bh, bw, 3), np.float32)
            for c in range(3):
                base = np.where(shirt > 0, wk.clothes_bgr[0][c], wk.clothes_bgr[1][c])
                col[..., c] = np.where(body, base * shade, 0.0)
            # the cast shadow: each figure pixel laid on the ground, ACROSS m to the right and
            # TOWARD m toward the camera per metre of height (a low sun ahead, to the left)
            ys, xs = np.nonzero(body)
            sh = np.zeros((bh, bw), np.uint8)
            if len(ys):
                y_frame = by0 + (ys + 0.5) / S
                height_m = (v - y_frame) / s
                sx = xs + ACROSS * height_m * ss
                sy = (v - by0) * S + TOWARD * height_m * ss * self.camera_height_m / wk.depth_m
                ok = (sx >= 0) & (sx < bw) & (sy >= 0) & (sy < bh)
                sh[sy[ok].astype(int), sx[ok].astype(int)] = 255
                sh = cv2.morphologyEx(sh, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
            # penumbra: wider away from the feet (blur sigma 0.03 m at the feet .. 0.1 m)
            sharp = cv2.GaussianBlur(sh.astype(np.float32) / 255, (0, 0), 0.03 * ss)
            soft = cv2.GaussianBlur(sh.astype(np.float32) / 255, (0, 0), 0.1 * ss)
            rows = (np.arange(bh, dtype=np.float32)[:, None] / S + by0 - v)
            away = np.clip(rows / max(1e-3, TOWARD * hm * s * self.camera_height_m / wk.depth_m),
                           0, 1)
            cols = np.clip((xs_box[None, :] - u) / (ACROSS * hm * s), 0, 1)
            mix = np.maximum(away, cols)
            shcov = sharp * (1 - mix) + soft * mix
            size = (bx1 - bx0, by1 - by0)
            cov = cv2.resize(body.astype(np.float32), size, interpolation=cv2.INTER_AREA)
            cols3 = cv2.resize(col, size, interpolation=cv2.INTER_AREA)
            shs = cv2.resize(shcov, size, interpolation=cv2.INTER_AREA)
            pc = people_cov[by0:by1, bx0:bx1]
            colour[by0:by1, bx0:bx1] = colour[by0:by1, bx0:bx1] * (1 - cov[..., None]) + cols3
            people_cov[by0:by1, bx0:bx1] = pc + cov * (1 - pc)
            shadow_cov[by0:by1, bx0:bx1] = np.maximum(shadow_cov[by0:by1, bx0:bx1], shs)
        return people_cov, colour, shadow_cov, count

    # ----------------------------------------------------------------------------- frames

    def frames(self):
        """Yields :class:`HeldoutFrame` per frame, after the camera and codec."""
        cond = self.conditions
        rng = np.random.default_rng(self.seed + 1)
        ratio = shadow_ratio(cond.shadow).astype(np.float32)
        bluer = (camera_response(7000.0) / camera_response(5500.0)).astype(np.float32)
        raw: list[np.ndarray] = []
        truths = []
        for i in range(self.frame_count):
            t = i / self.fps
            cov_s, col_s, sh_s, count = self._walker_layers(t)
            area = (self.width, self.height)
            gain = np.ones(3, np.float32)
            shadow_strength = 1.0
            if cond.cloud:  # covers the sun from 30 % to 70 % of the sequence, smoothly
                x = (t / self.duration_s - 0.3) / 0.4
                c = math.sin(math.pi * x) ** 2 if 0 <= x <= 1 else 0.0
                gain = ((1 - 0.45 * c) * (bluer**c)).astype(np.float32)
                shadow_strength = 1.0 - 0.8 * c
            shade = 1.0 - sh_s[..., None] * shadow_strength * (1.0 - ratio)
            lit = self.background_linear * shade
            person_lin = col_s * 1.1
            img = lit * (1.0 - cov_s[..., None]) + person_lin
            img = img * gain
            if cond.awb_jump and t >= 0.5 * self.duration_s:
                img = img * np.float32([0.82 * 1.2, 1.2, 1.15 * 1.2])
            shift = (0.0, 0.0)
            person = cov_s >= 0.5
            shadow = (sh_s >= 0.5) & ~person & (shadow_strength > 0.5)
            if cond.jitter_px > 0:
                dx, dy = rng.uniform(-cond.jitter_px, cond.jitter_px, 2)
                shift = (float(dx), float(dy))
                m = np.float32([[1, 0, dx], [0, 1, dy]])
                img = cv2.warpAffine(img, m, area, flags=cv2.INTER_LINEAR,
                                     borderMode=cv2.BORDER_REFLECT)
                person = cv2.warpAffine(person.astype(np.float32), m, area) >= 0.5
                shadow = cv2.warpAffine(shadow.astype(np.float32), m, area) >= 0.5
            if cond.noise > 0:
                read = (cond.noise / 255.0) * 0.1  # in linear units near mid-grey
                shot = read * read * 4.0
                sigma = np.sqrt(read * read + shot * np.clip(img, 0, 1))
                img = img + rng.standard_normal(img.shape).astype(np.float32) * sigma
            codes = np.clip(np.round(255.0 * _srgb(img)), 0, 255).astype(np.uint8)
            if cond.jpeg_quality is not None:
                codes = jpeg_round_trip(codes, cond.jpeg_quality)
            raw.append(codes)
            truths.append((person, shadow, count, shift))
        if cond.video_fourcc is not None:
            raw = video_round_trip(raw, cond.video_fourcc, self.fps)
        if cond.h264_crf is not None:
            raw = h264_round_trip(raw, cond.h264_crf, self.fps)
        for codes, (person, shadow, count, shift) in zip(raw, truths, strict=True):
            yield HeldoutFrame(codes, person, shadow, count, shift)

