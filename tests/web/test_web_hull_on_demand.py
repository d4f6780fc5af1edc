"""The hull planes (the largest download of a phone) are fetched only when hull-plane mode is
chosen; then they are relit with the current light exactly as the reference says, and a
failed download leaves the lightmap shading in place with a message."""

from __future__ import annotations

import numpy as np
import pytest

from tests.web.harness import StubServer, decode_floats
from tests.web.kioskref import light_message
from tests.web.test_web_relight import check

pytestmark = [pytest.mark.browser]

READY = "window.daylit.status.ready && window.daylit.status.lightsExact"
HULL_FILES = "performance.getEntriesByType('resource').map((e) => e.name)" \
             ".filter((u) => u.includes('/hull.'))"


def test_hull_planes_load_only_in_hull_plane_mode(new_page, web_build, reference):
    r = reference.light_vector("clear:135,40")
    with StubServer(web_build) as server:
        server.push(light_message(r, 7), remember=True)
        page = new_page().open(f"{server.url}/?mode=visit&test", READY)
        assert page.status()["shadingMode"] == "lightmap"
        assert page.page.evaluate(HULL_FILES) == []
        loaded_before = page.status()["bytesLoaded"]

        page.page.select_option(".shadingmode", "hull")
        page.wait(f"window.daylit.status.shadingMode === 'hull' && {READY}", 60000)
        fetched = page.page.evaluate(HULL_FILES)
        assert any("hull.d.base.ktx2" in u for u in fetched), fetched
        assert any("hull.I.base.ktx2" in u for u in fetched), fetched
        assert page.status()["bytesLoaded"] > loaded_before

        # Relit with the light that was already applied, as the numpy reference says.
        snap = page.page.evaluate("window.daylit.debug.snapshot('hull.d')")
        assert snap["sequence"] == 7
        applied = np.array(snap["r"]).reshape(-1, 3)
        np.testing.assert_allclose(applied, r, rtol=1e-3)  # the message's light, float32
        want = reference.compact("hull", "d").composite(applied, reference.selection)
        check("hull.d after activation", decode_floats(snap)[..., :3], want)
        assert not page.errors, page.errors


def test_a_failed_hull_download_keeps_the_lightmap(new_page, web_build, reference):
    r = reference.light_vector("overcast")
    with StubServer(web_build, fail_paths=("build/ktx2/hull.d.base.ktx2",)) as server:
        server.push(light_message(r, 2), remember=True)
        page = new_page().open(f"{server.url}/?mode=visit", READY)
        page.page.select_option(".shadingmode", "hull")
        page.wait("document.querySelector('.message').textContent.includes('Staying with')")
        message = page.page.inner_text(".message")
        assert "ktx2/hull.d.base.ktx2" in message and "404" in message, message
        assert page.status()["shadingMode"] == "lightmap"
        assert page.page.eval_on_selector(".shadingmode", "s => s.value") == "lightmap"
        assert page.status()["ready"] and page.status()["error"] is None
