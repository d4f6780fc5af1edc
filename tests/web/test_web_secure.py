"""The client against the real ``daylit serve`` (headless Chromium): the kiosk carries its URL's
operator token to the light stream and gets the site camera and its occlusion masks (and,
without it, says why it has none); a build file whose first copy arrives damaged is detected
by its SHA-256 and fetched again bypassing the cache, and one damaged every time is an error
that names it."""

from __future__ import annotations

import json

import pytest

from tests.server.helpers import KioskSequence
from tests.web.harness import DaylitServer

pytestmark = [pytest.mark.browser]

TOKEN = "kiosk-0c4e2f7a9b1d3e56"


@pytest.fixture(scope="module")
def kiosk_replay(web_build, tmp_path_factory):
    """The kiosk view with two people walking (30 frames, the first 10 of the empty site)."""
    return KioskSequence(web_build, frames=30, empty_frames=10).write(
        tmp_path_factory.mktemp("kiosk") / "frames")


def test_the_kiosk_forwards_its_token_and_gets_the_occlusion_stream(new_page, web_build,
                                                                     kiosk_replay):
    with DaylitServer(web_build, "--site-camera", f"replay:{kiosk_replay}",
                      token=TOKEN) as server:
        page = new_page().open(f"{server.url}/?mode=kiosk&token={TOKEN}&test")
        page.wait("window.daylit.status.occlusionMasks > 0 && "
                  "window.daylit.status.siteCameraFrames > 0", 90000)
        status = page.status()
        assert not status["siteCameraDenied"] and status["error"] is None
        assert page.errors == []
        page.page.close()  # one WebGL page at a time on SwiftShader

        # The same kiosk without the token: the light, no camera, and a note saying why.
        bare = new_page().open(f"{server.url}/?mode=kiosk&test")
        bare.wait("window.daylit.status.siteCameraDenied && window.daylit.status.lightSeq")
        bare.page.wait_for_timeout(1000)  # a frame would have come by now (10 per second)
        status = bare.status()
        assert status["siteCameraFrames"] == 0 and status["occlusionMasks"] == 0
        note = bare.page.evaluate("document.querySelector('#hud .message').textContent")
        assert "operator's token" in note, note


RECORD_FETCH_CACHE = """
window.fetchCacheModes = [];
const fetchAsIs = window.fetch;
window.fetch = (input, init) => {
  window.fetchCacheModes.push([String(input), init?.cache ?? 'default']);
  return fetchAsIs(input, init);
};
"""


def damage(body: bytes) -> bytes:
    """The same length, one byte flipped in the middle (the old length check passed it)."""
    out = bytearray(body)
    out[len(out) // 2] ^= 0x5A
    return bytes(out)


def test_a_damaged_download_is_fetched_again_bypassing_the_cache(new_page, web_build):
    model = json.loads((web_build / "manifest.json").read_text())["model"]["path"]
    with DaylitServer(web_build) as server:
        page = new_page()
        requests = []

        def first_damaged(route, request):
            requests.append(dict(request.headers))
            if len(requests) == 1:
                response = route.fetch()
                route.fulfill(response=response, body=damage(response.body()))
            else:
                route.continue_()

        page.page.route(f"**/build/{model}?*", first_damaged)
        page.page.add_init_script(RECORD_FETCH_CACHE)
        page.open(f"{server.url}/?mode=visit&test")
        status = page.status()
        assert status["integrity"] == "sha256"  # 127.0.0.1 is a secure context
        assert status["refetched"] == [model] and status["error"] is None
        assert len(requests) == 2
        # The second request bypassed the HTTP cache (and so replaced its copy).
        modes = page.page.evaluate("window.fetchCacheModes")
        assert [m for u, m in modes if f"/build/{model}?" in u] == ["default", "reload"]
        assert page.errors == []


def test_a_file_damaged_every_time_is_an_error_that_names_it(new_page, web_build):
    model = json.loads((web_build / "manifest.json").read_text())["model"]["path"]
    with DaylitServer(web_build) as server:
        page = new_page()

        def always_damaged(route, request):
            response = route.fetch()
            route.fulfill(response=response, body=damage(response.body()))

        page.page.route(f"**/build/{model}?*", always_damaged)
        page.open(f"{server.url}/?mode=visit&test", "window.daylit.status.error")
        error = page.status()["error"]
        assert model in error and "SHA-256" in error and "also when fetched again" in error
        note = page.page.evaluate("document.querySelector('#hud .message').textContent")
        assert "Could not load" in note, note


def test_an_insecure_page_checks_lengths_and_a_name_not_allowed_is_refused(browser, web_build):
    """Plain http:// under a LAN name (not localhost) has no SubtleCrypto: the client says it
    checks lengths only and boots; the name is served because --allow-host names it, and a
    name not allowed gets 421."""
    from tests.web.harness import CHROMIUM_FLAGS, chromium_path

    with DaylitServer(web_build, "--allow-host", "daylit.test") as server:
        flags = CHROMIUM_FLAGS + ["--host-resolver-rules=MAP daylit.test 127.0.0.1, "
                                  "MAP other.test 127.0.0.1"]
        remote = browser.browser_type.launch(executable_path=chromium_path(), args=flags,
                                             headless=True)
        try:
            page = remote.new_page(viewport={"width": 640, "height": 360})
            page.goto(f"http://daylit.test:{server.port}/?mode=visit&test")
            page.wait_for_function("window.daylit && window.daylit.status.ready", timeout=90000)
            assert page.evaluate("isSecureContext") is False
            status = page.evaluate("JSON.parse(JSON.stringify(window.daylit.status))")
            assert status["integrity"] == "length" and status["error"] is None
            refused = page.goto(f"http://other.test:{server.port}/")
            assert refused.status == 421
        finally:
            remote.close()
