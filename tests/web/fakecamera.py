"""Chromium's fake camera and a turned "phone" for the camera-mode tests: a Y4M file of a
picture (``--use-file-for-fake-video-capture``) and dispatched ``deviceorientation`` events."""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np

from tests.web.harness import CHROMIUM_FLAGS, StubServer, chromium_path
from tests.web.kioskref import light_message


def write_y4m(path, rgb: np.ndarray, frames: int = 2) -> None:
    """A 4:2:0 Y4M of ``rgb`` ((H, W, 3) uint8 sRGB codes, H and W even), BT.709 limited range
    (Chromium's fake camera reads the file as BT.709: written as BT.601, the colours came back
    12 codes off)."""
    h, w = rgb.shape[:2]
    r, g, b = (rgb[..., c].astype(np.float64) / 255 for c in range(3))
    luma = 0.2126 * r + 0.7152 * g + 0.0722 * b
    y = 16 + 219 * luma
    cb = 128 + 224 * (b - luma) / 1.8556
    cr = 128 + 224 * (r - luma) / 1.5748
    planes = [np.round(y), np.round(cb[::2, ::2]), np.round(cr[::2, ::2])]
    frame = b"FRAME\n" + b"".join(p.astype(np.uint8).tobytes() for p in planes)
    path.write_bytes(f"YUV4MPEG2 W{w} H{h} F30:1 Ip A1:1 C420jpeg\n".encode() + frame * frames)


def write_y4m_rows(path, size, bands, frames: int = 2) -> None:
    """A Y4M of horizontal bands: ``bands`` [(first row, (r, g, b)), ...] from the top,
    ``size`` (W, H)."""
    w, h = size
    rgb = np.zeros((h, w, 3), np.uint8)
    for row, colour in bands:
        rgb[row:] = colour
    write_y4m(path, rgb, frames)


def orient(page, alpha, beta, gamma):
    """Turn the "phone": the event is sent again until the camera view has read it (its
    listener may still be on its way in on a loaded machine), then two frames are drawn.
    Chromium's own event of nulls (no sensors here) may come later: the view ignores it."""
    page.wait_for_function("""([alpha, beta, gamma]) => {
      const angles = { alpha, beta, gamma, absolute: false };
      dispatchEvent(new DeviceOrientationEvent('deviceorientation', angles));
      const o = window.daylit.debug.cameraOrientation();
      return o !== null && o.alpha === alpha && o.beta === beta && o.gamma === gamma;
    }""", arg=[alpha, beta, gamma], timeout=30000, polling=100)
    page.evaluate("""() => new Promise((done) =>
      requestAnimationFrame(() => requestAnimationFrame(done)))""")


READY = "window.daylit.status.ready && window.daylit.status.mode === 'camera'"


@contextmanager
def camera_page(browser, web_build, y4m, sky, query="", size=(640, 360), has_touch=False):
    """The client in camera mode in its own Chromium, whose fake camera plays ``y4m``, served
    by a StubServer of ``web_build`` that sends the sky ``sky`` (n, 3; None: no sky, a server
    without cameras). Yields (page, server, errors): errors collects the page's uncaught
    exceptions."""
    flags = CHROMIUM_FLAGS + [f"--use-file-for-fake-video-capture={y4m}"]
    with StubServer(web_build) as server:
        if sky is not None:
            server.push(light_message(sky, 1), remember=True)
        camera_browser = browser.browser_type.launch(executable_path=chromium_path(),
                                                     args=flags, headless=True)
        try:
            page = camera_browser.new_page(viewport={"width": size[0], "height": size[1]},
                                           has_touch=has_touch)
            errors = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(f"{server.url}/?mode=camera&test{query}")
            page.wait_for_function(READY, timeout=60000)
            yield page, server, errors
        finally:
            camera_browser.close()


def assert_metered_the_ground(readings: dict, ground_codes: dict, ground_radiance: float):
    """A picture meter's readings ``{name: (exposure, meter, level)}`` against the band each
    pose put below the horizon (``ground_codes``: name -> its sRGB code): the level read is
    the band's linear value (6 %: the browser's decoding and scaling of the picture, a few
    codes), and the exposure draws the modelled ground (luminance ``ground_radiance``) at that
    level; ``readings["sky"]``, a view with no ground, is the camera meter's middle grey."""
    from tests.web.harness import srgb_to_linear

    for name, code in ground_codes.items():
        exposure, meter, level = readings[name]
        assert meter == "picture", (name, readings)
        truth = float(srgb_to_linear(code))
        assert abs(level / truth - 1.0) <= 0.06, (name, level, truth)
        assert abs(exposure * ground_radiance / level - 1.0) <= 1e-3, (name, exposure, level)
    exposure, meter, level = readings["sky"]
    assert meter == "camera" and level is None, readings
    assert abs(exposure * ground_radiance / 0.18 - 1.0) <= 1e-3, exposure
