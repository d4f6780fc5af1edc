"""The client's GPU memory meter (web/src/gpumemory.js, `status.gpuTextureBytes`): what it
counts when the hull planes are switched on equals what the manifest says those stacks hold,
counted here in Python: per stack its base array (UASTC layers decoded to RGBA8: 4 bytes a
texel), its ETC1S array, its gain array and its relight target (RGBA16F: 8 bytes a texel,
allocated when first drawn)."""

from __future__ import annotations

import pytest

from tests.web.harness import StubServer
from tests.web.kioskref import light_message

pytestmark = [pytest.mark.browser]


def hull_bytes(manifest: dict) -> int:
    atlas = next(a for a in manifest["atlases"] if a["id"] == "hull")
    texels = atlas["width"] * atlas["height"]
    total = 0
    for stack in atlas["stacks"].values():
        c = stack["compact"]
        layers = len(c["layers"])  # the base array's and the ETC1S array's together
        gain = len(c["gain"]["layers"]) if "gain" in c else 0
        total += 4 * texels * (layers + gain) + 8 * texels
    return total


def test_meter_counts_what_the_manifest_says(new_page, web_build, reference):
    with StubServer(web_build) as server:
        server.push(light_message(reference.light_vector("clear:135,40"), 1), remember=True)
        page = new_page(960, 540).open(f"{server.url}/?mode=visit&test",
                                       "window.daylit.status.exactRelitMs !== null")
        assert page.page.evaluate("window.daylit.debug.stacks()")  # a precondition
        before = page.status()
        assert before["gpuTextureBytes"] > 0 and before["gpuDrawingBufferBytes"] > 0
        page.page.evaluate("window.daylit.debug.activateAll()")
        after = page.status()
        assert after["gpuTextureBytes"] - before["gpuTextureBytes"] == hull_bytes(server.manifest)
        assert not page.errors, page.errors
