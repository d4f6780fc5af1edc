"""The AR mode in headless Chromium under an emulated WebXR device (IWER, tests/web/xremu.py):
the session starts from the AR button, the reticle finds the emulated floor where the test's
own ray meets it, a tap (the controller's trigger: a WebXR select) places the site's origin
there, and as the device moves and turns the hall stays put: the eye the page draws with is
the pose the test computed, and the drawn AR frame matches, pixel for pixel within a
tolerance, the visit mode's frame drawn from that same pose (computed in the test, relative
to the placed site) with the same light and exposure (issue 17)."""

from __future__ import annotations

import base64

import cv2
import numpy as np
import pytest

from tests.web import xremu
from tests.web.harness import SCREENSHOTS, StubServer
from tests.web.kioskref import light_message

pytestmark = [pytest.mark.browser]

SKY = "clear:135,40"
SKY2 = "clear:200,25"
SIZE = (640, 360)
EXPOSURE = 0.5
# AR draws straight to the screen (its passthrough: docs/web.md, "How the picture is
# displayed"), so the visit it is compared with does too (`frame=direct`): the same
# compositing and the canvas's own antialiasing on both sides.
URL = f"/?mode=visit&test&exposure={EXPOSURE}&frame=direct"
READY = "window.daylit.status.ready"
# The device where the visitor taps (looking 4 degrees down: the floor 23 m ahead), then
# where it walks and turns to, hall in view: (position m, yaw deg, pitch deg, roll deg).
START = ((0.5, 1.6, 1.0), 20.0, -4.0, 0.0)
POSES = [
    ((0.5, 1.6, 1.0), 20.0, -4.0, 0.0),
    ((3.0, 1.7, -2.0), 35.0, -2.0, 0.0),
    ((-4.0, 1.5, 4.0), 5.0, 3.0, 4.0),
    ((1.0, 1.2, 6.0), 25.0, 8.0, -3.0),
]
# Site points (metres, the site's own frame) whose screen positions are checked.
SITE_POINTS_M = np.array([[0.0, 0.0, 0.0], [0.0, 3.0, 0.0], [5.0, 2.0, -5.0], [-6.0, 4.0, 3.0]])


def screen(page, render=True) -> np.ndarray:
    """(H, W, 4) uint8 of the displayed picture."""
    s = page.evaluate(f"window.daylit.debug.screen({str(render).lower()})")
    return np.frombuffer(base64.b64decode(s["data"]), np.uint8).reshape(s["height"], s["width"], 4)


def set_pose(page, pose_spec):
    position, yaw, pitch, roll = pose_spec
    pose = xremu.pose_m(position, xremu.rotation(yaw, pitch, roll))
    page.evaluate("([p, q]) => { window.__xr.position.set(...p);"
                  " window.__xr.quaternion.set(...q); }",
                  [list(position), xremu.quaternion(pose[:3, :3])])
    frames = page.evaluate("window.daylit.debug.xrState().frames")
    # The pose is read at the next XR frame; two more make sure one was drawn with it.
    page.wait_for_function(f"window.daylit.debug.xrState().frames >= {frames + 3}", timeout=30000)
    return pose


def relight(page, sky, sun=None, sequence=1):
    page.evaluate("([r, s, n]) => window.daylit.debug.relight(r, n, s)",
                  [sky.ravel().tolist(), sun, sequence])


def sun_of(sky_spec: str) -> dict:
    """The sun of a clear sky "clear:AZ,EL", as a version-2 light message carries it."""
    from daylit import sky as skies

    azimuth_deg, elevation_deg = (float(v) for v in sky_spec.split(":")[1].split(","))
    return {"direction": skies.direction_from_azimuth_elevation(azimuth_deg,
                                                                elevation_deg).tolist(),
            "normalIrradiance": skies.clear_sky(azimuth_deg,
                                                elevation_deg).sun.normal_irradiance.tolist()}


def open_ar(new_page, server, sky, sun=None):
    """An AR page whose session runs with the site placed by a tap at the START pose's floor
    hit (checked on the way); returns the page and the hit (3,), metres."""
    ar = new_page(*SIZE)
    ar.page.add_init_script(xremu.init_script())
    ar.open(server.url + URL, READY)
    relight(ar.page, sky, sun)
    assert ar.page.evaluate("navigator.xr.isSessionSupported('immersive-ar')")
    button = ar.page.locator('[data-mode="ar"]')
    assert button.is_visible()
    button.click()
    ar.wait("window.daylit.status.mode === 'ar' && window.daylit.debug.xrState().frames > 2")
    state = ar.page.evaluate("window.daylit.debug.xrState()")
    assert state["alignment"]["position"] == [0, 0, -10]  # nothing stored yet

    start = set_pose(ar.page, START)
    hit = xremu.floor_hit_m(start)
    ar.wait("window.daylit.debug.xrState().reticleVisible")
    state = ar.page.evaluate("window.daylit.debug.xrState()")
    np.testing.assert_allclose(state["reticle"], hit, atol=1e-3)
    assert np.hypot(hit[0] - 0.5, hit[2] - 1.0) > 20  # a precondition: a far tap

    # The tap: a WebXR select (press and release of the controller's trigger).
    ar.page.evaluate("window.__xr.controllers.right.updateButtonValue('trigger', 1)")
    set_pose(ar.page, START)
    ar.page.evaluate("window.__xr.controllers.right.updateButtonValue('trigger', 0)")
    ar.wait(f"Math.abs(window.daylit.debug.xrState().alignment.position[2] - {hit[2]}) < 1e-3")
    return ar, hit


def visit_from(visit_page, hit, eye):
    """Draw the visit from the AR eye's pose relative to the site placed at hit: (H, W, 4)."""
    site_from_eye = np.linalg.inv(xremu.pose_m(hit, np.eye(3))) @ eye
    visit_page.evaluate("([m, fov]) => window.daylit.debug.setCameraMatrix(m, fov)",
                        [xremu.column_major(site_from_eye), float(np.degrees(xremu.FOVY_RAD))])
    return screen(visit_page)


def hall_pixels(ar_image: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels the AR frame covers opaquely (the virtual hall; not the shadows,
    drawn with alpha, not the reticle), two pixels in from every edge (antialiasing)."""
    opaque = (ar_image[..., 3] == 255).astype(np.uint8)
    return cv2.erode(opaque, np.ones((5, 5), np.uint8)).astype(bool)


@pytest.fixture(scope="module")
def sky(reference):
    return reference.light_vector(SKY)


def test_ar_places_the_hall_on_the_floor_and_holds_it(new_page, web_build, sky, reference):
    with StubServer(web_build) as server:
        server.push(light_message(sky, 1), remember=True)
        ar, hit = open_ar(new_page, server, sky)
        state = ar.page.evaluate("window.daylit.debug.xrState()")
        site = xremu.from_column_major(state["site"])
        np.testing.assert_allclose(site[:3, 3], hit, atol=1e-3)
        np.testing.assert_allclose(site[:3, :3], np.eye(3), atol=1e-6)
        stored = ar.page.evaluate("JSON.parse(localStorage.getItem('daylit.alignment.xr'))")
        np.testing.assert_allclose(stored["position"], hit, atol=1e-3)

        # New light during the session (the stream's next vector): both pages relit with it.
        sky2 = reference.light_vector(SKY2)
        relight(ar.page, sky2, sequence=2)
        visit = new_page(*SIZE).open(server.url + URL, READY)
        relight(visit.page, sky2)
        world_site = np.c_[SITE_POINTS_M + hit, np.ones(len(SITE_POINTS_M))]
        seen = []
        projection = xremu.perspective(xremu.FOVY_RAD, SIZE[0] / SIZE[1], 0.1, 2000)
        SCREENSHOTS.mkdir(parents=True, exist_ok=True)
        for spec in POSES:
            pose = set_pose(ar.page, spec)
            state = ar.page.evaluate("window.daylit.debug.xrState()")
            eye = xremu.left_eye_m(pose)
            drawn_eye = xremu.from_column_major(state["eye"]["matrixWorld"])
            drawn_projection = xremu.from_column_major(state["eye"]["projection"])
            np.testing.assert_allclose(drawn_eye, eye, atol=1e-4)
            site = xremu.from_column_major(state["site"])
            np.testing.assert_allclose(site[:3, 3], hit, atol=1e-3)
            # The site's points where the test's camera puts them, and where the page does.
            expected = xremu.project_px(world_site[:, :3], eye, projection, SIZE)
            drawn = xremu.project_px(world_site[:, :3], drawn_eye, drawn_projection, SIZE)
            np.testing.assert_allclose(drawn, expected, atol=0.5)
            seen.append(expected)

            # The same pose relative to the site, in the visit: the same hall, the same light.
            ar_image = screen(ar.page, render=False)
            visit_image = visit_from(visit.page, hit, eye)
            hall = hall_pixels(ar_image)
            assert hall.mean() > 0.05, hall.mean()  # a precondition: the hall is in view
            diff = np.abs(ar_image[..., :3].astype(int) - visit_image[..., :3].astype(int))[hall]
            # Measured: mean 0.01 codes, 99th percentile 0 (the same shaders, the same pixels);
            # a site 10 cm off or a pose a degree off moves the hall's edges by pixels.
            assert diff.mean() < 1.0 and np.percentile(diff, 99) <= 4, (
                spec, diff.mean(), np.percentile(diff, 99))
            if len(seen) == 1:
                cv2.imwrite(str(SCREENSHOTS / "ar-emulated.png"),
                            cv2.cvtColor(ar_image, cv2.COLOR_RGBA2BGRA))
        moved_px = np.ptp(np.array(seen), axis=0).max()
        assert moved_px > 30, moved_px  # a precondition: the poses move the hall on the screen
        assert not ar.errors and not visit.errors, ar.errors + visit.errors


def test_ar_sun_matches_the_visit(new_page, web_build, sky):
    """With the sun, the AR frame equals the visit's from the same site-relative pose: the
    sun's maps are in the site's frame and the materials' uniforms follow the placed site
    (before that fix, with the site tapped 23 m out: mean 4.0 codes, 99th percentile 64)."""
    sun = sun_of(SKY)
    with StubServer(web_build) as server:
        server.push(light_message(sky, 1), remember=True)
        ar, hit = open_ar(new_page, server, sky, sun)
        visit = new_page(*SIZE).open(server.url + URL, READY)
        relight(visit.page, sky, sun)
        pose = set_pose(ar.page, POSES[0])
        ar_image = screen(ar.page, render=False)
        visit_image = visit_from(visit.page, hit, xremu.left_eye_m(pose))
        hall = hall_pixels(ar_image)
        diff = np.abs(ar_image[..., :3].astype(int) - visit_image[..., :3].astype(int))[hall]
        assert diff.mean() < 1.0 and np.percentile(diff, 99) <= 12, (
            diff.mean(), np.percentile(diff, 99))
