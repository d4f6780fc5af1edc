"""The fisheye model agrees with OpenCV's and maps the sky the documented way round."""

import cv2
import numpy as np
import pytest

from daylit.sky import direction_from_azimuth_elevation
from server.fisheye import CalibrationError, FisheyeCamera, yaw_rotation

K = np.array([[310.0, 0.0, 330.5], [0.0, 305.0, 236.0], [0.0, 0.0, 1.0]])
D = np.array([0.04, -0.012, 0.003, -0.0004])


def random_rays(count, max_theta_deg, seed=0):
    rng = np.random.default_rng(seed)
    theta = np.radians(rng.uniform(0.0, max_theta_deg, count))
    phi = rng.uniform(0.0, 2 * np.pi, count)
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], 1)


def test_projection_matches_opencv_fisheye():
    cam = FisheyeCamera(640, 480, K, D)
    rays = random_rays(500, 85.0)
    ours = cam.project_camera(rays)
    theirs, _ = cv2.fisheye.projectPoints(
        rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, D
    )
    assert np.abs(ours - theirs.reshape(-1, 2)).max() < 1e-6


def test_unprojection_matches_opencv_and_inverts_projection():
    cam = FisheyeCamera(640, 480, K, D)
    rays = random_rays(500, 85.0, seed=1)
    px = cam.project_camera(rays)
    back = cam.unproject_camera(px)
    assert np.abs(back - rays).max() < 1e-9
    norm = cv2.fisheye.undistortPoints(px.reshape(-1, 1, 2), K, D).reshape(-1, 2)
    ours = back[:, :2] / back[:, 2:]
    assert np.abs(norm - ours).max() < 1e-5
    # Beyond 90 degrees (a 190-degree lens) our form keeps working.
    wide = random_rays(200, 95.0, seed=2)
    assert np.abs(cam.unproject_camera(cam.project_camera(wide)) - wide).max() < 1e-9


def test_default_orientation_puts_north_up_and_east_left():
    cam = FisheyeCamera.equidistant(400, 400)
    names = {"zenith": (0, 90), "north": (0, 30), "east": (90, 30), "south": (180, 30)}
    px = {k: cam.project(direction_from_azimuth_elevation(*v)[None])[0][0] for k, v in
          names.items()}
    centre = np.array([199.5, 199.5])
    assert np.allclose(px["zenith"], centre)
    assert px["north"][1] < centre[1] and abs(px["north"][0] - centre[0]) < 1e-9
    assert px["east"][0] < centre[0]  # seen from below, east is on the left
    assert px["south"][1] > centre[1]
    # Equidistant: 60 degrees from the zenith lands at 2/3 of the radius.
    assert np.isclose(np.linalg.norm(px["north"] - centre), 200.0 * 60 / 90)


def test_yaw_rotation_turns_azimuths_clockwise():
    d = direction_from_azimuth_elevation(30.0, 20.0)
    assert np.allclose(yaw_rotation(45.0) @ d, direction_from_azimuth_elevation(75.0, 20.0))


def test_scaled_camera_sees_the_same_directions():
    cam = FisheyeCamera(640, 480, K, D)
    half = cam.scaled_to(320, 240)
    d = random_rays(50, 80.0) @ cam.site_from_camera.T
    p_full, _ = cam.project(d)
    p_half, _ = half.project(d)
    assert np.allclose((p_full + 0.5) / 2 - 0.5, p_half)


def test_calibration_json_round_trip_and_errors():
    cam = FisheyeCamera(640, 480, K, D, yaw_rotation(12.0) @ FisheyeCamera.equidistant(
        2, 2).site_from_camera)
    again = FisheyeCamera.from_json(cam.to_json())
    assert np.allclose(again.K, cam.K) and np.allclose(again.site_from_camera,
                                                       cam.site_from_camera)
    with pytest.raises(CalibrationError, match="format"):
        FisheyeCamera.from_json({"K": K.tolist()})
    bad = cam.to_json() | {"site_from_camera": np.diag([1.0, 1.0, -1.0]).tolist()}
    with pytest.raises(CalibrationError, match="rotation"):
        FisheyeCamera.from_json(bad)
