"""Depth from the foot line (Kakuta Eq. 13 and the calibrated perspective camera), and the
in-front / behind decision against a virtual depth image."""

from __future__ import annotations

import math

import numpy as np
import pytest

from server.occlusion.depth import (
    EquidistantPanorama,
    PerspectiveCamera,
    find_people,
    occlusion_mask,
)
from server.occlusion.synthetic import SyntheticSite, Walker, box_depth_image, make_camera

# The demo build's kiosk camera (bake scenes/demo, draft): 320x180, 3.2 m up, turned and
# tilted slightly upward.
DEMO_K = [[234.458015822, 0.0, 160.0], [0.0, 234.458015822, 90.0], [0.0, 0.0, 1.0]]
DEMO_POSE = [
    [0.955779009, -0.009724409, -0.293925028, 16.0],
    [0.0, -0.999453152, 0.033066566, 3.2],
    [-0.294085849, -0.031604329, -0.955256342, 52.0],
    [0.0, 0.0, 0.0, 1.0],
]


@pytest.mark.parametrize("camera", [
    PerspectiveCamera(DEMO_K, DEMO_POSE, 320, 180),
    make_camera(1024, 512, hfov_deg=70.0, height_m=2.0, pitch_deg=-15.0, yaw_deg=30.0),
])
def test_the_foot_pixel_ray_meets_the_ground_at_the_true_depth(camera):
    rng = np.random.default_rng(1)
    forward = camera.R[:, 2]
    heading = np.array([forward[0], 0.0, forward[2]]) / math.hypot(forward[0], forward[2])
    side = np.array([heading[2], 0.0, -heading[0]])
    for _ in range(50):
        ground = camera.origin_m * [1, 0, 1] + heading * rng.uniform(4, 60) + side * rng.uniform(
            -3, 3)
        uv, z = camera.project(ground[None])
        if not (0 <= uv[0, 0] < camera.width and 0 <= uv[0, 1] < camera.height):
            continue
        assert camera.foot_depth_m(*uv[0]) == pytest.approx(z[0], rel=1e-9)
        point, _ = camera.ground_hit(*uv[0])
        assert np.allclose(point[0], ground, atol=1e-7)


def test_rays_above_the_horizon_have_no_ground():
    camera = make_camera(640, 480, pitch_deg=0.0)
    assert math.isnan(camera.foot_depth_m(320.0, 100.0))  # above the horizon row (240)
    assert camera.foot_depth_m(320.0, 400.0) > 0


def test_eq13_for_an_equidistant_panorama():
    pano = EquidistantPanorama(1024, 512, camera_height_m=1.5)  # the paper's Ladybug2 setup
    # 45 degrees below the horizon (row 384 of 512): as far away as the camera is high.
    assert pano.foot_depth_m(0.0, 384.0) == pytest.approx(1.5)
    for distance in (0.5, 2.0, 7.5, 30.0):
        row = pano.foot_row(distance)
        assert 256.0 < row < 512.0
        assert pano.foot_depth_m(0.0, row) == pytest.approx(distance, rel=1e-12)
    assert math.isnan(pano.foot_depth_m(0.0, 200.0))  # above the horizon


def test_foot_line_ignores_a_stray_pixel_below_the_feet():
    mask = np.zeros((60, 40), bool)
    mask[10:50, 15:25] = True
    mask[55, 20] = True  # noise below, joined through nothing: a separate speck
    mask[50, 18] = True  # a single pixel glued under the feet
    labels, people = find_people(mask, min_px=20, foot_min_px=2)
    assert len(people) == 1  # the speck is too small to be a person
    p = people[0]
    assert p.foot_px == (pytest.approx(20.0), 50.0)  # bottom edge of row 49, mean column + 0.5
    assert p.bbox_px == (15, 10, 25, 51)
    assert labels[55, 20] == 0 and labels[30, 20] == p.label


def walker_pair_site(near_xz, far_xz):
    camera = make_camera(640, 360)
    walkers = [Walker(near_xz, (0.0, 0.0), 1.75), Walker(far_xz, (0.0, 0.0), 1.7,
                                                        shirt=(0.2, 0.5, 0.2))]
    return SyntheticSite(camera, walkers, duration_s=1.0, noise_codes=0.0)


def test_overlapping_people_form_one_region_at_the_nearest_ones_depth():
    """The paper's rule, and a limitation (docs/occlusion.md): a far person whose silhouette
    joins a near one's takes the near one's foot line."""
    site = walker_pair_site((0.0, -6.0), (0.3, -16.0))
    truth = site.frame(0)
    _, people = find_people(truth.person, min_px=30)
    near = min(truth.people, key=lambda t: t.depth_m)
    assert len(truth.people) == 2 and len(people) == 1
    assert site.camera.foot_depth_m(*people[0].foot_px) == pytest.approx(near.depth_m, rel=0.03)


def test_people_are_in_front_exactly_where_they_are_nearer_than_the_virtual_surface():
    camera = make_camera(480, 270)
    virtual = box_depth_image(camera, (-2.0, 0.0, -14.0), (2.0, 4.0, -10.0))
    labels = np.zeros((270, 480), np.int32)
    labels[100:200, 200:260] = 1  # a person, across the box's silhouette edge
    labels[100:200, 300:320] = 2  # another, off the box
    _, people = find_people(labels > 0, min_px=10)
    by_label = {p.label: p for p in people}
    overlap = np.isfinite(virtual) & (labels == 1)
    assert overlap.any() and (np.isinf(virtual) & (labels == 1)).any()
    for depth_m, expect_over in ((8.0, True), (12.5, None), (20.0, False)):
        by_label[1].depth_m = depth_m
        by_label[2].depth_m = depth_m
        mask = occlusion_mask(labels, people, virtual) > 0
        ideal = (labels > 0) & (depth_m < virtual)
        assert np.array_equal(mask, ideal)
        if expect_over is not None:
            assert mask[overlap].all() == expect_over
        # Where no virtual object is seen, people are always in the mask.
        assert mask[(labels > 0) & np.isinf(virtual)].all()
        assert by_label[1].in_front_px == np.count_nonzero(ideal & (labels == 1))
    # Unknown depth: shown in front rather than hidden.
    by_label[1].depth_m = float("nan")
    assert (occlusion_mask(labels, people, virtual)[labels == 1] == 255).all()
    # No virtual depth at all: every person is in the mask.
    assert np.array_equal(occlusion_mask(labels, people, None) > 0, labels > 0)


def _silhouette(camera, corners_m: np.ndarray) -> np.ndarray:
    """(H, W) bool: the convex hull of 3-D points (N, 3) projected by ``camera``."""
    import cv2

    uv, z = camera.project(corners_m)
    assert np.all(z > 0)
    mask = np.zeros((camera.height, camera.width), np.uint8)
    cv2.fillConvexPoly(mask, np.round(cv2.convexHull(uv.astype(np.float32))).astype(np.int32)
                       .reshape(-1, 2), 1)
    return mask > 0


def _box(centre_m, size_m) -> np.ndarray:
    """The 8 corners (8, 3) of an axis-aligned box standing on the ground at ``centre_m``
    (x, z), ``size_m`` (width x, height y, depth z), metres."""
    (x, z), (w, h, d) = centre_m, size_m
    return np.array([[x + sx * w / 2, sy * h, z + sz * d / 2]
                     for sx in (-1, 1) for sy in (0, 1) for sz in (-1, 1)], dtype=np.float64)


@pytest.mark.parametrize("distance_m", [8.0, 14.0, 22.0])
def test_flat_pieces_on_the_ground_are_dropped_and_standing_ones_kept(distance_m):
    """Regions drawn by projecting 3-D boxes through the camera (not by the rule's formula):
    a piece of shadow lying on the ground across the view (1.5 m wide, 15 cm along the line
    of sight, 2 cm thick) is dropped; a walker (1.7 m) and a shoe cut off from its walker
    (12 cm) are kept, and so is the strip where the rule is off or the region may go on
    below the frame's bottom edge.

    What a silhouette cannot tell: a strip ``L`` long along the line of sight at ``D`` looks
    like a post about ``camera height x L / D`` tall (1.5 m at 8 m from 3 m up: 17 cm), and
    is kept.
    """
    from server.occlusion.depth import drop_flat_regions, standing_height_m

    camera = make_camera(1024, 512, hfov_deg=60.0, height_m=3.0, pitch_deg=-12.0)
    forward = camera.R[:, 2]
    heading = np.array([forward[0], 0.0, forward[2]]) / math.hypot(forward[0], forward[2])
    side = np.array([heading[2], 0.0, -heading[0]])

    def at(along_m: float, across_m: float) -> tuple[float, float]:
        p = camera.origin_m * [1, 0, 1] + heading * along_m + side * across_m
        return float(p[0]), float(p[2])

    shapes = {
        "walker": _box(at(distance_m, -2.0), (0.5, 1.7, 0.3)),
        "shoe": _box(at(distance_m, 0.0), (0.1, 0.12, 0.28)),
        "strip": _box(at(distance_m, 2.0), (1.5, 0.02, 0.15)),
    }
    mask = np.zeros((camera.height, camera.width), bool)
    for corners in shapes.values():
        mask |= _silhouette(camera, corners)
    labels, people = find_people(mask, min_px=1)
    assert len(people) == 3
    for p in people:
        p.depth_m = camera.foot_depth_m(*p.foot_px)
    heights = sorted(standing_height_m(p, camera) for p in people)
    # The rule's height is the bounding box's at the foot's depth: about the true height
    # (plus the box's own depth and a pixel or two), the strip's a few centimetres.
    assert heights[0] < 0.09 and 0.1 < heights[1] < 0.25 and 1.5 < heights[2] < 1.9, heights
    kept = drop_flat_regions(labels, people, camera, 0.1)
    assert len(kept) == 2
    assert not np.any(labels[_silhouette(camera, shapes["strip"])])
    assert np.all(labels[_silhouette(camera, shapes["walker"])] > 0)
    assert np.all(labels[_silhouette(camera, shapes["shoe"])] > 0)
    # Off, or a region that may go on below the frame's bottom edge: kept.
    labels, people = find_people(mask, min_px=1)
    for p in people:
        p.depth_m = camera.foot_depth_m(*p.foot_px)
    assert len(drop_flat_regions(labels, people, camera, 0.0)) == 3
    for p in people:
        p.at_bottom_edge = True
    assert len(drop_flat_regions(labels, people, camera, 0.1)) == 3
