"""The kiosk tests' reference (Sato Eq. 9 in numpy) and page helpers, shared by
test_web_kiosk.py and test_web_kiosk_sun.py.

Tolerance per pixel and channel: |gpu - ref| <= REL |ref| + ABS (O' and S' are half floats,
4.9e-4 relative each, and the ratio doubles it; P's sRGB decoding by the GPU is exact to 8-bit
precision).
"""

from __future__ import annotations

import time

import cv2
import numpy as np

from server import protocol
from tests.web.harness import decode_floats

REL = 5e-3
ABS = 2e-3

KIOSK_HELLO = {"streams": ["light", "site-camera"],
               "available_streams": ["light", "site-camera", "occlusion"],
               "site_camera": {"source": "test", "size": [320, 180]}}


def light_message(r, seq, t=None, version=1, sun=None):
    """A LIGHT message of the sky ``r`` (n, 3); version 2 carries ``sun`` (an object with
    ``direction``, ``normal_irradiance_w_m2`` and ``source``, or None: no sun)."""
    r = np.asarray(r, dtype=np.float32)
    t = time.time() if t is None else t
    return protocol.encode_light(r, np.zeros(len(r), bool), seq, t, 0, version=version, sun=sun)


def frame_message(image_bytes, seq, t):
    return protocol.encode_blob(protocol.MessageType.SITE_CAMERA, image_bytes, seq, t)


def composite(page):
    return decode_floats(page.page.evaluate("window.daylit.debug.kioskComposite()"))[..., :3]


def view_inputs(ref, r):
    view = ref.manifest["views"][0]
    O = ref.compact(view["id"], "O").composite(r, ref.selection).astype(np.float64)
    S = ref.compact(view["id"], "S").composite(r, ref.selection).astype(np.float64)
    mask = cv2.imread(str(ref.dir / view["mask"]), cv2.IMREAD_GRAYSCALE)
    return view, O, S, mask


def safe_ratio(num, den, scene_floor=0.0):
    """O'/S' per channel as docs/web.md states it: a floor f = max(1e-2 max_c |S'_c|,
    scene_floor) per pixel, 1 at or below it, num / den from 2f up, a smoothstep blend
    between; clamped to [0, 4]."""
    f = np.maximum(1e-2 * np.abs(den).max(axis=-1, keepdims=True), max(scene_floor, 1e-12))
    t = np.clip((den - f) / f, 0.0, 1.0)
    w = t * t * (3.0 - 2.0 * t)
    return np.clip(1.0 + w * (num / np.maximum(den, f) - 1.0), 0.0, 4.0)


def eq9(O, S, mask, P, k):
    # the scene floor: 1e-3 of S' over the real pixels (the client samples them on a grid)
    real = S[mask == 0] @ np.array([0.2126, 0.7152, 0.0722])
    ratio = safe_ratio(O, S, 1e-3 * float(real.mean()) if real.size else 0.0)
    M = mask[..., None]
    return np.where(M == 255, k * O, np.where(M == 128, P, P * ratio))


def worst(gpu, want):
    return float((np.abs(gpu - want) / (REL * np.abs(want) + ABS)).max())


def open_kiosk(server, new_page, r, seq=1, size=(480, 270), query="", message=None):
    """A kiosk page once it has drawn light ``seq`` exactly (``message``, or a version-1
    message of ``r``)."""
    server.push(message or light_message(r, seq), remember=True)
    page = new_page(*size).open(f"{server.url}/?mode=kiosk&test{query}")
    page.wait(f"window.daylit.status.lightSeq === {seq} && window.daylit.status.lightsExact")
    return page
