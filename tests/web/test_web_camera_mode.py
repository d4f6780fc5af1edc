"""The camera mode (the fallback without WebXR, iOS's) in headless Chromium: Chromium's fake
camera plays a Y4M file this test writes (two known colours, left and right), the page gets
dispatched ``deviceorientation`` events, and: the camera's picture is the background, and as
the "phone" turns the hall stays fixed to the site, i.e. a site point's screen position is
the one a pinhole camera turned by the W3C device-orientation angles puts it at (computed
here from the W3C definition, not from the page), and the drawn hall moves on the screen by
the homography of the inverse turn (issue 17)."""

from __future__ import annotations

import base64

import cv2
import numpy as np
import pytest

from tests.web.fakecamera import READY, camera_page, orient, write_y4m
from tests.web.harness import SCREENSHOTS
from tests.web.touch import touch_drag
from tests.web.xremu import perspective, project_px

pytestmark = [pytest.mark.browser]

SKY = "clear:135,40"
SIZE = (640, 360)
FOVY_DEG = 60.0  # the camera mode's field of view (camera-view.js)
LEFT_RGB = (200, 80, 40)
RIGHT_RGB = (40, 90, 200)
# The view follows the sensors and fingers alone: the test's picture (two colours) is not of the
# site, so the picture's registration of the pose (tested against Radiance frames in
# test_web_phone_estimate.py, and below on this picture) has nothing to find.
UNREGISTERED = "&exposure=0.1&register=off"
# The registration classes the picture by the client's own sun (its clock: lightfeed.sunNow),
# not the served sky's: pinned near SKY's sun (azimuth 135, elevation 40 at the demo site), so
# that a test does not depend on the hour it runs (at 13:47 JST in December no pool pixel was
# in the model's sun, and every registration came back empty).
SUN_TIME = "&time=2026-10-15T00:40:00Z"
SITE_POINTS_M = np.array([[0.0, 0.0, 0.0], [0.0, 4.0, 0.0], [6.0, 2.0, -4.0], [-8.0, 5.0, 2.0]])


def write_pattern(path):
    """The fake camera's picture: LEFT_RGB beside RIGHT_RGB."""
    w, h = SIZE
    rgb = np.zeros((h, w, 3), np.uint8)
    rgb[:, : w // 2] = LEFT_RGB
    rgb[:, w // 2:] = RIGHT_RGB
    write_y4m(path, rgb)


def device_rotation(alpha_deg, beta_deg, gamma_deg) -> np.ndarray:
    """(3, 3) world-from-device in three.js's frame (x east, y up, z south): the W3C
    orientation R = Rz(alpha) Rx(beta) Ry(gamma) in the earth frame (x east, y north, z up)."""
    a, b, g = np.radians([alpha_deg, beta_deg, gamma_deg])
    rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    ry = np.array([[np.cos(g), 0, np.sin(g)], [0, 1, 0], [-np.sin(g), 0, np.cos(g)]])
    earth_to_three = np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]])
    return earth_to_three @ rz @ rx @ ry


def screen(page) -> np.ndarray:
    s = page.evaluate("window.daylit.debug.screen()")
    return np.frombuffer(base64.b64decode(s["data"]), np.uint8).reshape(s["height"], s["width"], 4)


def not_camera(image: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels far from both camera colours (the hall and its shadows)."""
    rgb = image[..., :3].astype(int)
    far = [np.abs(rgb - np.array(c)).max(axis=-1) > 40 for c in (LEFT_RGB, RIGHT_RGB)]
    return far[0] & far[1]


def test_camera_mode_shows_the_camera_and_holds_the_hall(browser, web_build, reference,
                                                         tmp_path):
    y4m = tmp_path / "pattern.y4m"
    write_pattern(y4m)
    sky = reference.light_vector(SKY)
    with camera_page(browser, web_build, y4m, sky, UNREGISTERED, SIZE) as (
            page, server, errors):
        page.evaluate("(r) => window.daylit.debug.relight(r, 1)", sky.ravel().tolist())
        assert page.evaluate("screen.orientation.angle") == 0  # the expectation assumes it
        view = server.manifest["views"][0]["world_from_camera"]
        standpoint = np.array([view[0][3], 1.6, view[2][3]])
        # Facing the site's origin (alpha turns to the left, from north, -z).
        alpha0 = float(np.degrees(np.arctan2(standpoint[0], standpoint[2])))
        projection = perspective(np.radians(FOVY_DEG), SIZE[0] / SIZE[1], 0.1, 2000)
        images, rotations = [], []
        for alpha, beta, gamma in [(0, 90, 0), (12, 90, 0), (-10, 90, 0), (5, 80, 6)]:
            orient(page, alpha0 + alpha, beta, gamma)
            rot = device_rotation(alpha0 + alpha, beta, gamma)
            pose = np.eye(4)
            pose[:3, :3] = rot
            pose[:3, 3] = standpoint
            expected = project_px(SITE_POINTS_M, pose, projection, SIZE)
            # screen() draws one frame through the shipped renderFrame, which turns the
            # view by the orientation read: the pose no longer waits on the page's own
            # frame loop (CI once read the pose before a loaded machine had drawn a frame).
            images.append(screen(page))
            drawn = np.array(page.evaluate("(p) => window.daylit.debug.project(p)",
                                           SITE_POINTS_M.tolist()))
            np.testing.assert_allclose(drawn, expected, atol=0.5)
            rotations.append(rot)
        # The event of nulls a device without sensors sends, arriving late: the view holds.
        page.evaluate("""() => dispatchEvent(new DeviceOrientationEvent('deviceorientation',
          { alpha: null, beta: null, gamma: null, absolute: false }))""")
        screen(page)
        held = np.array(page.evaluate("(p) => window.daylit.debug.project(p)",
                                      SITE_POINTS_M.tolist()))
        np.testing.assert_allclose(held, drawn, atol=0.5)
        SCREENSHOTS.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(SCREENSHOTS / "camera-mode.png"),
                    cv2.cvtColor(images[0], cv2.COLOR_RGBA2BGRA))

        # The camera's picture is the background: the top corners (nothing of the site
        # there) show the Y4M's two colours.
        picks = page.evaluate("(p) => window.daylit.debug.pick(p)", [[20, 12], [620, 12]])
        assert picks == [None, None], picks
        for image in images[:3]:
            np.testing.assert_allclose(image[12, 20, :3], LEFT_RGB, atol=8)
            np.testing.assert_allclose(image[12, 620, :3], RIGHT_RGB, atol=8)

        # The drawn hall moves as the inverse of the turn: first image warped by the
        # homography K R2^T R1 K^-1 (camera axes) lands on the others.
        f = SIZE[1] / 2 / np.tan(np.radians(FOVY_DEG) / 2)
        k = np.array([[f, 0, SIZE[0] / 2], [0, f, SIZE[1] / 2], [0, 0, 1]])
        flip = np.diag([1, -1, -1])  # three.js camera axes to image axes (y down, z ahead)
        hall0 = not_camera(images[0])
        assert 0.05 < hall0.mean() < 0.8, hall0.mean()  # a precondition: the hall in view
        for image, rot in zip(images[1:], rotations[1:], strict=True):
            rel = flip @ rot.T @ rotations[0] @ flip
            h = k @ rel @ np.linalg.inv(k)
            warped = cv2.warpPerspective(hall0.astype(np.uint8), h, SIZE,
                                         flags=cv2.INTER_NEAREST).astype(bool)
            inside = cv2.warpPerspective(np.ones(SIZE[::-1], np.uint8), h, SIZE,
                                         flags=cv2.INTER_NEAREST).astype(bool)
            hall = not_camera(image)
            union = (warped | hall) & inside
            iou = (warped & hall & inside).sum() / union.sum()
            assert iou > 0.9, iou
        assert not errors, errors


def turned_pose(alpha_deg, heading_deg, standpoint):
    """(4, 4) world-from-camera of the camera mode: the device turned by the W3C angles
    (alpha_deg, beta 90: held upright, gamma 0), then the model's heading offset about +y."""
    h = np.radians(heading_deg)
    turn = np.array([[np.cos(h), 0, np.sin(h)], [0, 1, 0], [-np.sin(h), 0, np.cos(h)]])
    pose = np.eye(4)
    pose[:3, :3] = turn @ device_rotation(alpha_deg, 90, 0)
    pose[:3, 3] = standpoint
    return pose


def drawn_px(page, points):
    screen(page)  # one frame through the shipped renderFrame: the view takes the pose
    return np.array(page.evaluate("(p) => window.daylit.debug.project(p)", points.tolist()))


def test_touch_turns_and_walks_the_model_and_the_alignment_is_kept(browser, web_build,
                                                                   reference, tmp_path):
    """docs/web.md: one finger turns the model about the vertical (0.15 degrees per px) until
    it sits on the real site, two fingers walk the standpoint in the view's ground plane (half
    a metre per 50 px of the fingers' motion, up = forward), facing any way; the alignment is
    kept for the next visit (localStorage). Real touch events (CDP)."""
    y4m = tmp_path / "pattern.y4m"
    write_pattern(y4m)
    sky = reference.light_vector(SKY)
    with camera_page(browser, web_build, y4m, sky, UNREGISTERED, SIZE,
                     has_touch=True) as (page, server, errors):
        view = server.manifest["views"][0]["world_from_camera"]
        standpoint = np.array([view[0][3], 1.6, view[2][3]])
        alpha0 = float(np.degrees(np.arctan2(standpoint[0], standpoint[2])))
        projection = perspective(np.radians(FOVY_DEG), SIZE[0] / SIZE[1], 0.1, 2000)
        orient(page, alpha0, 90, 0)
        dx_px = 80
        touch_drag(page, [(200, 250)], dx_px, 0)
        heading_deg = 0.15 * dx_px
        pose = turned_pose(alpha0, heading_deg, standpoint)
        expected = project_px(SITE_POINTS_M, pose, projection, SIZE)
        np.testing.assert_allclose(drawn_px(page, SITE_POINTS_M), expected, atol=0.5)
        # The next visit starts aligned: the page again, same orientation, same picture.
        page.reload()
        page.wait_for_function(READY, timeout=60000)
        orient(page, alpha0, 90, 0)
        np.testing.assert_allclose(drawn_px(page, SITE_POINTS_M), expected, atol=0.5)

        # Two fingers pushed up 100 px: 1 m forward, facing the site and facing away from it
        # (south-west here: a heading taken from the camera's Euler angle walked backwards).
        for alpha in (alpha0, alpha0 + 180):
            orient(page, alpha, 90, 0)
            pose = turned_pose(alpha, heading_deg, standpoint)
            # points 6-12 m ahead of the camera, in its view before the walk
            ahead = (pose @ np.array([[0, 0, -8, 1], [2, 1, -6, 1], [-3, -1, -12, 1]]).T).T[:, :3]
            touch_drag(page, [(260, 250), (380, 250)], 0, -100)
            forward = -pose[:3, 2] * np.array([1, 0, 1])
            standpoint = standpoint + forward / np.linalg.norm(forward)
            walked = turned_pose(alpha, heading_deg, standpoint)
            np.testing.assert_allclose(drawn_px(page, ahead),
                                       project_px(ahead, walked, projection, SIZE), atol=0.5)
        assert not errors, errors


def test_a_far_shift_found_twice_without_a_gain_leaves_the_view(browser, web_build, reference,
                                                                tmp_path):
    """The registration on (the default), the two-colour picture, the phone held level facing
    north (the pose the view draws before any orientation event; the phone neither estimates
    nor registers until one comes): its registrations find the same far shift (22 px) with a
    gain under 2 % every time. Found twice, only a shift of a pixel is followed without the gain
    (a settled view's last pixel); on main the far one was, and walked the view 10 degrees."""
    y4m = tmp_path / "pattern.y4m"
    write_pattern(y4m)
    sky = reference.light_vector(SKY)
    with camera_page(browser, web_build, y4m, sky, "&exposure=0.1" + SUN_TIME, SIZE) as (
            page, server, errors):
        page.evaluate("window.daylit.debug.holdPhoneEstimates(true)")
        page.evaluate("window.daylit.debug.resetAlignment()")
        orient(page, 0.0, 90.0, 0.0)  # the identity: level, facing north
        before = drawn_px(page, SITE_POINTS_M)
        shifts = [page.evaluate("window.daylit.debug.phoneRegister()") for _ in range(3)]
        gains = [s["fisher"] / s["fisherAtZero"] - 1 for s in shifts]
        print("registrations", [s["shiftPx"] for s in shifts], np.round(gains, 4))
        # Preconditions: the same shift each time, far, with less than the 2 % gain.
        assert all(s["shiftPx"] == shifts[0]["shiftPx"] for s in shifts), shifts
        assert max(np.abs(shifts[0]["shiftPx"])) > 1 and max(gains) < 0.02, shifts
        np.testing.assert_allclose(drawn_px(page, SITE_POINTS_M), before, atol=0.5)
        assert not errors, errors
