"""Frames through a codec and back, as a site camera's stream would bring them.

JPEG by OpenCV; a video codec through OpenCV's FFmpeg backend; H.264 (libx264) through
imageio-ffmpeg's FFmpeg, since OpenCV's has no H.264 encoder. Every decode is OpenCV's FFmpeg
(or ``cv2.imdecode``), as the server decodes a live camera. Used by the held-out generator
(heldout.py) and the standard synthetic sequence's codec runs (conftest.py).
"""

from __future__ import annotations

import os
import tempfile

import cv2
import numpy as np


def jpeg_round_trip(codes: np.ndarray, quality: int) -> np.ndarray:
    """(H, W, 3) uint8 BGR encoded as JPEG at ``quality`` (OpenCV: 4:2:0), decoded."""
    ok, buf = cv2.imencode(".jpg", codes, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return cv2.imdecode(buf, cv2.IMREAD_COLOR)


def _decoded(path: str, expected: int) -> list[np.ndarray]:
    """Every frame of a video file as OpenCV's FFmpeg decodes it (BGR uint8)."""
    cap = cv2.VideoCapture(path, cv2.CAP_FFMPEG)
    decoded = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        decoded.append(frame)
    cap.release()
    if len(decoded) != expected:
        raise RuntimeError(f"video round trip gave {len(decoded)} of {expected} frames")
    return decoded


def video_round_trip(frames: list[np.ndarray], fourcc: str, fps: float):
    """``frames`` encoded by OpenCV's FFmpeg with ``fourcc`` at its default bit rate, decoded."""
    h, w = frames[0].shape[:2]
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, "heldout.mp4")
        wr = cv2.VideoWriter(path, cv2.CAP_FFMPEG, cv2.VideoWriter_fourcc(*fourcc), fps, (w, h))
        if not wr.isOpened():
            raise RuntimeError(f"OpenCV's FFmpeg cannot write {fourcc}")
        for codes in frames:
            wr.write(codes)
        wr.release()
        return _decoded(path, len(frames))


def h264_round_trip(frames: list[np.ndarray], crf: int, fps: float):
    """``frames`` encoded as H.264 (libx264, yuv420p, ``crf``, a keyframe every 2 s as IP
    cameras send them) by imageio-ffmpeg's FFmpeg (OpenCV's has no H.264 encoder), decoded
    by OpenCV's FFmpeg as the server decodes an RTSP stream."""
    import imageio_ffmpeg

    h, w = frames[0].shape[:2]
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, "heldout.mp4")
        writer = imageio_ffmpeg.write_frames(
            path, (w, h), pix_fmt_in="bgr24", pix_fmt_out="yuv420p", fps=fps, codec="libx264",
            output_params=["-crf", str(crf), "-g", str(int(2 * fps)), "-bf", "0",
                           "-preset", "veryfast"],
            macro_block_size=1, ffmpeg_log_level="error")
        writer.send(None)  # start the encoder
        for codes in frames:
            writer.send(np.ascontiguousarray(codes))
        writer.close()
        return _decoded(path, len(frames))
