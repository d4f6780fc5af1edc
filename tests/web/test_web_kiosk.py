"""The kiosk composite (Sato Eq. 9) in headless Chromium against numpy, and occlusion by
visitors (issue 6): a person in front of a virtual object hides it, one behind does not.

Eq. 9 with a live frame P (linear, from the sRGB image), relit O' and S', mask M, camera
scale k:  k O' where M = 255 (virtual), P where M = 128 (sky), P O'/S' where M = 0 (real).
Synthesized background (no frame): P = k S' on real pixels and k sum r phi on the sky.
Tolerance per pixel and channel: |gpu - ref| <= 5e-3 |ref| + 2e-3 (O' and S' are half
floats, 4.9e-4 relative each, and the ratio doubles it; P's sRGB decoding by the GPU is
exact to 8-bit precision). Measured worst: printed by the test.
"""

from __future__ import annotations

import types

import cv2
import numpy as np
import pytest

from bake.views import pixel_rays, sky_weights
from server.occlusion import OcclusionProcessor, encode_message
from server.occlusion.synthetic import SyntheticSite, Walker
from tests.web.harness import StubServer, srgb_to_linear
from tests.web.kioskref import (
    ABS,
    KIOSK_HELLO,
    REL,
    composite,
    eq9,
    frame_message,
    light_message,
    open_kiosk,
    view_inputs,
    worst,
)

pytestmark = [pytest.mark.browser]

@pytest.mark.parametrize("version", [1, 3], ids=["float32", "float16"])
def test_kiosk_composite_equals_eq9(new_page, web_build, reference, version):
    """Version 3 sends the sky in float16; the reference is computed from the exact vector, so
    the wire's rounding has to fit in the same tolerance."""
    ref = reference
    r = ref.light_vector("clear:135,40")
    view, O, S, mask = view_inputs(ref, r)
    h, w = view["height"], view["width"]
    k = 0.4 / O[mask == 255].mean()
    with StubServer(web_build, dict(KIOSK_HELLO, protocol=version)) as server:
        page = open_kiosk(server, new_page, r, message=light_message(r, 1, version=version))
        page.page.evaluate("(k) => window.daylit.debug.setCameraScale(k)", k)
        # Without a frame: the synthesized background.
        gpu = composite(page)
        vv = types.SimpleNamespace(width=w, height=h, K=np.array(view["K"]),
                                   world_from_camera=np.array(view["world_from_camera"]))
        _, dirs = pixel_rays(vv)
        centroids = np.array([light["centroid"] for light in ref.manifest["dome"]["lights"]])
        sky = (sky_weights(dirs, centroids) @ r).reshape(h, w, 3)
        want = np.where(mask[..., None] == 255, k * O,
                        np.where(mask[..., None] == 128, k * sky, k * S * eq9(O, S, mask, 1.0, 1)))
        synthesized = worst(gpu, want)
        assert synthesized <= 1.0, synthesized
        # With a frame P: random colours, so a misplaced pixel cannot pass.
        rng = np.random.default_rng(3)
        P8 = rng.integers(0, 256, size=(h, w, 3), dtype=np.uint8)
        png = cv2.imencode(".png", P8[..., ::-1])[1].tobytes()  # lossless, so P is known
        server.push(frame_message(png, 1, 1.0e9 + 1))
        page.wait("window.daylit.debug.kioskState().hasFrame === 1")
        gpu = composite(page)
        live = worst(gpu, eq9(O, S, mask, srgb_to_linear(P8), k))
        assert live <= 1.0, live
        assert not page.errors, page.errors
    print(f"\nEq. 9 (protocol {version}): worst {live:.3f}, synthesized {synthesized:.3f} of "
          "the tolerance")


def people_frames(build_dir):
    """Frames of two people crossing the demo's kiosk view, one in front of the virtual
    building and one behind it, with the occlusion processor's masks (as the server will
    send them) and the pixels where each person is seen against the building."""
    proc = OcclusionProcessor.from_build(build_dir, "kiosk")
    cam = proc.camera
    depth = proc.virtual_depth_m
    rows, cols = np.nonzero(np.isfinite(depth))
    u = int(np.median(cols))
    building_m = float(depth[rows[cols == u].max(), u])
    forward = cam.R[:, 2]
    ray = cam.ray_directions(u + 0.5, 90.0)[0]
    heading = np.array([ray[0], 0.0, ray[2]]) / np.hypot(ray[0], ray[2])
    side = np.array([heading[2], 0.0, -heading[0]])

    def walker(depth_m, start_side_m, speed_mps, **clothes):
        along = depth_m / float(heading @ forward)
        p = cam.origin_m * [1, 0, 1] + heading * along + side * start_side_m
        v = side * speed_mps
        return Walker((p[0], p[2]), (v[0], v[2]), enter_s=1.0, **clothes)

    site = SyntheticSite(cam, [walker(0.6 * building_m, -1.5, 0.6),
                               walker(1.2 * building_m, 1.5, -0.6, shirt=(0.1, 0.5, 0.2))],
                         fps=10.0, duration_s=2.5)
    for i in range(site.frame_count):
        truth = site.frame(i)
        result = proc.process(truth.image, capture_time_s=1.0e9 + i / 10)
        assert result.ok
    near, far = sorted(truth.people, key=lambda t: t.depth_m)
    over = np.isfinite(depth)
    near_px = (truth.person_index == near.index) & over
    far_px = (truth.person_index == far.index) & over
    return truth.image, result, near_px, far_px


def test_a_person_in_front_hides_the_virtual_building_and_one_behind_does_not(
        new_page, web_build, reference):
    image, result, near_px, far_px = people_frames(web_build)
    assert near_px.sum() > 20 and far_px.sum() > 10
    ref = reference
    r = ref.light_vector("overcast")
    _, O, _, mask = view_inputs(ref, r)
    t = result.capture_time_s
    jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()
    P = srgb_to_linear(cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)[..., ::-1])
    k = 1.5 / O[mask == 255].mean()  # virtual pixels clearly brighter than the people
    with StubServer(web_build, KIOSK_HELLO) as server:
        page = open_kiosk(server, new_page, r)
        page.page.evaluate("(k) => window.daylit.debug.setCameraScale(k)", k)
        # As the server sends them: the frame, then its mask with the same capture time.
        server.push(frame_message(jpeg, 7, t),
                    encode_message(result.mask, 7, t, result.people_in_front))
        page.wait(f"(s => s.hasOcclusion === 1 && s.maskCaptureTime === {t!r})"
                  "(window.daylit.debug.kioskState())")
        state = page.page.evaluate("window.daylit.debug.kioskState()")
        assert state["frameCaptureTime"] == state["maskCaptureTime"] == t
        assert any('"occlusion"' in m for m in server.received)  # it subscribed
        gpu = composite(page)
        page.screenshot("kiosk-occlusion")
        assert not page.errors, page.errors
    shows_person = np.abs(gpu - P).mean(axis=2) < np.abs(gpu - k * O).mean(axis=2)
    # The near person stands in front: the picture shows them, not the building.
    assert shows_person[near_px].mean() > 0.9, shows_person[near_px].mean()
    # The far person stands behind: the building hides them.
    assert shows_person[far_px].mean() < 0.05, shows_person[far_px].mean()
    assert np.allclose(gpu[far_px], k * O[far_px], rtol=REL, atol=ABS)
    print(f"\nocclusion: near shown {shows_person[near_px].mean():.3f}, "
          f"far shown {shows_person[far_px].mean():.3f}")
