"""Ground rays kept as their factors (geometry.GroundRays) against the (3, H*W) table.

The compiled kernels compute the rays on the fly from the factors; every consumer must give,
to the bit, what it gives with the materialised table (and the table must hold the rays that
the mount and the pinhole model say).
"""

import math

import numpy as np
import pytest

from obstacle_detection.pipeline import floor, geometry, voxel
from obstacle_detection.pipeline.params import KINECT_V2_SD, Intrinsics, corridor

SHAPE = (424, 512)
MOUNT = dict(camera_height_m=0.62, camera_pitch_rad=0.21, camera_roll_rad=-0.04)


def test_model_table_and_pixels_agree_with_the_geometry():
    params = corridor(**MOUNT)
    model = geometry.ray_model(SHAPE, KINECT_V2_SD, params)
    table = model.table()
    assert table.shape == (3, SHAPE[0] * SHAPE[1]) and table.dtype == np.float32
    np.testing.assert_array_equal(table, geometry.ground_rays(SHAPE, KINECT_V2_SD, params))
    pixels = np.array([0, 511, 512, 100 * 512 + 37, SHAPE[0] * SHAPE[1] - 1])
    np.testing.assert_array_equal(model.at(pixels), table[:, pixels])
    other = corridor(camera_height_m=0.4, camera_pitch_rad=-0.1, camera_roll_rad=0.07)
    np.testing.assert_array_equal(model.for_mount(other).table(),
                                  geometry.ground_rays(SHAPE, KINECT_V2_SD, other))
    # the principal point looks along the optical axis: pitched down by the mount's pitch
    intr = Intrinsics(fx=400.0, fy=400.0, cx=10.0, cy=5.0)
    ray = geometry.ray_model((11, 21), intr, corridor(camera_height_m=0.5,
                                                      camera_pitch_rad=0.3)).at([5 * 21 + 10])
    np.testing.assert_allclose(ray[:, 0], [math.cos(0.3), 0.0, -math.sin(0.3)], atol=1e-6)


def test_sample_rays_from_the_model_equal_those_from_the_table():
    model = geometry.ray_model(SHAPE, KINECT_V2_SD, corridor(**MOUNT))
    step = floor.sample_step(SHAPE)
    table = model.table().reshape(3, *SHAPE)[:, ::step, ::step].reshape(3, -1)
    np.testing.assert_array_equal(floor.sample_rays(model, SHAPE), table)


def _frame():
    """Return a random depth image [m] with holes."""
    rng = np.random.default_rng(3)
    depth = rng.uniform(0.6, 4.0, SHAPE).astype(np.float32)
    depth[rng.random(SHAPE) < 0.1] = 0.0
    return depth


@pytest.mark.numba
@pytest.mark.parametrize('shape', [SHAPE, (7, 9000), (1, 3)])
def test_projection_from_the_model_equals_the_table(shape, both_paths):
    # the rays are computed a band of rows at a time: a partial last band, rows wider than
    # a band, a tiny image
    params = corridor(**MOUNT)
    intr = Intrinsics(fx=365.0, fy=365.0, cx=shape[1] / 2.0, cy=shape[0] / 2.0)
    model = geometry.ray_model(shape, intr, params)
    depth = _frame()[:shape[0], :shape[1]] if shape == SHAPE else np.full(shape, 2.0,
                                                                           np.float32)
    # the numpy path reads the table, the compiled one computes the rays from the factors
    def stage():
        roi = voxel.points_in_roi(depth, model, params)
        return roi.points, roi.pixel_index, roi.labels, roi.pixel_voxel

    assert both_paths(stage)[0].shape[0] > (1000 if shape == SHAPE else 0)
