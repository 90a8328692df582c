"""The clearing cloud (pipeline.clearing) and its message, on depth images whose answer is known.

A 9 x 7 image with the principal point on pixel (4, 3) and fx = fy = 2 px: pixel (u, v) at depth
z lies at ((u - 4) z / 2, (v - 3) z / 2, z) in the optical frame.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from builtin_interfaces.msg import Time

from obstacle_detection.pipeline import clearing
from obstacle_detection.pipeline.clearing import BORDER_FRACTIONS, clearing_points
from obstacle_detection.pipeline.params import Intrinsics
from message_helpers import pointcloud2_to_points
from obstacle_detection.ros.conversions import result_to_messages

INTRINSICS = Intrinsics(fx=2.0, fy=2.0, cx=4.0, cy=3.0)
REPO = Path(__file__).resolve().parents[1]


def _grid_points(points: np.ndarray, count: int) -> np.ndarray:
    """Return the points of the kept pixels (the border points follow them)."""
    return points[:count]


def test_every_stride_pixel_and_the_last_row_and_column_are_back_projected() -> None:
    depth = np.full((7, 9), 2.0, np.float32)

    points = clearing_points(depth, INTRINSICS, stride_px=4, range_m=100.0)

    # rows 0, 4, 6 and columns 0, 4, 8: 9 pixels
    grid = _grid_points(points, 9)
    expected = [((u - 4) * 1.0, (v - 3) * 1.0, 2.0) for v in (0, 4, 6) for u in (0, 4, 8)]
    np.testing.assert_allclose(grid, expected, atol=1e-6)
    assert points.dtype == np.float32


def test_no_return_pixels_give_no_point() -> None:
    depth = np.zeros((7, 9), np.float32)
    depth[4, 4] = 1.0
    depth[0, 0] = np.nan
    depth[0, 8] = np.inf

    points = clearing_points(depth, INTRINSICS, stride_px=4, range_m=100.0)

    # the one valid pixel is also the outermost valid pixel of its row, on both sides
    assert points.shape == (1 + 2 * len(BORDER_FRACTIONS), 3)
    np.testing.assert_allclose(points[0], [0.0, 0.5, 1.0], atol=1e-6)


def test_a_surface_beyond_the_range_gives_the_point_at_the_range_on_its_ray() -> None:
    depth = np.zeros((7, 9), np.float32)
    depth[4, 8] = 3.0            # (6, 1.5, 3) m: 6.87 m away

    point = clearing_points(depth, INTRINSICS, stride_px=4, range_m=2.0)[0]

    assert np.linalg.norm(point) == pytest.approx(2.0, rel=1e-6)
    np.testing.assert_allclose(point / np.linalg.norm(point),
                               np.array([6.0, 1.5, 3.0]) / np.linalg.norm([6.0, 1.5, 3.0]),
                               atol=1e-6)


def test_the_outermost_pixels_of_each_row_add_points_along_their_ray() -> None:
    depth = np.zeros((7, 9), np.float32)
    depth[0, 2:7] = 2.0          # row 0: valid from column 2 to 6 (off the stride grid)

    points = clearing_points(depth, INTRINSICS, stride_px=4, range_m=100.0)

    left, right = np.array([-2.0, -3.0, 2.0]), np.array([2.0, -3.0, 2.0])
    border = points[1:]          # after the one grid pixel, (4, 0)
    expected = [p * f for f in BORDER_FRACTIONS for p in (left, right)]
    np.testing.assert_allclose(border, expected, atol=1e-6)


def test_the_clearing_message_is_in_the_image_frame() -> None:
    from obstacle_detection.pipeline.detector import Detector

    depth = np.full((42, 51), 1500, np.uint16)
    result = Detector().process(depth, Intrinsics(fx=40.0, fy=40.0, cx=25.0, cy=21.0))
    points = clearing.clearing_points(result.depth_m, result.intrinsics, stride_px=4,
                                      range_m=4.0)

    messages = result_to_messages(result, stamp=Time(sec=3), cloud_frame_id='base_footprint',
                                  costmap_frame_id='base_footprint',
                                  image_frame_id='camera_optical', clearing_points=points)
    plain = result_to_messages(result, stamp=Time(sec=3), cloud_frame_id='base_footprint',
                               costmap_frame_id='base_footprint', image_frame_id='camera_optical')

    assert messages['clearing'].header.frame_id == 'camera_optical'
    np.testing.assert_array_equal(pointcloud2_to_points(messages['clearing']), points)
    assert 'clearing' not in plain


@pytest.mark.parametrize('stride', [1, 3, 4])
def test_the_compiled_clearing_points_equal_the_reference(both_paths, stride: int) -> None:
    rng = np.random.default_rng(stride)
    depth = rng.uniform(0.2, 9.0, (40, 57)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.3] = 0.0
    depth[rng.random(depth.shape) < 0.1] = np.nan
    depth[rng.random(depth.shape) < 0.05] = np.inf
    depth[:, :5] = 0.0
    depth[12] = 0.0   # a kept row (stride 1, 3, 4) without a return: no border point
    points = both_paths(clearing_points, depth, INTRINSICS, stride_px=stride, range_m=4.0)
    assert points.shape[0] > 3 * 2 * (40 // stride)


# --- marks and rays matched to a voxel layer (clearing.nav2_clouds), level camera 0.6 m up ----
#: optical -> base of a level camera 0.6 m above base_footprint's origin
LEVEL = (clearing.OPTICAL_TO_BODY, np.array([0.0, 0.0, 0.6]))


def _optical(base_points: list[list[float]]) -> np.ndarray:
    """Return base-frame points of the level camera in its optical frame, float32."""
    rot, t = LEVEL
    return ((np.array(base_points, np.float64) - t) @ rot).astype(np.float32)


def test_marks_less_than_a_cell_inside_the_outermost_rays_are_not_reachable() -> None:
    # the outermost rays run at 45 degrees left and right (optical x / z = -1 and +1)
    rays = _optical([[3.0, 3.0, 0.0], [3.0, -3.0, 0.0], [3.0, 0.0, 0.0]])
    marks = np.array([[2.0, 1.98, 0.3],      # 0.014 m inside the left ray: dropped
                      [2.0, 1.90, 0.3],      # 0.07 m inside: kept
                      [2.0, -1.96, 0.3],     # 0.028 m inside the right ray: dropped
                      [2.0, 0.0, 0.3],
                      [-1.0, 0.0, 0.3]])     # behind the camera: dropped

    keep = clearing.reachable_marks(marks, rays, *LEVEL, margin_m=0.05)

    assert keep.tolist() == [False, True, False, True, False]
    assert not clearing.reachable_marks(marks, rays[:0], *LEVEL, margin_m=0.05).any()


def test_a_column_marked_only_within_a_voxel_is_filled_two_voxels_down() -> None:
    top = [[1.01, 0.01, 0.30], [1.02, 0.02, 0.33]]             # a box top: one cell, 3 cm
    face = [[1.51, 0.01, 0.05], [1.51, 0.01, 0.30]]            # a face: 25 cm, left alone
    low = [[2.01, 0.01, 0.04]]                                  # 4 cm up: filled down to 0

    out = clearing.filled_marks(np.array(top + face + low), cell_m=0.05, voxel_m=0.1)

    assert out.dtype == np.float32 and out[:5].tolist() == np.float32(top + face + low).tolist()
    filled = out[5:]
    np.testing.assert_allclose(sorted(filled[np.isclose(filled[:, 0], 1.01), 2]),
                               [0.10, 0.15, 0.20, 0.25], atol=1e-6)
    np.testing.assert_allclose(sorted(filled[np.isclose(filled[:, 0], 1.02), 2]),
                               [0.13, 0.18, 0.23, 0.28], atol=1e-6)
    np.testing.assert_allclose(filled[np.isclose(filled[:, 0], 2.01), 2], 0.0, atol=1e-7)
    assert not np.isclose(filled[:, 0], 1.51).any()


def test_a_ray_stops_where_it_enters_a_guarded_column() -> None:
    # a mark 0.25 m up in the cell x 1.00-1.05: its column is x 0.95-1.10, z 0.15-0.35
    mark = np.array([[1.01, 0.01, 0.25]])
    rays = _optical([[2.0, 0.02, 0.0],       # to the floor behind: passes x = 0.95 at 0.315
                     [2.0, 0.02, 0.6],       # level, far above: untouched
                     [0.8, 0.02, 0.0]])      # ends before the column: untouched

    out = clearing.guarded(rays, mark, *LEVEL, cell_m=0.05, voxel_m=0.1)

    rot, t = LEVEL
    ends = out.astype(np.float64) @ rot.T + t
    assert ends[0, 0] == pytest.approx(0.95, abs=1e-5)          # the column's grown near side
    assert ends[0, 2] == pytest.approx(0.6 * (1 - 0.95 / 2.0), abs=1e-5)
    np.testing.assert_allclose(out[1:], rays[1:], atol=1e-6)


def test_a_ray_from_inside_a_guarded_column_is_dropped() -> None:
    rays = _optical([[2.0, 0.0, 0.0], [2.0, 1.0, 0.0]])
    mark = np.array([[0.0, 0.0, 0.6]])       # the camera's own column

    out = clearing.guarded(rays, mark, *LEVEL, cell_m=0.05, voxel_m=0.1)

    assert out.shape == (0, 3)


def test_nav2_clouds_leave_out_edge_marks_and_stop_the_rays_before_them() -> None:
    # rays fan out to 45 degrees; a person's edge at the left one, 2 m ahead
    fan = [[3.0, y, 0.0] for y in np.linspace(-3.0, 3.0, 61)]
    rays = _optical(fan)
    edge = [[2.0, 1.985, z] for z in (0.1, 0.5, 0.9)]
    inside = [[2.0, 0.5, z] for z in (0.1, 0.5, 0.9)]

    marks, points = clearing.nav2_clouds(np.array(edge + inside, np.float32), rays, *LEVEL,
                                         cell_m=0.05, voxel_m=0.1)

    np.testing.assert_allclose(marks, np.float32(inside))
    rot, t = LEVEL
    ends = points.astype(np.float64) @ rot.T + t
    slope = ends[:, 1] / ends[:, 0]
    # the edge column (x 2.00-2.05, y 1.95-2.00) grown by a cell: the 45 deg ray enters it at
    # x = 1.95, its two neighbours (y / x = 0.967, 0.933) at y = 1.90; the others pass it by
    assert ends[np.isclose(slope, 1.0), 0] == pytest.approx([1.95], abs=1e-5)
    near = (slope > 0.92) & (slope < 0.99)
    assert ends[near, 1] == pytest.approx([1.90, 1.90], abs=1e-5)
    assert np.isclose(ends[slope < 0.92, 0], 3.0, atol=1e-4).all()


def test_the_compiled_ray_guard_equals_the_reference(both_paths) -> None:
    rng = np.random.default_rng(7)
    rays = _optical(np.column_stack((rng.uniform(0.5, 4.0, 3000), rng.uniform(-2, 2, 3000),
                                     rng.uniform(-0.2, 1.5, 3000))).tolist())
    marks = np.column_stack((rng.uniform(0.5, 2.0, 300), rng.uniform(-1, 1, 300),
                             rng.uniform(0.0, 1.0, 300)))

    out = both_paths(clearing.guarded, rays, marks, *LEVEL, cell_m=0.05, voxel_m=0.1)

    assert 0 < out.shape[0] <= rays.shape[0]
    assert (np.linalg.norm(out, axis=1) < np.linalg.norm(rays[:out.shape[0]], axis=1)
            - 1e-6).any() or out.shape[0] < rays.shape[0]


def test_a_pitched_camera_marks_and_clears_a_box_top_at_the_same_height() -> None:
    """The body pitches the camera 2 deg down; the mount (Nav2's TF) stays level.

    Placed by that mount, the clearing cloud's floor lies on z = 0 and its box tops where the
    marks are (3-6 cm higher without the frame's pose: rays cutting the boxes' voxels).
    """
    import math

    from obstacle_detection.pipeline.detector import Detector
    from obstacle_detection.pipeline.params import corridor
    from obstacle_detection.sim.scenes import build_scene, render_scene

    frame = render_scene('corridor', seed=3, height_m=0.6, pitch_rad=math.radians(2.0),
                         noise=False)
    result = Detector(corridor()).process(frame.depth_mm, frame.intrinsics)
    assert result.floor.d_pitch_deg == pytest.approx(2.0, abs=0.1)
    nominal = result.pose.optical_to_base(
        clearing.clearing_cloud(result, stride_px=4, range_m=4.0), nominal=True)
    as_seen = result.pose.optical_to_base(
        clearing_points(result.depth_m, result.intrinsics, stride_px=4, range_m=4.0),
        nominal=True)

    floor = nominal[(nominal[:, 0] > 1.5) & (nominal[:, 0] < 2.5) & (np.abs(nominal[:, 2]) < 0.15)]
    assert np.median(np.abs(floor[:, 2])) < 0.005
    boxes = [p for p in build_scene('corridor', seed=3).primitives if p.name.startswith('box')]
    for box in boxes:
        def top(points: np.ndarray) -> np.ndarray:
            (x0, y0, _), (x1, y1, z1) = box.min_m, box.max_m
            inside = (points[:, 0] > x0 + 0.03) & (points[:, 0] < x1 - 0.03)
            inside &= (points[:, 1] > y0 + 0.03) & (points[:, 1] < y1 - 0.03)
            return points[inside & (np.abs(points[:, 2] - z1) < 0.1), 2]
        marks, cleared, raw = top(result.obstacle_points), top(nominal), top(as_seen)
        assert marks.size > 10 and cleared.size > 10
        assert np.median(cleared) == pytest.approx(np.median(marks), abs=0.003)
        assert np.median(raw) - np.median(marks) > 0.025


def test_on_a_body_pitching_2_deg_the_clearing_cloud_lies_on_the_true_surfaces() -> None:
    """The held-out drive past boxes, the body rocking +-2 deg under a static URDF.

    Placed by the URDF (the nominal mount), the clearing points of the stride grid lie on the
    true surfaces within 2.5 m (median 0.04 cm; 3.4 cm without the frame's pose).
    """
    from obstacle_detection.cli import bag_processor
    from obstacle_detection.sim.sequences import BodyPitch, SceneSequence

    config = bag_processor.config_from_values(
        bag_processor.node_param_values(REPO / 'params' / 'corridor.yaml'), 'corridor')
    sequence = SceneSequence('drive_past_boxes', body_pitch=BodyPitch(phase_deg=90.0))
    errors: dict[str, list[np.ndarray]] = {'published': [], 'as seen': []}
    for index in (8, 40, 72, 104):
        frame = sequence.frame(index, noise=False).frame
        result = config.detector.process(frame.depth_mm, frame.intrinsics)
        # the grid points come first, row by row: their pixels give their true positions
        _, _, rows, cols = clearing._rays_and_samples(result.depth_m.shape, result.intrinsics, 4)
        band = result.depth_m[rows][:, cols]
        kept_r, kept_c = np.nonzero(np.isfinite(band) & (band > 0.0))
        truth = frame.points_ground[rows[kept_r], cols[kept_c]]
        near = np.isfinite(truth).all(axis=1) & (truth[:, 0] < 2.5)
        for key, points in (
                ('published', clearing.clearing_cloud(result, stride_px=4, range_m=4.0)),
                ('as seen', clearing_points(result.depth_m, result.intrinsics, stride_px=4,
                                            range_m=4.0))):
            placed = result.pose.optical_to_base(points[:kept_r.size], nominal=True)
            errors[key].append(np.abs(placed[near, 2] - truth[near, 2]))

    assert np.median(np.concatenate(errors['published'])) < 0.003
    assert np.median(np.concatenate(errors['as seen'])) > 0.02


def test_a_ray_over_a_tall_column_passes_and_one_through_it_stops() -> None:
    # a box face 5-40 cm up in the cell x 1.00-1.05: over it a ray clears its top voxel only
    face = np.array([[1.01, 0.01, z] for z in (0.05, 0.15, 0.25, 0.40)])
    rays = _optical([[2.0, 0.02, 0.30],      # passes x = 1.0 at 0.45: over the column
                     [2.0, 0.02, 0.0]])      # passes x = 0.95 at 0.315: into it

    out = clearing.guarded(rays, face, *LEVEL, cell_m=0.05, voxel_m=0.1)

    np.testing.assert_allclose(out[0], rays[0], atol=1e-6)
    rot, t = LEVEL
    assert (out[1].astype(np.float64) @ rot.T + t)[0] == pytest.approx(0.95, abs=1e-5)


@pytest.mark.parametrize('voxel_m', [0.1, 0.0])
def test_the_node_matches_its_marks_unless_clearing_voxel_m_is_0(voxel_m: float) -> None:
    from obstacle_detection.cli import bag_processor
    from obstacle_detection.sim.scenes import render_scene

    corridor = REPO / 'params' / 'corridor.yaml'
    values = bag_processor.node_param_values(corridor) | {'clearing_voxel_m': voxel_m}
    config = bag_processor.config_from_values(values, str(corridor))
    frame = render_scene('corridor', seed=1)
    result = config.detector.process(frame.depth_mm, frame.intrinsics)

    marks, points = config.nav2_clouds(result)

    seen = clearing.clearing_cloud(result, stride_px=4, range_m=4.0)
    if voxel_m == 0.0:     # STVL: the clouds as seen
        assert marks is result.obstacle_points
        np.testing.assert_array_equal(points, seen)
    else:                  # the walls run out of the view: their edge marks are left out
        sent = {tuple(p) for p in marks.tolist()}
        left_out = [p for p in result.obstacle_points.tolist() if tuple(p) not in sent]
        assert 0 < len(left_out) < 0.2 * result.obstacle_points.shape[0]
        assert points.shape[0] == seen.shape[0] and not np.array_equal(points, seen)
