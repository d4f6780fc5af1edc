"""``daylit calibrate``: the sky camera's intrinsics and its rotation to north.

``daylit calibrate intrinsics IMAGE... --board 9x6 --square-mm 25 -o sky-camera.json``
    Finds the checkerboard in each image (``cv2.findChessboardCornersSB``, which is sub-pixel
    accurate and robust to fisheye distortion), runs ``cv2.fisheye.calibrate`` and saves K, D
    and the reprojection error (RMS and per image, in pixels).

``daylit calibrate north SKY_IMAGE --time 2026-06-21T10:15:00 --build build/site``
    Finds the sun in one sky image (the centroid of the largest clipped blob), compares its
    azimuth through the current lens model with the sun's true azimuth at the site and time
    (NREL SPA via pvlib) and turns the camera's rotation about the vertical by the difference.
    The camera is assumed level (use a bubble level); the difference between the measured and
    true elevation is reported as a check of levelling and intrinsics. Several images (taken at
    different times, ``--time`` once per image) are averaged.

Files are written to a temporary name and renamed, never half-written.
"""

from __future__ import annotations

import argparse
import datetime as dt
import math
import sys
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

import cv2
import numpy as np

from daylit.sky import azimuth_elevation_from_direction, sun_position
from server.fisheye import (
    CalibrationError,
    FisheyeCamera,
    load_calibration,
    save_json_atomic,
    yaw_rotation,
)


class CalibrateError(ValueError):
    """Calibration that cannot be done from the given images; the message says why."""


# ----------------------------------------------------------------------------- intrinsics


def board_points(board: tuple[int, int], square_m: float) -> np.ndarray:
    """(1, cols * rows, 3) float64 corner positions on the board plane (z = 0), metres."""
    cols, rows = board
    grid = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * square_m
    return np.concatenate([grid, np.zeros((grid.shape[0], 1))], axis=1)[None].astype(np.float64)


def find_corners(image: np.ndarray, board: tuple[int, int]) -> np.ndarray | None:
    """Sub-pixel inner corners ``(1, cols * rows, 2)`` float64, or None if not found."""
    gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    found, corners = cv2.findChessboardCornersSB(
        gray, board, flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
    )
    if not found:
        found, corners = cv2.findChessboardCorners(
            gray, board, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
        )
        if not found:
            return None
        criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
        corners = cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1), criteria)
    return corners.reshape(1, -1, 2).astype(np.float64)


def calibrate_intrinsics(
    images: list[np.ndarray],
    board: tuple[int, int],
    square_m: float,
    names: list[str] | None = None,
) -> tuple[FisheyeCamera, dict]:
    """Fisheye intrinsics from checkerboard images.

    Returns the camera (north-up default rotation) and a report: RMS reprojection error and
    per-image errors in pixels, and which images were used.
    """
    if not images:
        raise CalibrateError("no images given")
    names = names or [f"image {i}" for i in range(len(images))]
    h, w = images[0].shape[:2]
    obj = board_points(board, square_m)
    object_points, image_points, used, rejected = [], [], [], []
    for name, image in zip(names, images, strict=True):
        if image.shape[:2] != (h, w):
            raise CalibrateError(f"{name}: size {image.shape[1]}x{image.shape[0]} differs from "
                                 f"the first image's {w}x{h}")
        corners = find_corners(image, board)
        if corners is None:
            rejected.append(name)
            continue
        object_points.append(obj)
        image_points.append(corners)
        used.append(name)
    if len(used) < 3:
        raise CalibrateError(
            f"the {board[0]}x{board[1]} board was found in {len(used)} image(s); at least 3 "
            "are needed (check --board: it counts inner corners)")
    flags = cv2.CALIB_RECOMPUTE_EXTRINSIC | cv2.CALIB_FIX_SKEW | cv2.CALIB_USE_INTRINSIC_GUESS
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-10)

    def fit(objs, imgs):
        """OpenCV's fit from a few starting focal lengths (it is known to stall from a poor
        start); the one with the smallest reprojection error wins."""
        best, failure = None, None
        for f0 in (max(w, h) / math.pi, min(w, h) / math.pi, 0.7 * min(w, h) / math.pi):
            K0 = np.array([[f0, 0, (w - 1) / 2], [0, f0, (h - 1) / 2], [0, 0, 1.0]])
            try:
                result = cv2.fisheye.calibrate(objs, imgs, (w, h), K0, np.zeros(4),
                                               flags=flags, criteria=criteria)
            except cv2.error as exc:
                failure = exc
                continue
            if best is None or result[0] < best[0]:
                best = result
        if best is None:
            raise failure
        return best

    try:
        rms, K, D, rvecs, tvecs = fit(object_points, image_points)
    except cv2.error:
        # OpenCV's initial pose estimate fails on some views; drop those and try again.
        keep = []
        for k in range(len(used)):
            try:
                fit(object_points[k:k + 1], image_points[k:k + 1])
                keep.append(k)
            except cv2.error:
                rejected.append(used[k])
        used = [used[k] for k in keep]
        object_points = [object_points[k] for k in keep]
        image_points = [image_points[k] for k in keep]
        if len(used) < 3:
            raise CalibrateError("OpenCV's fisheye calibration failed on all but "
                                 f"{len(used)} image(s); take more, varied views") from None
        try:
            rms, K, D, rvecs, tvecs = fit(object_points, image_points)
        except cv2.error as exc:
            raise CalibrateError(f"OpenCV fisheye calibration failed: {exc.err}") from None
    per_image = {}
    for name, objp, imgp, rvec, tvec in zip(used, object_points, image_points, rvecs, tvecs,
                                            strict=True):
        proj, _ = cv2.fisheye.projectPoints(objp, rvec, tvec, K, D)
        per_image[name] = float(np.sqrt(np.mean(np.sum((proj - imgp) ** 2, axis=-1))))
    camera = FisheyeCamera(w, h, K, D.reshape(4))
    report = {
        "rms_px": float(rms),
        "per_image_rms_px": per_image,
        "images_used": used,
        "images_rejected": rejected,
        "board": {"inner_corners": list(board), "square_m": square_m},
    }
    return camera, report


# ---------------------------------------------------------------------------------- north


def find_sun(image: np.ndarray, level: float = 0.98) -> tuple[float, float]:
    """Pixel ``(u, v)`` of the sun: intensity-weighted centroid of the largest clipped blob."""
    gray = image.max(axis=2) if image.ndim == 3 else image
    gray = gray.astype(np.float32)
    full = 255.0 if image.dtype == np.uint8 else (65535.0 if image.dtype == np.uint16 else 1.0)
    mask = (gray >= level * full).astype(np.uint8)
    if not mask.any():
        mask = (gray >= 0.98 * gray.max()).astype(np.uint8)  # not clipped: take the brightest
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if count < 2:
        raise CalibrateError("no sun found in the image")
    biggest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    ys, xs = np.nonzero(labels == biggest)
    weight = gray[ys, xs]
    return float(np.average(xs, weights=weight)), float(np.average(ys, weights=weight))


def north_from_sun(
    observations: list[tuple[np.ndarray, dt.datetime]],
    camera: FisheyeCamera,
    latitude_deg: float,
    longitude_deg: float,
    elevation_m: float,
) -> tuple[FisheyeCamera, dict]:
    """Turn ``camera`` about the vertical so that the sun in each image lands at its azimuth.

    Returns the re-oriented camera and a report (yaw applied, per-image measured and true sun
    positions, elevation differences).
    """
    rows = []
    for image, when in observations:
        if image.shape[:2] != (camera.height, camera.width):
            raise CalibrateError(
                f"sky image is {image.shape[1]}x{image.shape[0]}, the lens model is for "
                f"{camera.width}x{camera.height}")
        u, v = find_sun(image)
        d, ok = camera.unproject(np.array([[u, v]]))
        if not ok[0]:
            raise CalibrateError("the bright spot found is outside the lens's field of view")
        az_m, el_m = azimuth_elevation_from_direction(d)
        az_t, el_t = sun_position(latitude_deg, longitude_deg, elevation_m, when)
        if el_t <= 0:
            raise CalibrateError(f"the sun is below the horizon at {when.isoformat()}")
        yaw = (az_t - float(az_m[0]) + 180.0) % 360.0 - 180.0
        rows.append({"time": when.isoformat(), "sun_pixel": [u, v],
                     "measured_azimuth_deg": float(az_m[0]),
                     "measured_elevation_deg": float(el_m[0]),
                     "true_azimuth_deg": az_t, "true_elevation_deg": el_t, "yaw_deg": yaw})
    yaws = np.radians([r["yaw_deg"] for r in rows])
    yaw_deg = math.degrees(math.atan2(np.sin(yaws).mean(), np.cos(yaws).mean()))
    spread = max(abs((r["yaw_deg"] - yaw_deg + 180) % 360 - 180) for r in rows)
    rotated = camera.with_rotation(yaw_rotation(yaw_deg) @ camera.site_from_camera)
    report = {
        "yaw_applied_deg": yaw_deg,
        "yaw_spread_deg": spread,
        "elevation_error_deg": max(abs(r["measured_elevation_deg"] - r["true_elevation_deg"])
                                   for r in rows),
        "observations": rows,
    }
    return rotated, report


# ------------------------------------------------------------------------------------ CLI


def add_calibrate_parser(subparsers) -> None:
    cal = subparsers.add_parser(
        "calibrate",
        help="calibrate the sky camera: fisheye intrinsics, rotation to north",
        description="Calibrate the fisheye sky camera (see docs/server.md, Calibration).",
    )
    sub = cal.add_subparsers(dest="calibrate_command", metavar="STEP")
    intr = sub.add_parser(
        "intrinsics",
        help="fisheye intrinsics from checkerboard images",
        description="Fit OpenCV's fisheye model to checkerboard images taken with the sky "
                    "camera (10-30 images, the board filling different parts of the image, "
                    "including near the edge of the image circle).",
    )
    intr.add_argument("images", nargs="+", metavar="IMAGE")
    intr.add_argument("--board", default="9x6",
                      help="inner corners per row x per column (default 9x6)")
    intr.add_argument("--square-mm", type=float, default=25.0,
                      help="side of one square in millimetres (default 25)")
    intr.add_argument("-o", "--output", required=True, help="calibration JSON to write")
    intr.set_defaults(run=run_intrinsics)
    north = sub.add_parser(
        "north",
        help="rotation to north from sky images with the sun visible",
        description="Turn the camera model about the vertical so that the sun's measured "
                    "azimuth matches its true azimuth. Give one --time per image, in the same "
                    "order; a time without an offset is local time at the site.",
    )
    north.add_argument("images", nargs="+", metavar="SKY_IMAGE")
    north.add_argument("--time", action="append", required=True, metavar="ISO",
                       help="when the image was taken, e.g. 2026-06-21T10:15:00+09:00")
    north.add_argument("--build", help="build directory: site position and time zone")
    north.add_argument("--lat", type=float, help="latitude, degrees (without --build)")
    north.add_argument("--lon", type=float, help="longitude, degrees east (without --build)")
    north.add_argument("--elevation-m", type=float, default=0.0)
    north.add_argument("--timezone", help="IANA time zone for times without an offset")
    north.add_argument("--calibration", help="intrinsics JSON (default: ideal equidistant lens)")
    north.add_argument("--fov-deg", type=float, default=180.0,
                       help="field of view of the ideal lens without --calibration")
    north.add_argument("-o", "--output",
                       help="JSON to write (default: update --calibration in place)")
    north.set_defaults(run=run_north)
    cal.set_defaults(run=lambda args: (cal.print_help(), 2)[1])


def _read_image(path: str) -> np.ndarray:
    image = cv2.imread(path, cv2.IMREAD_COLOR)
    if image is None:
        raise CalibrateError(f"{path}: not an image OpenCV can read")
    return image


def run_intrinsics(args: argparse.Namespace) -> int:
    try:
        cols, _, rows = args.board.lower().partition("x")
        board = (int(cols), int(rows))
        if min(board) < 2:
            raise ValueError
    except ValueError:
        print(f"daylit calibrate: error: --board {args.board!r} must look like 9x6",
              file=sys.stderr)
        return 2
    try:
        images = [_read_image(p) for p in args.images]
        camera, report = calibrate_intrinsics(images, board, args.square_mm / 1000.0,
                                              list(args.images))
    except CalibrateError as exc:
        print(f"daylit calibrate: error: {exc}", file=sys.stderr)
        return 1
    data = camera.to_json() | {"intrinsics": report}
    save_json_atomic(args.output, data)
    print(f"intrinsics from {len(report['images_used'])} images "
          f"({len(report['images_rejected'])} without a board): RMS reprojection error "
          f"{report['rms_px']:.3f} px")
    worst = max(report["per_image_rms_px"].items(), key=lambda kv: kv[1])
    print(f"worst image: {worst[0]} ({worst[1]:.3f} px); fx={camera.K[0, 0]:.2f} "
          f"fy={camera.K[1, 1]:.2f} cx={camera.K[0, 2]:.2f} cy={camera.K[1, 2]:.2f} "
          f"D={np.round(camera.D, 5).tolist()}")
    print(f"wrote {args.output}; next: daylit calibrate north SKY_IMAGE --time ... "
          f"--calibration {args.output}")
    return 0


def run_north(args: argparse.Namespace) -> int:
    try:
        if args.build:
            from daylit.manifest import ManifestError, load

            try:
                scene = load(args.build)["scene"]
            except ManifestError as exc:
                raise CalibrateError(str(exc)) from None
            lat, lon, elev = scene["latitude_deg"], scene["longitude_deg"], scene["elevation_m"]
            tz_name = args.timezone or scene["timezone"]
        elif args.lat is not None and args.lon is not None:
            lat, lon, elev, tz_name = args.lat, args.lon, args.elevation_m, args.timezone
        else:
            raise CalibrateError("give --build, or --lat and --lon")
        if len(args.time) != len(args.images):
            raise CalibrateError(f"{len(args.images)} image(s) but {len(args.time)} --time")
        times = [_parse_time(t, tz_name) for t in args.time]
        images = [_read_image(p) for p in args.images]
        data: dict = {}
        if args.calibration:
            camera, data = load_calibration(args.calibration)
        else:
            h, w = images[0].shape[:2]
            camera = FisheyeCamera.equidistant(w, h, args.fov_deg)
        camera, report = north_from_sun(list(zip(images, times, strict=True)), camera, lat,
                                        lon, elev)
    except (CalibrateError, CalibrationError) as exc:
        print(f"daylit calibrate: error: {exc}", file=sys.stderr)
        return 1
    output = args.output or args.calibration
    if not output:
        print("daylit calibrate: error: give -o FILE (or --calibration to update)",
              file=sys.stderr)
        return 2
    save_json_atomic(output, data | camera.to_json() | {"north": report})
    print(f"turned the camera by {report['yaw_applied_deg']:+.2f} deg about the vertical "
          f"(spread over images {report['yaw_spread_deg']:.2f} deg); sun elevation differs by "
          f"{report['elevation_error_deg']:.2f} deg (large: camera not level, or intrinsics)")
    print(f"wrote {output}; use it with [sky] calibration = \"{output}\"")
    return 0


def _parse_time(text: str, tz_name: str | None) -> dt.datetime:
    try:
        when = dt.datetime.fromisoformat(text)
    except ValueError:
        raise CalibrateError(f"--time {text!r} is not an ISO date-time") from None
    if when.tzinfo is None:
        if not tz_name:
            raise CalibrateError(f"--time {text!r} has no offset; give --timezone or --build")
        try:
            when = when.replace(tzinfo=ZoneInfo(tz_name))
        except (ZoneInfoNotFoundError, ValueError):
            raise CalibrateError(f"unknown time zone {tz_name!r}") from None
    return when
