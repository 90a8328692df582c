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
