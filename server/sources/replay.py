"""Replay of a recorded sky: a folder of images (sorted by name) or a video file, looping.

OpenEXR files (``.exr``) are read as linear float RGB with the OpenEXR package (OpenCV's EXR
reader is off by default) and measured as HDR frames: no value counts as clipped, and no
inverse response is applied (float frames are linear as they are). An EXR file's standard
``capDate`` ("YYYY:MM:DD HH:MM:SS", local) and ``utcOffset`` (seconds, UTC = local +
utcOffset; 0 when absent) attributes give the time its sky was at, for the sun's position
(``Frame.sky_time_s``); other frames are stamped with the time they are played.

A sub-folder of a replay folder is a **bracket** (``server.brackets``): its 8-bit exposures,
with their times from EXIF or its ``bracket.json``, are merged into one linear HDR frame (with
the clip level of its shortest exposure) and measured like an EXR frame. A bracket that cannot
be merged (one exposure, sizes that differ, a missing time) is skipped with a log line and
``last_error`` in the status. Brackets are replay-only: a live camera's exposure cannot be
driven through OpenCV portably.
"""

from __future__ import annotations

import asyncio
import datetime as dt
import logging
import time
from pathlib import Path

import cv2
import numpy as np

from server.brackets import BracketError, read_bracket
from server.measure import Frame
from server.photometry import Photometry, inverse_response_table
from server.protocol import Flags
from server.sources.base import Deliver, Source

log = logging.getLogger("daylit.sources")

IMAGE_SUFFIXES = {".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp", ".webp", ".exr", ".hdr"}


class ReplayError(RuntimeError):
    """A replay that has nothing to play."""


def read_exr_rgb(path: Path | str) -> tuple[np.ndarray, float | None]:
    """An OpenEXR image's R, G, B channels as (H, W, 3) float32 linear RGB, and its capture
    time (Unix seconds) from ``capDate``/``utcOffset``, or None.

    Raises ``OSError`` (unreadable) or ``ValueError`` (no R, G and B channels, a malformed
    ``capDate``).
    """
    import OpenEXR

    try:
        with OpenEXR.File(str(path), separate_channels=True) as f:
            channels = f.channels()
            missing = [c for c in "RGB" if c not in channels]
            if missing:
                raise ValueError(f"{path}: no {', '.join(missing)} channel "
                                 f"(has {', '.join(sorted(channels))})")
            rgb = np.stack([np.asarray(channels[c].pixels, dtype=np.float32)
                            for c in "RGB"], axis=-1)
            # Inside the block: closing the file empties its header dict.
            sky_time_s = exr_capture_time_s(f.header(), path)
    except RuntimeError as exc:  # OpenEXR reports unreadable files so
        raise OSError(f"{path}: {exc}") from None
    return rgb, sky_time_s


def exr_capture_time_s(header: dict, where: object = "EXR") -> float | None:
    """Unix seconds of an EXR header's ``capDate`` (local) and ``utcOffset`` (UTC = local +
    utcOffset), or None without ``capDate``."""
    text = header.get("capDate")
    if not text:
        return None
    try:
        local = dt.datetime.strptime(str(text).strip(), "%Y:%m:%d %H:%M:%S")
    except ValueError:
        raise ValueError(f"{where}: capDate {text!r} is not YYYY:MM:DD HH:MM:SS") from None
    offset_s = float(header.get("utcOffset", 0.0))
    return local.replace(tzinfo=dt.UTC).timestamp() + offset_s


def read_frame_image(path: Path) -> tuple[np.ndarray | None, bool, bool, float | None]:
    """One replay image: (image, bgr, hdr, sky_time_s). EXR: linear float RGB, HDR, with its
    capture time when the file has one; others through OpenCV, BGR (float images such as
    Radiance .hdr count as HDR), no time. Image None when it cannot be read."""
    if path.suffix.lower() == ".exr":
        try:
            rgb, sky_time_s = read_exr_rgb(path)
            return rgb, False, True, sky_time_s
        except (OSError, ValueError) as exc:
            log.warning("replay: skipping %s (%s)", path, exc)
            return None, False, False, None
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    return image, True, image is not None and image.dtype.kind == "f", None


class ReplaySource(Source):
    """Plays ``path`` at ``rate_hz`` frames per second, forever.

    Images that cannot be read, and brackets that cannot be merged, are skipped with a log
    line (once per file and reason). Frames are stamped with the time they are played (the
    recording's own time is not known in general).

    ``photometry``: its inverse response and saturation level merge brackets (default sRGB).
    """

    flags = Flags.REPLAY

    def __init__(self, path: Path | str, rate_hz: float = 2.0,
                 photometry: Photometry | None = None):
        self.path = Path(path)
        self.period_s = 1.0 / rate_hz
        self.name = f"replay:{self.path}"
        self.played = 0
        self.skipped = 0
        self.last_error = ""
        self.photometry = photometry or Photometry()
        self._response = inverse_response_table(self.photometry.response)
        self._warned: set[str] = set()

    def _images(self) -> list[Path]:
        """The folder's images and bracket folders (not hidden ones), in name order."""
        entries = sorted(p for p in self.path.iterdir() if not p.name.startswith(".") and (
            p.is_dir() or p.suffix.lower() in IMAGE_SUFFIXES))
        if not entries:
            raise ReplayError(f"{self.path}: no images ({', '.join(sorted(IMAGE_SUFFIXES))}) "
                              "or bracket folders")
        return entries

    def _skip(self, message: str) -> None:
        self.skipped += 1
        self.last_error = message
        if message not in self._warned:  # a looping replay would repeat it every loop
            self._warned.add(message)
            log.warning("replay: skipping %s", message)

    def read_entry(self, path: Path) -> tuple[np.ndarray, bool, bool, float | None,
                                              float | None] | None:
        """One entry: (image, bgr, hdr, sky_time_s, clip_level), or None (skipped)."""
        if path.is_dir():
            try:
                b = read_bracket(path, self._response, self.photometry.saturation_level)
            except (BracketError, OSError) as exc:
                self._skip(f"bracket {exc}" if isinstance(exc, BracketError) else
                           f"bracket {path} ({exc})")
                return None
            return b.image, True, True, b.sky_time_s, b.clip_level
        image, bgr, hdr, sky_time_s = read_frame_image(path)
        if image is None or image.ndim != 3 or image.shape[2] < 3:
            self._skip(f"{path} (not a colour image that can be read)")
            return None
        return image[:, :, :3], bgr, hdr, sky_time_s, None

    async def run(self, deliver: Deliver) -> None:
        next_s = time.monotonic()
        if self.path.is_dir():
            frames = self._images_forever()
        elif self.path.is_file():
            frames = self._video_forever()
        else:
            raise ReplayError(f"{self.path}: no such file or folder")
        async for image, bgr, hdr, sky_time_s, clip_level in frames:
            deliver(Frame(image, time.time(), bgr=bgr, hdr=hdr, sky_time_s=sky_time_s,
                          clip_level=clip_level))
            self.played += 1
            next_s = max(next_s + self.period_s, time.monotonic())
            await asyncio.sleep(next_s - time.monotonic())

    async def _images_forever(self):
        while True:
            good = 0
            for path in self._images():
                entry = await asyncio.to_thread(self.read_entry, path)
                if entry is None:
                    continue
                good += 1
                yield entry
            if not good:
                raise ReplayError(f"{self.path}: none of the images could be read "
                                  f"(last: {self.last_error})")

    async def _video_forever(self):
        while True:
            cap = await asyncio.to_thread(cv2.VideoCapture, str(self.path))
            try:
                if not cap.isOpened():
                    raise ReplayError(f"{self.path}: OpenCV cannot open this video")
                count = 0
                while True:
                    ok, image = await asyncio.to_thread(cap.read)
                    if not ok:
                        break
                    count += 1
                    yield image, True, False, None, None
                if not count:
                    raise ReplayError(f"{self.path}: the video has no frames")
            finally:
                cap.release()

    def status(self) -> dict:
        return {"replayed_frames": self.played, "skipped_frames": self.skipped,
                "last_error": self.last_error}
