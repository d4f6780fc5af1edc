"""The offline visit (docs/web.md, "Offline"): a visit opened once with the real server
(`daylit serve`) keeps its files in the service worker (web/sw.js) and the last live light on
the phone; with the server gone, the page opens again from what was kept, every file with its
manifest's SHA-256, and draws the kept light: the same picture as a page served live and given
that light, within the AR test's tolerance. The server back, the live light takes over."""

from __future__ import annotations

import base64
import json
import time

import numpy as np
import pytest

from tests.web.harness import DaylitServer, StubServer

pytestmark = [pytest.mark.browser]

# `sw`: test pages register the worker only when asked (offline.js registerOffline).
URL = "/?mode=visit&test&sw&exposure=0.5&smoothing=0"
READY = "window.daylit && window.daylit.status.ready"
CAMERA = ([18.0, 7.0, 24.0], [0.0, 2.0, 0.0])  # metres, the site's frame
# The simulated sun held still (a summer morning, a thousandth of real time): at the default
# 20 times real time it can enter another patch during the online visit, whose page then
# fetched that patch's sun-bounce images too, which the offline page never asks for.
SKY = ("--set", "sim.start=2026-06-21T10:00", "--set", "sim.clock_speed=0.001")


def screen(page) -> np.ndarray:
    """(H, W, 3) uint8 of the displayed picture."""
    s = page.evaluate("window.daylit.debug.screen(true)")
    image = np.frombuffer(base64.b64decode(s["data"]), np.uint8)
    return image.reshape(s["height"], s["width"], 4)[..., :3]


def test_an_offline_visit_opens_from_what_was_kept_with_the_kept_light(new_page, web_build):
    manifest = json.loads((web_build / "manifest.json").read_text())
    server = DaylitServer(web_build, *SKY).start()
    try:
        online = new_page().open(server.url + URL, READY)
        online.wait("window.daylit.status.lightSource === 'server'"
                    " && window.daylit.status.lightsExact"
                    " && window.daylit.status.offlineKept !== null"
                    " && window.daylit.status.sunBouncePatch !== null", 60000)
        status = online.status()
        assert status["offlineWorker"] == "registered"
        assert status["offlineKept"]["failed"] == 0, status["offlineKept"]
        loaded_bytes = status["bytesLoaded"]
        kept_light = online.page.evaluate(
            f"JSON.parse(localStorage.getItem('daylit.light.{manifest['scene']['id']}'))")
        assert len(kept_light["rgb"]) == 3 * manifest["dome"]["count"]
    finally:
        server.stop()

    # The server is gone: the same page opens again from the worker's copies.
    online.page.reload()
    online.wait(READY, 60000)
    # Its sun's bounce drawn too (its images read after the site is shown, as online).
    online.wait("window.daylit.status.lightSource === 'kept' && window.daylit.status.lightsExact"
                " && window.daylit.status.sunBouncePatch !== null", 60000)
    status = online.status()
    assert not status["connected"]
    assert status["bytesLoaded"] == loaded_bytes
    # Every file checked against the manifest's SHA-256, none fetched again, no error.
    assert status["integrity"] == "sha256" and status["refetched"] == [] and status["error"] is None
    assert "kept from the last visit" in online.page.locator("#hud").inner_text()
    online.page.evaluate("([p, t]) => window.daylit.debug.setCamera(p, t)", list(CAMERA))

    # The reference: the same build served live, given the kept light by the test.
    with StubServer(web_build) as stub:
        live = new_page().open(stub.url + "/?mode=visit&test&exposure=0.5&smoothing=0", READY)
        live.page.evaluate("([r, s]) => window.daylit.debug.relight(r, 1, s)",
                           [kept_light["rgb"], kept_light["sun"]])
        live.page.evaluate("([p, t]) => window.daylit.debug.setCamera(p, t)", list(CAMERA))
        reference = screen(live.page)
    assert reference.std() > 10  # a precondition: the site is in view, lit

    # The offline page draws the sun's bounce when its images are read (from the kept copies):
    # waited for by the picture itself, whatever the frame rate.
    deadline = time.monotonic() + 60
    while True:
        diff = np.abs(screen(online.page).astype(int) - reference.astype(int))
        if (diff.mean() < 1.0 and np.percentile(diff, 99) <= 4) or time.monotonic() > deadline:
            break
        time.sleep(1)
    assert diff.mean() < 1.0 and np.percentile(diff, 99) <= 4, (diff.mean(),
                                                                np.percentile(diff, 99))

    # The server back on its port: the live light replaces the kept one, and its note goes.
    with DaylitServer(web_build, *SKY, port=server.port):
        online.wait("window.daylit.status.lightSource === 'server'", 60000)
        online.wait("document.querySelector('#hud').innerText.indexOf('kept from') < 0")
    errors = [e for e in online.errors
              if "WebSocket" not in e and "ERR_CONNECTION_REFUSED" not in e]
    assert not errors and not live.errors, errors + live.errors
