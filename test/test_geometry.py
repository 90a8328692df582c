"""Back-projection, mount transform and region of interest against known geometry."""

import math

import numpy as np
import pytest

from eval_helpers import to_ground
from obstacle_detection.pipeline import geometry
from obstacle_detection.pipeline.params import DetectorParams, Intrinsics

INTR = Intrinsics(fx=500.0, fy=400.0, cx=3.0, cy=2.0)


def test_back_project_follows_seed_equations():
    depth = np.zeros((5, 7), np.float32)
    depth[4, 6] = 2.0      # i = 4, j = 6
    depth[2, 3] = 1.5      # the principal point
    pts, pix = geometry.back_project(depth, INTR)
    np.testing.assert_array_equal(pix, [2 * 7 + 3, 4 * 7 + 6])
    np.testing.assert_allclose(pts[0], [0.0, 0.0, 1.5])
    np.testing.assert_allclose(pts[1], [(6 - 3) * 2.0 / 500.0, (4 - 2) * 2.0 / 400.0, 2.0],
                               rtol=1e-6)


def test_back_project_skips_no_return():
    depth = np.zeros((3, 3), np.float32)
    pts, pix = geometry.back_project(depth, INTR)
    assert pts.shape == (0, 3) and pix.size == 0


def test_level_mount_maps_optical_axes_to_ground_axes():
    p = DetectorParams(camera_height_m=0.5)
    optical = np.array([[0, 0, 2.0], [1.0, 0, 0], [0, 1.0, 0]], np.float32)
    ground = to_ground(optical, p)
    np.testing.assert_allclose(ground, [[2.0, 0, 0.5], [0, -1.0, 0.5], [0, 0, -0.5]], atol=1e-6)


def test_positive_pitch_looks_down():
    pitch = math.radians(30)
    rot, t = geometry.mount_transform(1.0, pitch, 0.0)
    axis = rot @ np.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(axis, [math.cos(pitch), 0.0, -math.sin(pitch)], atol=1e-12)
    # the optical axis meets the ground at depth h / sin(pitch)
    hit = rot @ np.array([0.0, 0.0, 1.0 / math.sin(pitch)]) + t
    assert hit[2] == pytest.approx(0.0, abs=1e-12)


def test_positive_roll_lowers_the_image_right_side():
    rot = geometry.mount_rotation(0.0, math.radians(10))
    right = rot @ np.array([1.0, 0.0, 0.0])
    assert right[2] < 0.0 and right[1] < 0.0
    np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-12)


def test_roi_boundaries_inclusive():
    p = DetectorParams(camera_height_m=0.6, max_range_m=2.0, min_range_m=0.5,
                       lateral_limit_m=1.0, tdbg_m=-0.1, smar_m=0.8)
    eps = 1e-4
    pts = np.array([
        [2.0 - eps, 0.0, 0.0], [2.0 + eps, 0.0, 0.0],    # forward range
        [0.5 + eps, 0.0, 0.0], [0.5 - eps, 0.0, 0.0],    # minimum range
        [1.0, 1.0 - eps, 0.0], [1.0, -1.0 - eps, 0.0],   # lateral
        [1.0, 0.0, -0.1 + eps], [1.0, 0.0, -0.1 - eps],  # TDBG below the ground
        [1.0, 0.0, 1.4 - eps], [1.0, 0.0, 1.4 + eps],    # camera height + SMAR
    ], np.float32)
    np.testing.assert_array_equal(geometry.roi_mask(pts, p),
                                  [True, False, True, False, True, False, True, False, True,
                                   False])


# -- FramePose: the one transform of a frame's outputs ---------------------------------------
NOMINAL = DetectorParams(camera_height_m=0.6, camera_x_m=0.2, camera_y_m=0.1,
                         camera_yaw_rad=math.radians(10.0))
#: the floor fit's pose of a body pitched 2 deg down, rolled 0.5 deg, 3 cm higher
USED = NOMINAL.with_frame_mount(camera_height_m=0.63, camera_pitch_rad=math.radians(2.0),
                                camera_roll_rad=math.radians(0.5))
#: base-frame points: the floor 2 m ahead, a box top 1.5 m ahead, 25 cm high
BASE_POINTS = np.array([[2.0, 0.3, 0.0], [1.5, -0.2, 0.25]])


def _seen_by(params: DetectorParams, base_points: np.ndarray) -> np.ndarray:
    """Return the optical-frame points a camera mounted as ``params`` sees at base points."""
    pose = geometry.FramePose(params)
    return (base_points - pose.translation()) @ pose.rotation()   # R^T (P - t), row-wise


def test_the_pose_places_the_optical_axes_as_the_mount_says():
    pose = geometry.FramePose(DetectorParams(camera_height_m=0.5, camera_x_m=0.3,
                                             camera_yaw_rad=math.radians(90.0)))
    # the optical z axis (forward) 1 m out: 1 m to the left of a camera turned 90 deg left
    np.testing.assert_allclose(pose.optical_to_base(np.array([[0.0, 0.0, 1.0]])),
                               [[0.3, 1.0, 0.5]], atol=1e-12)


def test_the_ground_frame_outputs_are_the_used_pose():
    pose = geometry.FramePose(NOMINAL, USED)
    optical = _seen_by(USED, BASE_POINTS)
    rot, t = geometry.mount_transform(USED.camera_height_m, USED.camera_pitch_rad,
                                      USED.camera_roll_rad)
    ground = optical @ rot.T + t        # what the pipeline's rays give (the ground frame)

    np.testing.assert_allclose(pose.ground_to_base(ground), BASE_POINTS, atol=1e-12)
    np.testing.assert_allclose(pose.optical_to_base(optical), BASE_POINTS, atol=1e-12)


def test_clearing_points_placed_by_the_nominal_mount_land_where_the_marks_are():
    """A camera pitched 2 deg against its level nominal mount.

    The floor point and the box top reach the same base-frame place through the clearing cloud
    as through the marks.
    """
    pose = geometry.FramePose(NOMINAL, USED)
    optical = _seen_by(USED, BASE_POINTS).astype(np.float32)

    moved = pose.to_nominal_optical(optical)

    assert moved.dtype == np.float32
    np.testing.assert_allclose(pose.optical_to_base(moved, nominal=True), BASE_POINTS,
                               atol=1e-5)
    # not re-expressed, the nominal mount misplaces them: up by about range x sin(2 deg)
    # (6.4 and 4.8 cm), down by the 3 cm of height
    off = pose.optical_to_base(optical, nominal=True) - BASE_POINTS
    np.testing.assert_allclose(off[:, 2], [0.034, 0.018], atol=0.003)


def test_an_uncorrected_pose_leaves_the_clearing_points_as_they_are():
    pose = geometry.FramePose(NOMINAL, NOMINAL.with_frame_mount(tdbg_m=-0.2))   # ROI only
    points = np.ones((4, 3), np.float32)

    assert not pose.corrected
    assert pose.to_nominal_optical(points) is points
