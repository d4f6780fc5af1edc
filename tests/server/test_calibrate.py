"""Calibration on synthetic images with known answers: fisheye intrinsics and north."""

import datetime as dt
import json
import math

import cv2
import numpy as np
import pytest

from daylit.sky import azimuth_elevation_from_direction
from server.calibrate import calibrate_intrinsics, find_sun, north_from_sun, run_intrinsics
from server.fisheye import ZENITH_NORTH_UP, FisheyeCamera, yaw_rotation
from server.simsky import SimulatedSky

BOARD = (9, 6)
SQUARE_M = 0.03
TRUE_K = np.array([[152.0, 0.0, 322.4], [0.0, 151.2, 241.7], [0.0, 0.0, 1.0]])
TRUE_D = np.array([0.035, -0.012, 0.003, -0.0005])


def look_at(direction: np.ndarray, tilt_deg: float, spin_deg: float) -> np.ndarray:
    """Board rotation (columns: board x, y, normal) facing the camera along ``direction``."""
    z = direction / np.linalg.norm(direction)
    helper = np.array([0.0, 1.0, 0.0]) if abs(z[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z], axis=1)
    tilt, spin = math.radians(tilt_deg), math.radians(spin_deg)
    Rx = np.array([[1, 0, 0], [0, math.cos(tilt), -math.sin(tilt)],
                   [0, math.sin(tilt), math.cos(tilt)]])
    Rz = np.array([[math.cos(spin), -math.sin(spin), 0], [math.sin(spin), math.cos(spin), 0],
                   [0, 0, 1]])
    return R @ Rz @ Rx


def sub_pixel_rays(cam: FisheyeCamera, samples: int = 3) -> list[np.ndarray]:
    """Camera rays through ``samples^2`` sub-pixel positions of every pixel."""
    px = cam.pixel_grid()
    offsets = (np.arange(samples) + 0.5) / samples - 0.5
    return [cam.unproject_camera(px + [ox, oy]) for ox in offsets for oy in offsets]


def render_board(cam: FisheyeCamera, rays_list, R: np.ndarray, t: np.ndarray):
    """8-bit image of the checkerboard at pose (R, t) seen through ``cam`` (supersampled)."""
    n = R[:, 2]
    acc = np.zeros(cam.width * cam.height)
    cols, rows = BOARD
    for rays in rays_list:
        with np.errstate(invalid="ignore", divide="ignore"):
            lam = (t @ n) / (rays @ n)
        p = (lam[:, None] * rays - t) @ R
        x, y = p[:, 0] / SQUARE_M, p[:, 1] / SQUARE_M
        on_board = (x >= -1) & (x < cols) & (y >= -1) & (y < rows)
        margin = (x >= -2) & (x < cols + 1) & (y >= -2) & (y < rows + 1)
        dark = (np.floor(x) + np.floor(y)) % 2 == 0
        value = np.where(on_board, np.where(dark, 0.08, 0.92), np.where(margin, 0.92, 0.45))
        value = np.where(np.isfinite(lam) & (lam > 0), value, 0.0)
        acc += value
    gray = np.round(255 * acc / len(rays_list)).astype(np.uint8).reshape(cam.height, cam.width)
    return cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR)


def board_images(cam):
    """Views of the board all over the field, up to 60 degrees off the axis."""
    poses = [(0, 0, 0, 0), (25, 0, 20, 10), (25, 90, -20, 40), (25, 180, 15, -30),
             (25, 270, -15, 70), (45, 45, 25, 5), (45, 135, -25, 100), (45, 225, 20, -60),
             (45, 315, -20, 30), (58, 0, 30, 15), (58, 120, -30, -20), (58, 240, 25, 50)]
    cols, rows = BOARD
    centre_on_board = np.array([(cols - 1) / 2, (rows - 1) / 2, 0.0]) * SQUARE_M
    images = []
    rays = sub_pixel_rays(cam)
    for theta, phi, tilt, spin in poses:
        th, ph = math.radians(theta), math.radians(phi)
        d = np.array([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)])
        R = look_at(d, tilt, spin)
        t = 0.27 * d - R @ centre_on_board
        images.append(render_board(cam, rays, R, t))
    return images


@pytest.fixture(scope="module")
def true_camera():
    return FisheyeCamera(640, 480, TRUE_K, TRUE_D)


@pytest.fixture(scope="module")
def checkerboards(true_camera):
    return board_images(true_camera)


def test_intrinsics_from_checkerboards_reproject_within_half_a_pixel(true_camera,
                                                                    checkerboards):
    cam, report = calibrate_intrinsics(checkerboards, BOARD, SQUARE_M)
    assert len(report["images_used"]) >= 10
    assert report["rms_px"] < 0.5
    # The recovered model against the true one, over the field the boards covered.
    rng = np.random.default_rng(3)
    theta = np.radians(rng.uniform(0, 65, 2000))
    phi = rng.uniform(0, 2 * np.pi, 2000)
    rays = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi),
                     np.cos(theta)], 1)
    error = np.linalg.norm(cam.project_camera(rays) - true_camera.project_camera(rays), axis=1)
    assert error.max() < 0.5, error.max()


def test_too_few_boards_is_a_clear_error(true_camera):
    from server.calibrate import CalibrateError

    blank = np.full((480, 640, 3), 128, np.uint8)
    with pytest.raises(CalibrateError, match="found in 0 image"):
        calibrate_intrinsics([blank] * 3, BOARD, SQUARE_M)


def test_calibrate_intrinsics_command_writes_the_file(tmp_path, checkerboards, capsys):
    paths = []
    for k, image in enumerate(checkerboards[:6]):
        path = tmp_path / f"board{k:02d}.png"
        cv2.imwrite(str(path), image)
        paths.append(str(path))
    out = tmp_path / "sky-camera.json"

    class Args:
        images = paths
        board = "9x6"
        square_mm = 30.0
        output = str(out)

    assert run_intrinsics(Args) == 0
    data = json.loads(out.read_text())
    assert data["format"] == "daylit-fisheye-calibration" and data["intrinsics"]["rms_px"] < 0.5
    assert "RMS reprojection error" in capsys.readouterr().out
    assert not list(tmp_path.glob(".*tmp*"))  # written via a temporary name, then renamed


@pytest.mark.parametrize("yaw_deg", [23.4, -141.0])
def test_north_from_a_rendered_sun_within_half_a_degree(yaw_deg):
    site = (34.4686, 135.8194, 100.0)
    true_rotation = yaw_rotation(yaw_deg) @ ZENITH_NORTH_UP
    lens = FisheyeCamera(640, 640, [[200.0, 0, 321.3], [0, 200.0, 318.2], [0, 0, 1]],
                         [0.02, -0.004, 0.0, 0.0], true_rotation)
    sim = SimulatedSky.for_site(*site, "Asia/Tokyo", camera=lens, cloud_cover=0.0,
                                start="2026-03-20T14:10")
    frame = sim.render_at(sim.clock.start_s)
    when = dt.datetime.fromtimestamp(sim.clock.start_s, dt.UTC)
    unrotated = lens.with_rotation(ZENITH_NORTH_UP)  # intrinsics known, north not yet
    image = cv2.cvtColor(frame.image, cv2.COLOR_RGB2BGR)
    found, report = north_from_sun([(image, when)], unrotated, *site)
    applied = (report["yaw_applied_deg"] - yaw_deg + 180) % 360 - 180
    assert abs(applied) < 0.5
    # The sun's direction through the recovered camera is where the ephemeris says.
    u, v = find_sun(image)
    d, _ = found.unproject(np.array([[u, v]]))
    az, el = azimuth_elevation_from_direction(d)
    obs = report["observations"][0]
    assert abs((az[0] - obs["true_azimuth_deg"] + 180) % 360 - 180) < 0.5
    assert report["elevation_error_deg"] < 0.5


def test_calibrate_north_command_updates_a_calibration(tmp_path, build_dir, capsys):
    from daylit.cli import main

    lens = FisheyeCamera.equidistant(480, 480, site_from_camera=yaw_rotation(-37.0)
                                     @ ZENITH_NORTH_UP)
    sim = SimulatedSky.for_site(34.4686, 135.8194, 100.0, "Asia/Tokyo", camera=lens,
                                cloud_cover=0.0, start="2026-06-21T09:00")
    frame = sim.render_at(sim.clock.start_s)
    sky = tmp_path / "sky.png"
    cv2.imwrite(str(sky), cv2.cvtColor(frame.image, cv2.COLOR_RGB2BGR))
    calibration = tmp_path / "sky-camera.json"
    calibration.write_text(json.dumps(FisheyeCamera.equidistant(480, 480).to_json()))
    code = main(["calibrate", "north", str(sky), "--time", "2026-06-21T09:00",
                 "--build", str(build_dir), "--calibration", str(calibration)])
    assert code == 0, capsys.readouterr().err
    data = json.loads(calibration.read_text())
    assert abs(data["north"]["yaw_applied_deg"] + 37.0) < 0.5
    assert np.allclose(data["site_from_camera"], lens.site_from_camera, atol=0.01)
    assert "turned the camera by" in capsys.readouterr().out
    assert main(["calibrate", "north", str(sky), "--time", "not a time", "--build",
                 str(build_dir), "-o", str(tmp_path / "x.json")]) == 1
    assert "not an ISO date-time" in capsys.readouterr().err
