"""The client's GPU memory (web/src/gpumemory.js, `status.gpuTextureBytes`; issue 17's phone
budget) on a phone's viewport (390 x 844 CSS px at device pixel ratio 3: 780 x 1688 drawn),
against budgets computed here from what each mode needs, not from the client:

- switching the hull planes on adds exactly what their stacks hold by the manifest: per stack
  its UASTC base array decoded to RGBA8 (4 bytes a texel), its ETC1S array as ETC2 RGB8 blocks
  (half a byte a texel; 4 before 2026-11-25, when it was decoded to RGBA8 too), its relight
  target (RGBA16F), and the gain array the two stacks share, once (RGBA8; once per stack
  before);
- the ETC1S arrays on the GPU as ETC2 change no texel: every relit target is bit-identical to
  the one drawn with every array decoded to RGBA8 (`?textures=rgba8`, which the known-answer
  tests in test_web_relight.py hold against numpy);
- the canvas has no MSAA where the linear HDR frame draws (one single-sampled RGBA8 + depth,
  8 bytes a pixel; 4 samples before);
- the sun's shadow maps hold per map a float32 depth, an RGBA8 visibility map, an R8 ground
  visibility with its mipmaps and two RGBA8 coarse maps, and one RGBA8 normals target for
  both (one per map before), 2048² on a desktop and 1024² on a phone (the client tells a
  phone by its touch screen at most 600 px across; 2048² everywhere before).
"""

from __future__ import annotations

import base64
from pathlib import Path

import numpy as np
import pytest

from tests.sunbounce_levels import is_etc1s
from tests.web.harness import StubServer
from tests.web.kioskref import light_message

pytestmark = [pytest.mark.browser]

# a phone as Chromium emulates one: touch (pointer: coarse) on a 390 px wide screen, so the
# client takes its phone profile by itself
PHONE = dict(viewport={"width": 390, "height": 844}, device_scale_factor=3, is_mobile=True,
             has_touch=True)
DESKTOP = dict(viewport={"width": 960, "height": 540})
PHONE_DRAWN_PX = (780, 1688)  # the client caps the pixel ratio at 2
SUN_MAP_PX = {"desktop": 2048, "phone": 1024}  # web/src/sun.glsl.js MAP_SIZE, PHONE_MAP_SIZE
SUN_CELL = 16  # its CELL: a coarse texel per 16 x 16


def hull_bytes(manifest: dict) -> int:
    atlas = next(a for a in manifest["atlases"] if a["id"] == "hull")
    texels = atlas["width"] * atlas["height"]
    blocks = -(-atlas["width"] // 4) * -(-atlas["height"] // 4)  # ETC2: 8 bytes a 4x4 block
    total = 0
    gains = {}  # the I and d stacks share one gain file: one texture
    for stack in atlas["stacks"].values():
        c = stack["compact"]
        etc1s = c["etc1s"]["layers"] if "etc1s" in c else 0
        uastc = len(c["layers"]) - etc1s  # the base array's layers, refinements included
        if "gain" in c:
            gains[c["gain"]["ktx2"]] = len(c["gain"]["layers"])
        total += 4 * texels * uastc + 8 * blocks * etc1s + 8 * texels
    return total + 4 * texels * sum(gains.values())


def sun_bytes(maps: int, size: int) -> int:
    texels = size**2
    ground = sum((size >> level) ** 2 for level in range(size.bit_length()))
    coarse = 4 * ((size // SUN_CELL) * size + (size // SUN_CELL) ** 2)
    return maps * (4 * texels + 4 * texels + ground + coarse) + 4 * texels


def bounce_bytes(build_dir: Path, manifest: dict, patch: int, etc1s_format: str,
                 hull: bool = False) -> int:
    """The sun-bounce images of one sun patch the visit holds: every atlas stack's with an image
    for that patch (its scale not null), each of its levels (one or two: ``len(scale[p])``)
    decoded to RGBA8 (UASTC), or, for a coarse image stored with ETC1S (its KTX2 header's
    supercompression scheme 1, BasisLZ; since 2026-12-06 evening) where the client takes
    ETC1S as ETC2 (``etc1s_format``, its status), 8 bytes a 4 x 4 block; the hull planes'
    only in hull-plane mode (``hull``; since 2026-12-06 the client fetches them only then)."""
    total = 0
    for atlas in manifest["atlases"]:
        if atlas["id"] == "hull" and not hull:
            continue
        texels = atlas["width"] * atlas["height"]
        blocks = -(-atlas["width"] // 4) * -(-atlas["height"] // 4)
        for stack in atlas.get("sun_bounce", {}).values():
            lights = stack["compact"]["lights"]
            if lights["scale"][patch] is None:
                continue
            shared = lights.get("image")  # the light whose files hold each light's image
            holder = shared[patch] if shared else patch
            for level in range(len(lights["scale"][patch])):
                file = build_dir / lights["ktx2"][level].format(index=holder)
                etc2 = is_etc1s(file) and etc1s_format == "etc2"
                total += 8 * blocks if etc2 else 4 * texels
    return total


class PhonePage:
    def __init__(self, browser, url, device=PHONE):
        self.context = browser.new_context(**device)
        self.page = self.context.new_page()
        self.errors = []
        self.page.on("console", lambda m: self.errors.append(m.text) if m.type == "error" else None)
        self.page.on("pageerror", lambda e: self.errors.append(str(e)))
        self.page.goto(url)
        self.page.wait_for_function("window.daylit && window.daylit.status.exactRelitMs !== null",
                                    timeout=120000)

    def status(self) -> dict:
        return self.page.evaluate("JSON.parse(JSON.stringify(window.daylit.status))")

    def frames(self, n=3):
        self.page.evaluate("(n) => new Promise((ok) => { let i = 0; const f = () =>"
                           " (++i > n ? ok() : requestAnimationFrame(f)); f(); })", n)

    def target(self, key) -> np.ndarray:
        snap = self.page.evaluate("(k) => window.daylit.debug.snapshot(k)", key)
        return np.frombuffer(base64.b64decode(snap["data"]), np.float32)


def test_hull_planes_add_what_the_manifest_says(browser, web_build, reference):
    with StubServer(web_build) as server:
        server.push(light_message(reference.light_vector("clear:135,40"), 1), remember=True)
        page = PhonePage(browser, f"{server.url}/?mode=visit&test")
        try:
            assert page.page.evaluate("window.daylit.debug.stacks()")  # a precondition
            before = page.status()
            # SwiftShader has WEBGL_compressed_texture_etc, as phones do (OpenGL ES 3.0)
            assert before["etc1sTextures"] == "etc2"
            page.page.evaluate("window.daylit.debug.activateAll()")
            after = page.status()
            added = after["gpuTextureBytes"] - before["gpuTextureBytes"]
            assert added == hull_bytes(server.manifest)
            # the linear frame draws: the canvas single-sampled, colour and depth
            assert page.page.evaluate("window.daylit.debug.formats().linearFrame")
            assert after["gpuDrawingBufferBytes"] == PHONE_DRAWN_PX[0] * PHONE_DRAWN_PX[1] * 8
            assert not page.errors, page.errors
        finally:
            page.context.close()


def test_etc2_arrays_change_no_texel(browser, web_build, reference):
    with StubServer(web_build) as server:
        server.push(light_message(reference.light_vector("clear:135,40"), 1), remember=True)
        targets = {}
        for query in ("", "&textures=rgba8"):
            page = PhonePage(browser, f"{server.url}/?mode=visit&test&shading=hull{query}")
            try:
                status = page.status()
                assert status["etc1sTextures"] == ("rgba8" if query else "etc2")
                # UASTC stays RGBA8 by default, ASTC on the GPU or not (SwiftShader has it):
                # as ASTC the relit targets are 0.1-3.5 % RMS off (docs/benchmarks.md)
                assert status["uastcTextures"] == "rgba8"
                keys = page.page.evaluate("window.daylit.debug.targets()")
                assert {"hull.I", "hull.d", "ground.I", "ground.d", "lightmap.I"} <= set(keys)
                targets[query] = {k: page.target(k) for k in keys}
                assert not page.errors, page.errors
            finally:
                page.context.close()
        for key, rgba8 in targets["&textures=rgba8"].items():
            assert np.abs(rgba8).max() > 0, key  # a precondition: something was drawn
            assert np.array_equal(targets[""][key], rgba8), key


@pytest.mark.parametrize("profile", ["desktop", "phone"])
def test_sun_maps_share_their_normals(browser, web_build, reference, profile):
    from daylit import sky as skies

    with StubServer(web_build) as server:
        server.push(light_message(reference.light_vector("clear:135,40"), 1), remember=True)
        device = PHONE if profile == "phone" else DESKTOP
        page = PhonePage(browser, f"{server.url}/?mode=visit&test", device)
        try:
            assert page.status()["profile"] == profile  # from the screen, not the URL
            before = page.status()["gpuTextureBytes"]
            r = skies.patch_mean_radiance(skies.clear_sky(135, 40), reference.dome_vertices,
                                          include_sun=False)
            sun = {"direction": skies.direction_from_azimuth_elevation(135, 40).tolist(),
                   "normalIrradiance": skies.clear_sky(135, 40).sun.normal_irradiance.tolist()}
            page.page.evaluate("([r, s]) => window.daylit.debug.relight(r, 2, s)",
                               [r.astype(float).ravel().tolist(), sun])
            page.frames()
            assert page.page.evaluate("window.daylit.debug.sunShadowRenders()") >= 1
            maps = len(page.page.evaluate("window.daylit.debug.sunMaps().texelM"))
            assert maps == 2  # the demo has real proxies: a map of all casters, one of the real
            named = sum(a["bytes"] for a in page.page.evaluate("window.daylit.debug.gpuBreakdown()")
                        if a["name"].startswith("sun ") and not a["name"].startswith("sun bounce"))
            assert named == sun_bytes(maps, SUN_MAP_PX[profile])
            # and the sun added them and the bounce images of its patch (its levels, RGBA8, per
            # atlas stack that has one), nothing else
            patch = page.page.evaluate("window.daylit.debug.sunBounce()")
            assert patch >= 0  # a precondition
            added = page.status()["gpuTextureBytes"] - before
            assert added == sun_bytes(maps, SUN_MAP_PX[profile]) + bounce_bytes(
                web_build, server.manifest, patch, page.status()["etc1sTextures"])
            assert not page.errors, page.errors
        finally:
            page.context.close()
