"""End to end with ``daylit serve``: a replayed sky, the page, the light sequence advancing,
the picture changing as the reference says; the server stopped and restarted; an asset that
fails; the graphics context lost and restored; no console errors in normal use."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from tests.web.harness import DaylitServer, StubServer, decode_floats, free_port

pytestmark = [pytest.mark.browser]


def fisheye(size=256, sky_code=150, sun=None):
    """An ideal equidistant fisheye frame (zenith at the centre, north up, east left, as the
    server's default lens): a uniform sky, optionally with a bright round sun."""
    img = np.zeros((size, size, 3), np.uint8)
    c = size / 2
    cv2.circle(img, (int(c), int(c)), int(c) - 1, (sky_code,) * 3, -1)
    if sun is not None:
        az, el = np.radians(sun[0]), sun[1]
        rho = (90 - el) / 90 * c
        x, y = c - rho * math.sin(az), c - rho * math.cos(az)
        cv2.circle(img, (int(x), int(y)), 14, (235, 235, 235), -1)
    return img


@pytest.fixture(scope="module")
def replay_dir(tmp_path_factory):
    """Two skies, each held for a while: overcast-like, then dimmer with a sun."""
    d = tmp_path_factory.mktemp("sky")
    for i in range(6):
        cv2.imwrite(str(d / f"a{i:02d}.png"), fisheye(sky_code=150))
    for i in range(6):
        cv2.imwrite(str(d / f"b{i:02d}.png"), fisheye(sky_code=90, sun=(135, 40)))
    return d


def serve_args(replay_dir):
    return ["--sky", f"replay:{replay_dir}", "--set", "sky.rate_hz=4",
            "--set", "stream.smoothing_s=0"]


def snapshot(page, key):
    s = page.page.evaluate("(k) => window.daylit.debug.snapshot(k)", key)
    return np.array(s["r"]).reshape(-1, 3), decode_floats(s)[..., :3], s["sequence"]


def test_replayed_sky_relights_the_picture_as_the_reference_says(
        new_page, web_build, reference, replay_dir):
    with DaylitServer(web_build, *serve_args(replay_dir)) as server:
        page = new_page().open(f"{server.url}/?mode=visit&test&exposure=0.02",
                               "window.daylit.status.ready && window.daylit.status.lightsExact")
        first_seq = page.status()["lightSeq"]
        r1, t1, _ = snapshot(page, "lightmap.I")
        # Wait until the other sky has been applied (mean radiance changes by a quarter).
        mean1 = r1.mean()
        page.wait(f"window.daylit.status.lightSeq > {first_seq}")
        for _ in range(100):
            r2, t2, seq2 = snapshot(page, "lightmap.I")
            if abs(r2.mean() / mean1 - 1) > 0.25:
                break
            page.page.wait_for_timeout(200)
        else:
            pytest.fail("the replayed sky never changed the applied light")
        assert seq2 > first_seq
        assert not page.errors, page.errors  # normal use: nothing in the console
    # The picture changed the way the reference says: the region's brightness ratio.
    walls = reference.composite("lightmap", "I", r1, "master").mean(axis=2) > 1e-3
    for region in (walls, np.ones_like(walls)):
        got = t2.mean(axis=2)[region].mean() / t1.mean(axis=2)[region].mean()
        want = (reference.composite("lightmap", "I", r2, "compact").mean(axis=2)[region].mean()
                / reference.composite("lightmap", "I", r1, "compact").mean(axis=2)[region].mean())
        assert got == pytest.approx(want, rel=5e-3), (got, want)


def test_stopping_the_server_shows_stale_and_a_restart_recovers_without_reload(
        new_page, web_build, replay_dir):
    port = free_port()
    server = DaylitServer(web_build, *serve_args(replay_dir), port=port).start()
    try:
        page = new_page().open(f"{server.url}/?mode=visit",
                               "window.daylit.status.ready && window.daylit.status.lightSeq > 0")
        page.page.evaluate("window.__sameDocument = true")
        assert page.status()["connected"] and not page.status()["stale"]
        relights = page.status()["relights"]
        server.stop()
        page.wait("!window.daylit.status.connected && window.daylit.status.stale")
        # The HUD redraws its line on its own clock, a moment after the status changes.
        page.wait("/reconnecting|stale/.test(document.querySelector('.statusline').textContent)")
        line = page.page.inner_text(".statusline")
        assert "reconnecting" in line or "stale" in line, line
        assert page.status()["lightSeq"] is not None  # the last light is kept
        server = DaylitServer(web_build, *serve_args(replay_dir), port=port).start()
        page.wait("window.daylit.status.connected && !window.daylit.status.stale", 60000)
        page.wait(f"window.daylit.status.relights > {relights}")
        assert page.page.evaluate("window.__sameDocument === true")
        assert "live" in page.page.inner_text(".statusline")
    finally:
        server.stop()


def test_an_asset_that_fails_shows_its_message(new_page, web_build):
    missing = "build/ktx2/lightmap.I.base.ktx2"
    with StubServer(web_build, fail_paths=(missing,)) as server:
        page = new_page().open(f"{server.url}/?mode=visit", "window.daylit.status.error")
        error = page.status()["error"]
        assert "ktx2/lightmap.I.base.ktx2" in error and "404" in error, error
        message = page.page.inner_text(".message")
        assert "Could not load ktx2/lightmap.I.base.ktx2" in message and "Retrying" in message
        assert page.page.is_visible(".message")
        page.screenshot("asset-failure")


def test_a_lost_graphics_context_is_restored(new_page, web_build, reference):
    from tests.web.kioskref import light_message

    with StubServer(web_build) as server:
        server.push(light_message(reference.light_vector("overcast"), 3), remember=True)
        page = new_page().open(f"{server.url}/?mode=visit&test",
                               "window.daylit.status.ready && window.daylit.status.lightsExact")
        before = page.status()["relights"]
        page.page.evaluate("window.daylit.debug.loseContext()")
        page.wait("window.daylit.status.contextLost || window.daylit.status.relights > "
                  f"{before}", 10000)
        page.wait("!window.daylit.status.contextLost && window.daylit.status.ready && "
                  "window.daylit.status.lightsExact", 60000)
        assert page.status()["lightSeq"] == 3
        assert not page.errors, page.errors
