"""Screenshots of the demo in each mode, saved in tests/web/screenshots/ (not committed) for
people to look at; each must show a picture (not a blank canvas) and no console error."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tests.web.harness import StubServer
from tests.web.kioskref import KIOSK_HELLO, light_message

pytestmark = [pytest.mark.browser]

# A late afternoon in spring: long shadows toward the north-east.
SKY = "clear:235,22"


def picture_stats(png: bytes):
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR).astype(np.float64)
    return img.mean(), img.std()


@pytest.fixture(scope="module")
def sky(reference):
    return reference.light_vector(SKY)


def shot(page, name):
    png = page.page.screenshot()
    mean, std = picture_stats(png)
    assert 20 < mean < 235 and std > 10, (name, mean, std)  # a picture, not a blank canvas
    # No surface drawn pure black (the hull planes' bottom faces buried in the hall's podium,
    # pulled over its floor, drew it 0, 0, 0 once the planes multiplied in linear light).
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    black = float((img.sum(axis=-1) == 0).mean())
    assert black < 1e-4, (name, black)
    page.screenshot(name)


@pytest.mark.parametrize("name,query,size,action", [
    ("visit", "mode=visit", (960, 540), None),
    ("visit-hull-planes", "mode=visit", (960, 540), "hull"),
    ("visit-shading-off", "mode=visit", (960, 540), "off"),
    ("visit-phone-portrait", "mode=visit", (390, 780), None),
    ("camera-fake-device", "mode=camera", (960, 540), None),
    ("kiosk-synthesized", "mode=kiosk", (960, 540), None),
])
def test_screenshots_of_each_mode(new_page, web_build, sky, name, query, size, action):
    hello = KIOSK_HELLO if "kiosk" in query else None
    with StubServer(web_build, hello) as server:
        server.push(light_message(sky, 5), remember=True)
        ready = "window.daylit.status.ready && window.daylit.status.lightsExact"
        page = new_page(*size).open(f"{server.url}/?{query}", ready)
        if action == "hull":
            page.page.select_option(".shadingmode", "hull")
            page.wait("window.daylit.status.shadingMode === 'hull'")
        elif action == "off":
            page.page.uncheck(".shading")
        page.page.wait_for_timeout(1500)  # the orbit settles, the exposure adapts
        shot(page, name)
        if "camera" in query:
            # Chromium's fake camera stands in for the phone's; without it: the visit.
            assert page.status()["mode"] in ("camera", "visit")
        assert not page.errors, page.errors
