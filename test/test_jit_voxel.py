"""The compiled back-projection / ROI / voxel grid (optional numba) against the numpy path."""

import math

import numpy as np
import pytest

from obstacle_detection.labels import LABEL_GROUND
from obstacle_detection.pipeline import geometry, voxel
from obstacle_detection.pipeline._compiled import voxel as jit_voxel
from obstacle_detection.pipeline.depth import crop_borders, decode_depth
from obstacle_detection.pipeline.median import median_filter
from obstacle_detection.pipeline.params import (KINECT_V2_SD, DetectorParams, Intrinsics,
                                                table_4_2, table_4_3)
from obstacle_detection.pipeline.detector import Detector
from obstacle_detection.sim.scenes import render_scene, scene_params

pytestmark = pytest.mark.numba


def project(depth_m, rays, params, reuse=False):
    """Return the compiled projection of a frame, with the stage's float32 ROI bounds."""
    return jit_voxel.project_roi(depth_m, (rays.ru, rays.rv, rays.rot), voxel.roi_bounds(params),
                                 params.voxel_size_m, reuse=reuse)


def assert_same_frame(depth_m, rays, params, both_paths):
    """Check the stage's two paths (points, pixels, voxels, labels) bit for bit.

    And the compiled projection, with and without its reused buffers, against the numpy path.
    """
    ref = voxel.points_in_roi.reference(depth_m, rays, params)
    pts, pix, valid = ref.points, ref.pixel_index, ref.labels.reshape(-1) != 0
    for reuse in (False, True):
        proj = project(depth_m, rays, params, reuse=reuse)
        np.testing.assert_array_equal(proj.points, pts)
        assert proj.points.dtype == np.float32
        np.testing.assert_array_equal(proj.pixel_index, pix)
        flat = proj.labels.reshape(-1)
        np.testing.assert_array_equal(flat != 0, valid)
        np.testing.assert_array_equal(np.flatnonzero(flat == LABEL_GROUND), pix)

    def stage():
        roi = voxel.points_in_roi(depth_m, rays, params)
        grid = voxel.voxel_grid(roi)
        is_obstacle = np.arange(grid.counts.size) % 3 == 0
        return roi.points, roi.pixel_index, grid, *voxel.pixel_labels(roi, grid, is_obstacle)

    both_paths(stage)
    return pts.shape[0]


def test_voxel_numbers_across_the_bitmap_words():
    """Cells at either end of a 64-cell word of the occupied bitmap, a full word, lone cells.

    Points on a line along z (the fastest axis: linear key = cell index), several per cell in
    shuffled order, keyed as the projection keys them: the voxels, their order and their means
    equal numpy's voxel grid.
    """
    size = (0.1, 0.1, 0.01)
    cells = np.array([0, 1, 62, 63, 64, 65, 127, 128, 191, 255, 256, 1000, 1023, 1024]
                     + list(range(300, 364)))          # 300..363: a whole word and a bit more
    rng = np.random.default_rng(9)
    z = (np.repeat(cells, 3) + rng.uniform(0.1, 0.9, 3 * cells.size)) * 0.01
    pts = np.stack([np.full(z.size, 0.05), np.full(z.size, 0.05), z], 1).astype(np.float32)
    pts = pts[rng.permutation(pts.shape[0])]
    ijk = np.floor(pts / np.asarray(size, np.float32)).astype(np.int64)
    low = ijk.min(axis=0)
    dims = ijk.max(axis=0) - low + 1
    keys = ((ijk[:, 0] - low[0]) * dims[1] + ijk[:, 1] - low[1]) * dims[2] + ijk[:, 2] - low[2]
    n = pts.shape[0]
    cols = np.ascontiguousarray(pts.T)
    proj = jit_voxel.Projection(cols.T, np.arange(n), keys, np.zeros(n, np.uint8),
                                np.full(n, -1, np.int32), low, dims, False, cols)
    got = jit_voxel.voxelise(proj)
    want = voxel.voxel_downsample(pts, size)
    for name, value in zip(('centroids', 'point_voxel', 'counts'), got):
        np.testing.assert_array_equal(value, getattr(want, name), err_msg=name)
    np.testing.assert_array_equal(proj.pixel_voxel, want.point_voxel)
    assert want.counts.size == np.unique(cells).size
    assert (want.counts == 3).all()


@pytest.mark.parametrize('preset', [table_4_2, table_4_3])
@pytest.mark.parametrize('name', ['corridor', 'people', 'ramps', 'farm_row', 'step_down',
                                  'pitched_floor'])
def test_scene_frames_match_numpy(name, preset, both_paths):
    frame = render_scene(name, seed=1)
    params = scene_params(frame, preset())
    depth = decode_depth(frame.depth_mm)
    if params.median_kernel > 1:
        depth = median_filter(depth, 5)
    rays = geometry.ray_model(depth.shape, frame.intrinsics, params)
    kept = assert_same_frame(depth, rays, params, both_paths)
    assert kept > 1000 or preset is table_4_3   # 4.3's 1 m range may see nothing


@pytest.mark.parametrize('pitch_deg, roll_deg, crop', [(0.0, 0.0, (0, 0, 0, 0)),
                                                       (25.0, 4.0, (20, 30, 10, 40)),
                                                       (-5.0, -8.0, (0, 100, 60, 0))])
def test_mount_and_crop_match_numpy(pitch_deg, roll_deg, crop, both_paths):
    frame = render_scene('corridor', pitch_rad=math.radians(pitch_deg),
                         roll_rad=math.radians(roll_deg))
    params = scene_params(frame, table_4_2(crop_top_px=crop[0], crop_bottom_px=crop[1],
                                           crop_left_px=crop[2], crop_right_px=crop[3]))
    depth = crop_borders(decode_depth(frame.depth_mm), *crop)
    rays = geometry.ray_model(depth.shape, frame.intrinsics, params)
    assert_same_frame(depth, rays, params, both_paths)


def test_empty_and_all_outside_frames(both_paths):
    params = DetectorParams(camera_height_m=0.5, max_range_m=2.0)
    intr = Intrinsics(fx=50.0, fy=50.0, cx=8.0, cy=6.0)
    rays = geometry.ray_model((12, 16), intr, params)
    for depth in (np.zeros((12, 16), np.float32), np.full((12, 16), 9.0, np.float32)):
        assert assert_same_frame(depth, rays, params, both_paths) == 0
        roi = voxel.points_in_roi(depth, rays, params)
        assert voxel.voxel_grid(roi).centroids.shape == (0, 3)
        assert (roi.pixel_voxel == -1).all()


def test_roi_and_voxel_boundaries_and_negative_coordinates(both_paths):
    """Depths chosen so that points land exactly on the ROI bounds and voxel faces."""
    params = DetectorParams(camera_height_m=0.5, max_range_m=2.0, min_range_m=0.5,
                            lateral_limit_m=1.0, tdbg_m=-0.1, smar_m=0.8)
    h, w = 40, 60
    rng = np.random.default_rng(9)
    # Arbitrary rays (any mount, ahead of the camera), then depths that hit chosen ground
    # coordinates.
    rot = rng.uniform(-0.2, 0.2, (3, 3))
    rot[:, 2] = (1.0, 0.0, -0.3)
    rot[1, 0] = 0.6                                  # left and right of the camera
    rays = geometry.GroundRays(rng.uniform(-1.0, 1.0, w), rng.uniform(-1.0, 1.0, h), rot)
    targets = np.concatenate([
        np.float32([0.5, 2.0, 0.525, 1.0, 1.975, 0.75]),
        rng.choice(np.arange(18, 82, dtype=np.float32) * np.float32(0.025), h * w - 6)])
    depth = (targets / rays.table()[0]).astype(np.float32)
    # nudge by an ulp either way so that some products hit the bound exactly, some not
    depth = np.where(rng.random(h * w) < 0.3, np.nextafter(depth, np.float32(0)), depth)
    depth[::17] = 0.0
    depth = depth.reshape(h, w)
    m = assert_same_frame(depth, rays, params, both_paths)
    pts = voxel.points_in_roi.reference(depth, rays, params).points
    assert m > 100 and (pts[:, 1] < 0).any() and (pts[:, 2] < 0).any()
    on_bound = (pts[:, 0] == np.float32(0.5)) | (pts[:, 0] == np.float32(2.0))
    assert on_bound.any()
    on_face = pts[:, 0] / np.float32(0.025) == np.floor(pts[:, 0] / np.float32(0.025))
    assert on_face.sum() > 10


def test_roi_lattice_holds_the_bounds():
    params = DetectorParams()
    bounds = voxel.roi_bounds(params)
    size = np.asarray(params.voxel_size_m, np.float32)
    low, dims = jit_voxel.roi_lattice(bounds, size)
    assert (dims > 0).all()
    assert low[1] == math.floor(-params.lateral_limit_m / 0.025)


def _outputs(params, frame):
    """Return the outputs of one frame that do not depend on the clock."""
    result = Detector(params).process(frame.depth_mm, frame.intrinsics)
    return (result.obstacle_points, result.ground_points, result.labels, result.voxel_points,
            result.voxel_normals, result.voxel_is_obstacle, result.voxel_slope_obstacle,
            result.pixel_voxel, result.voxel_neighbours, result.costmap)


@pytest.mark.parametrize('name', ['corridor', 'people', 'farm_row'])
def test_pipeline_identical_with_and_without_jit(name, both_paths):
    # half the Kinect's pixels on the same geometry: as many voxels, a quarter of the median
    half = Intrinsics(KINECT_V2_SD.fx / 2, KINECT_V2_SD.fy / 2, KINECT_V2_SD.cx / 2,
                      KINECT_V2_SD.cy / 2)
    frame = render_scene(name, seed=2, intrinsics=half, size=(256, 212))
    obstacles = both_paths(_outputs, scene_params(frame, table_4_2()), frame)[0]
    assert obstacles.shape[0] > 100
