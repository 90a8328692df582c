"""The fused costmap: log-odds evidence, scrolling with odometry, clearing, odometry faults."""

import math

import numpy as np
import pytest

from obstacle_detection.labels import CELL_FREE, CELL_OCCUPIED, CELL_UNKNOWN
from obstacle_detection.pipeline.costmap import Costmap
from obstacle_detection.pipeline.fusion import FusedGrid, FusionParams, PoseBuffer, frame_evidence
from obstacle_detection.pipeline.geometry import yaw_from_quaternion

RES = 0.05


def frame_grid(occupied_xy=(), free_all=False, *, nx=40, ny=80, origin=(0.0, -2.0),
               res=RES) -> Costmap:
    """Return a per-frame costmap (base frame, 2 m x 4 m by default) with given occupied points."""
    data = np.full((ny, nx), CELL_FREE if free_all else CELL_UNKNOWN, dtype=np.int8)
    for x, y in occupied_xy:
        col = math.floor((x - origin[0]) / res)
        row = math.floor((y - origin[1]) / res)
        if 0 <= col < nx and 0 <= row < ny:
            data[row, col] = CELL_OCCUPIED
    return Costmap(data, res, origin)


def to_base(point, pose):
    """Odom point -> base-frame point of a robot at pose (x, y, yaw)."""
    dx, dy = point[0] - pose[0], point[1] - pose[1]
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return (c * dx + s * dy, -s * dx + c * dy)


def world_cell(grid: FusedGrid, point):
    """(row, col) in the window of the odom point, asserting it is inside."""
    row, col, inside = grid.cell_of(np.array([point]))
    assert inside[0]
    return int(row[0]), int(col[0])


# -- log-odds -----------------------------------------------------------------------------------

def test_log_odds_update_matches_hand_computation():
    params = FusionParams(size_m=1.0, resolution_m=0.1, hit_log_odds=0.85,
                          miss_log_odds=-0.4, min_log_odds=-2.0, max_log_odds=3.5,
                          occupied_log_odds=0.5, free_log_odds=-0.2)
    grid = FusedGrid(params)
    # frame cells 0.1 m, x in [0, 0.5), y in [-0.5, 0.5): the window's right half at pose 0
    a, b = (0.25, 0.15), (0.35, -0.25)

    def frame(a_state, b_state):
        data = np.full((10, 5), CELL_UNKNOWN, dtype=np.int8)
        for (x, y), state in ((a, a_state), (b, b_state)):
            data[math.floor((y + 0.5) / 0.1), math.floor(x / 0.1)] = state
        return Costmap(data, 0.1, (0.0, -0.5))

    hand_a, hand_b = [], []
    la = lb = 0.0
    steps = [(CELL_OCCUPIED, CELL_FREE)] * 3 + [(CELL_FREE, CELL_FREE)] + \
        [(CELL_OCCUPIED, CELL_FREE)] * 2 + [(CELL_OCCUPIED, CELL_UNKNOWN)]
    for sa, sb in steps:
        la += 0.85 if sa == CELL_OCCUPIED else -0.4
        if sb == CELL_FREE:
            lb -= 0.4
        la, lb = min(max(la, -2.0), 3.5), min(max(lb, -2.0), 3.5)
        hand_a.append(la)
        hand_b.append(lb)
        grid.update(frame(sa, sb), (0.0, 0.0, 0.0))
        np.testing.assert_allclose(grid.log_odds[world_cell(grid, a)], la, atol=1e-6)
        np.testing.assert_allclose(grid.log_odds[world_cell(grid, b)], lb, atol=1e-6)
    # 0.85, 1.7, 2.55, 2.15, 3.0, 3.5 (clamped), 3.5 ; -0.4 ... -2.0 (clamped), unchanged
    np.testing.assert_allclose(hand_a, [0.85, 1.7, 2.55, 2.15, 3.0, 3.5, 3.5])
    np.testing.assert_allclose(hand_b, [-0.4, -0.8, -1.2, -1.6, -2.0, -2.0, -2.0])
    states = grid.cell_states()
    assert states[world_cell(grid, a)] == CELL_OCCUPIED
    assert states[world_cell(grid, b)] == CELL_FREE
    assert np.count_nonzero(grid.log_odds) == 2          # every other cell never seen
    assert np.count_nonzero(states != CELL_UNKNOWN) == 2


def test_state_thresholds_and_frame_counts():
    p = FusionParams()
    assert p.frames_to_mark() == 1           # 1.0 >= 0.5
    assert p.frames_to_clear() == 5          # 2.4 - 5 * 0.4 = 0.4 < 0.5, 4 frames leave 0.8
    assert FusionParams(hit_log_odds=0.3).frames_to_mark() == 2
    assert FusionParams(max_log_odds=3.5, hit_log_odds=0.85).frames_to_clear() == 8


def test_seen_ground_clears_a_cell_after_the_computed_number_of_frames():
    params = FusionParams()
    grid = FusedGrid(params)
    point = (1.025, 0.125)   # a cell centre 1 m ahead
    pose = (0.0, 0.0, 0.0)
    for _ in range(5):                       # 1, 2, 2.4 (clamped), 2.4, 2.4
        grid.update(frame_grid([point]), pose)
    assert grid.log_odds[world_cell(grid, point)] == pytest.approx(2.4)
    free = frame_grid(free_all=True)         # the person left: ground seen in every cell
    for k in range(1, 7):
        grid.update(free, pose)
        state = grid.cell_states()[world_cell(grid, point)]
        assert (state == CELL_OCCUPIED) == (k < 5)
        np.testing.assert_allclose(grid.log_odds[world_cell(grid, point)], 2.4 - 0.4 * k,
                                   atol=1e-6)
    assert grid.cell_states()[world_cell(grid, point)] == CELL_UNKNOWN   # -0.0: undecided
    for _ in range(2):
        grid.update(free, pose)
    assert grid.cell_states()[world_cell(grid, point)] == CELL_FREE      # -0.8


def test_a_false_hit_on_seen_ground_does_not_show():
    grid = FusedGrid()
    point, pose = (1.225, -0.425), (0.0, 0.0, 0.0)
    for _ in range(4):
        grid.update(frame_grid(free_all=True), pose)                     # -1.0 (clamped)
    grid.update(frame_grid([point], free_all=True), pose)                # one false hit: 0
    assert grid.cell_states()[world_cell(grid, point)] != CELL_OCCUPIED
    grid.update(frame_grid([point], free_all=True), pose)                # a real one: 1.0
    assert grid.cell_states()[world_cell(grid, point)] == CELL_OCCUPIED


def test_unknown_cells_keep_their_evidence():
    grid = FusedGrid()
    point = (0.425, -0.075)
    for _ in range(3):
        grid.update(frame_grid([point]), (0.0, 0.0, 0.0))
    before = grid.log_odds.copy()
    for _ in range(20):                      # blind zone: the frame knows nothing there
        grid.update(frame_grid([]), (0.0, 0.0, 0.0))
    np.testing.assert_array_equal(grid.log_odds, before)
    assert grid.cell_states()[world_cell(grid, point)] == CELL_OCCUPIED


# -- scrolling ----------------------------------------------------------------------------------

def trajectory():
    """Robot poses: forward 0.9 m in uneven steps, then a left turn of 60 deg while moving."""
    poses = [(0.037 * i, 0.011 * i, 0.0) for i in range(25)]
    x, y, _ = poses[-1]
    poses += [(x + 0.02 * i, y + 0.013 * i, math.radians(6.0 * i)) for i in range(1, 11)]
    return poses


def test_a_fixed_world_obstacle_stays_in_its_world_cell_while_the_robot_moves_and_turns():
    params = FusionParams()
    grid = FusedGrid(params)
    point = (1.525, 0.475)                   # centre of odom cell (col 30, row 9)
    world = (math.floor(point[0] / RES), math.floor(point[1] / RES))
    seen = 0
    for pose in trajectory():
        update = grid.update(frame_grid([to_base(point, pose)]), pose)
        seen += 1
        assert not update.in_place and not update.reset
        # the window is centred on the robot, its origin on the odom lattice
        half = params.cells // 2
        assert grid.origin_cell == (math.floor(pose[0] / RES) - half,
                                    math.floor(pose[1] / RES) - half)
        row, col = world_cell(grid, point)
        assert (col + grid.origin_cell[0], row + grid.origin_cell[1]) == world
        # every hit landed in that one world cell: its log-odds is the hand sum
        assert grid.log_odds[row, col] == pytest.approx(min(seen * 1.0, 2.4), abs=1e-5)
        occupied = np.argwhere(grid.cell_states() == CELL_OCCUPIED)
        assert (np.abs(occupied - [row, col]).max(axis=1) <= 1).all()  # splat: a neighbour
    assert grid.pose[2] == pytest.approx(math.radians(60.0))


def test_a_costmap_cell_is_never_lost_between_rotated_lattices():
    # one occupied frame cell at every yaw from 0 to 90 deg: a window cell is always hit
    for yaw_deg in range(0, 91, 3):
        pose = (0.013, -0.021, math.radians(yaw_deg))
        hit, miss = frame_evidence(frame_grid([(1.012, 0.337)]), pose, (-40, -40), (80, 80),
                                   RES)
        assert 1 <= np.count_nonzero(hit) <= 2
        assert not (hit & miss).any()


def test_scrolling_forgets_cells_that_leave_the_window():
    grid = FusedGrid()
    point = (0.525, 0.025)
    grid.update(frame_grid([point]), (0.0, 0.0, 0.0))

    def drive(x_from, x_to):
        for x in np.linspace(x_from, x_to, 11)[1:]:
            assert not grid.update(frame_grid([]), (float(x), 0.0, 0.0)).reset

    drive(0.0, 1.5)                            # the obstacle 1 m behind: still inside
    assert grid.origin_xy_m == pytest.approx((1.5 - 2.0, -2.0))   # scrolled by 30 cells
    assert grid.values_at(np.array([point]))[0] == CELL_OCCUPIED
    drive(1.5, 3.0)                            # 2.5 m behind: it left, forgotten
    assert np.count_nonzero(grid.log_odds) == 0
    assert grid.values_at(np.array([point]))[0] == CELL_UNKNOWN
    drive(3.0, 0.0)                            # back: not remembered
    assert grid.values_at(np.array([point]))[0] == CELL_UNKNOWN


def test_to_costmap_is_the_window_in_odom():
    grid = FusedGrid(FusionParams(size_m=2.0, resolution_m=0.1))
    grid.update(frame_grid([(0.55, 0.05)], res=0.1, nx=10, ny=20, origin=(0.0, -1.0)),
                (3.02, -1.0, 0.0))
    costmap = grid.to_costmap()
    assert costmap.data.shape == (20, 20) and costmap.data.dtype == np.int8
    assert costmap.resolution_m == 0.1
    np.testing.assert_allclose(costmap.origin_xy_m, (2.0, -2.0))   # robot cell (30, -10)
    row, col, inside = costmap.cell_of(np.array([[3.57, -0.95]]))
    assert inside[0] and costmap.data[row[0], col[0]] == CELL_OCCUPIED


# -- odometry faults ----------------------------------------------------------------------------

def test_no_odometry_fuses_in_place_and_says_so_once():
    grid = FusedGrid()
    point = (0.825, -0.325)
    first = grid.update(frame_grid([point]), None)
    assert first.in_place and first.warning and 'no odometry' in first.message
    second = grid.update(frame_grid([point]), None)
    assert second.in_place and second.message == ''
    # in place at the odom origin: the base frame is the odom frame
    assert grid.log_odds[world_cell(grid, point)] == pytest.approx(2.0)
    back = grid.update(frame_grid([]), (0.0, 0.0, 0.0))
    assert not back.in_place and 'odometry received' in back.message


def test_the_reason_for_a_missing_pose_is_reported_once():
    grid = FusedGrid()
    buffer = PoseBuffer(max_age_s=0.1)
    buffer.add(0.0, (0.2, 0.0, 0.0))
    grid.update(frame_grid([]), *buffer.pose_at(0.0)[:1], pose_stamp_s=0.0)
    pose, why = buffer.pose_at(0.5)                       # odometry stopped 0.5 s ago
    update = grid.update(frame_grid([]), pose, no_pose_reason=why)
    assert update.in_place and update.reason == why and 'late' in update.message
    again = grid.update(frame_grid([]), None, no_pose_reason='no odometry received')
    assert again.in_place and again.message == ''          # the same cause: said once
    invalid = grid.update(frame_grid([]), (0.2, float('nan'), 0.0))
    assert 'not finite' in invalid.message                 # another cause: said
    assert grid.pose == (0.2, 0.0, 0.0)


def test_odometry_lost_midway_fuses_at_the_last_pose_and_loses_nothing():
    grid = FusedGrid()
    point = (1.525, 0.275)
    pose = (0.4, 0.1, math.radians(20.0))
    grid.update(frame_grid([to_base(point, pose)]), pose)
    before = grid.log_odds.copy()
    update = grid.update(frame_grid([to_base(point, pose)]), None)
    assert update.in_place
    np.testing.assert_allclose(update.pose, pose)
    assert grid.log_odds[world_cell(grid, point)] == pytest.approx(2.0)
    changed = np.argwhere(grid.log_odds != before)
    assert (np.abs(changed - world_cell(grid, point)).max(axis=1) <= 1).all()


def test_an_old_pose_is_ignored():
    grid = FusedGrid()
    grid.update(frame_grid([]), (0.5, 0.0, 0.0), pose_stamp_s=10.0)
    update = grid.update(frame_grid([]), (0.9, 0.0, 0.0), pose_stamp_s=9.5)
    assert update.in_place and update.pose == (0.5, 0.0, 0.0)
    assert 'older' in update.reason and update.warning
    again = grid.update(frame_grid([]), (0.9, 0.0, 0.0), pose_stamp_s=9.6)
    assert again.in_place and again.message == ''                 # said once
    fresh = grid.update(frame_grid([]), (0.52, 0.0, 0.0), pose_stamp_s=10.1)
    assert not fresh.in_place and fresh.pose == (0.52, 0.0, 0.0)


def test_a_pose_that_is_not_finite_fuses_in_place():
    grid = FusedGrid()
    grid.update(frame_grid([]), (0.5, 0.0, 0.0))
    update = grid.update(frame_grid([]), (float('nan'), 0.0, 0.0))
    assert update.in_place and 'not finite' in update.reason and grid.pose == (0.5, 0.0, 0.0)


def test_an_odometry_jump_is_a_reset_that_keeps_the_map_around_the_robot():
    grid = FusedGrid()
    pose = (2.0, 1.0, math.radians(30.0))
    near, side = (0.975, 0.025), (0.525, 1.475)       # base frame: ahead, and far left
    for _ in range(3):
        grid.update(frame_grid([near, side]), pose)
    # odometry restarts at a new origin: the robot did not move, odom did
    new_pose = (-7.0, 4.0, math.radians(-60.0))
    update = grid.update(frame_grid([]), new_pose)
    assert update.reset and not update.in_place
    assert 'jumped' in update.message and update.warning
    for base in (near, side):
        c, s = math.cos(new_pose[2]), math.sin(new_pose[2])
        odom = (new_pose[0] + c * base[0] - s * base[1], new_pose[1] + s * base[0] + c * base[1])
        assert grid.values_at(np.array([odom]))[0] == CELL_OCCUPIED
    assert '(0 cells lost)' in update.message
    # a 45 deg jump re-anchors a square window: its corners leave and are reported lost
    grid = FusedGrid()
    corner = (1.9, 1.9)                                 # window corner at pose 0
    grid.update(frame_grid([corner, (1.0, 0.0)]), (0.0, 0.0, 0.0))
    update = grid.update(frame_grid([]), (5.0, 5.0, math.radians(45.0)))
    assert update.reset and '(0 cells lost)' not in update.message
    assert np.count_nonzero(grid.cell_states() == CELL_OCCUPIED) >= 1   # (1, 0) kept


def test_small_pose_changes_are_not_a_reset():
    grid = FusedGrid(FusionParams(max_jump_m=0.2, max_jump_deg=10.0))
    grid.update(frame_grid([]), (0.0, 0.0, 0.0))
    assert not grid.update(frame_grid([]), (0.19, 0.0, math.radians(9.0))).reset
    assert grid.update(frame_grid([]), (0.19, 0.0, math.radians(20.0))).reset


def test_pose_buffer_interpolates_holds_and_refuses():
    buffer = PoseBuffer(max_age_s=0.1)
    assert buffer.pose_at(1.0) == (None, 'no odometry received')
    assert buffer.add(1.0, (0.0, 0.0, math.radians(170.0))) == ''
    assert buffer.add(1.2, (0.2, -0.4, math.radians(-170.0))) == ''
    pose, why = buffer.pose_at(1.05)
    assert why == ''
    np.testing.assert_allclose(pose[:2], (0.05, -0.1))
    assert math.degrees(pose[2]) == pytest.approx(175.0)             # the short way round
    pose, why = buffer.pose_at(1.15)
    assert math.degrees(pose[2]) == pytest.approx(-175.0)
    assert buffer.pose_at(1.28) == ((0.2, -0.4, math.radians(-170.0)), '')   # late, held
    pose, why = buffer.pose_at(1.5)
    assert pose is None and 'late' in why
    pose, why = buffer.pose_at(0.5)
    assert pose is None and 'older than the oldest' in why
    assert 'not newer' in buffer.add(1.1, (0.0, 0.0, 0.0))
    assert 'not finite' in buffer.add(1.3, (0.0, float('inf'), 0.0))


def test_yaw_from_quaternion():
    half = math.radians(120.0) / 2             # a quaternion of a 120 deg turn about z
    assert yaw_from_quaternion(0.0, 0.0, math.sin(half), math.cos(half)) == \
        pytest.approx(math.radians(120.0))
    assert yaw_from_quaternion(0.0, 0.0, 0.0, 1.0) == 0.0


# -- bad input ----------------------------------------------------------------------------------

@pytest.mark.parametrize('field, value, words', [
    ('size_m', 0.0, 'size_m'),
    ('resolution_m', -0.05, 'resolution_m'),
    ('resolution_m', 5.0, 'must not exceed size_m'),
    ('resolution_m', 1e-4, 'cells a side'),
    ('hit_log_odds', 0.0, 'hit_log_odds'),
    ('miss_log_odds', 0.4, 'miss_log_odds'),
    ('min_log_odds', 1.0, 'min_log_odds'),
    ('max_log_odds', float('nan'), 'max_log_odds'),
    ('free_log_odds', 0.1, 'free_log_odds'),
    ('free_log_odds', -3.0, 'free_log_odds'),
    ('occupied_log_odds', 4.0, 'occupied_log_odds'),
    ('occupied_log_odds', True, 'occupied_log_odds'),
    ('max_jump_m', 0.0, 'max_jump_m'),
    ('max_jump_deg', 200.0, 'max_jump_deg'),
])
def test_bad_parameters_are_refused_with_their_name(field, value, words):
    with pytest.raises(ValueError, match=words):
        FusionParams(**{field: value})
