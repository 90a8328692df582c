"""Robot-level traversability, drops and the floor fit against geometry with a known answer.

Scenes are built from the generator's primitives (Box, Wall, Ramp, StepDown, Floor) and
rendered without noise unless a test says otherwise, so what is an obstacle is known from the
geometry alone. Cells are 5 cm (the costmap's default); each test looks at cells well inside
the object it asks about, and checks that the seed's slope-only preset (``table_4_2``) gets it
wrong where the robot-level rule is meant to differ (the test has teeth).
"""

import math

import numpy as np
import pytest

from obstacle_detection.labels import CELL_OCCUPIED, CELL_UNKNOWN, LABEL_GROUND, LABEL_OBSTACLE
from obstacle_detection.evaluation import runner as evaluation
from obstacle_detection.pipeline import floor, geometry, traversal
from obstacle_detection.pipeline.params import corridor, table_4_2
from obstacle_detection.pipeline.detector import Detector
from obstacle_detection.sim.primitives import Box, Floor, Ramp, StepDown, Wall
from obstacle_detection.sim.render import render, Scene
from obstacle_detection.sim.scenes import render_scene, scene_params


SCENARIOS = evaluation.SUITES['seed']


def run(primitives, *, height=0.6, pitch_deg=0.0, noise=False, preset=corridor,
        seed=0, **overrides):
    """Render the primitives from the mount and run the detector; (frame, params, result)."""
    scene = Scene('test', tuple(primitives), height_m=height,
                  pitch_rad=math.radians(pitch_deg))
    frame = render(scene, seed=seed, noise=noise)
    params = scene_params(frame, preset(median_kernel=5, **overrides))
    return frame, params, Detector(params).process(frame.depth_mm, frame.intrinsics)


def cells(result, x0, x1, y0, y1):
    """Costmap values of the cells whose centres lie in [x0, x1] x [y0, y1] [m]."""
    xs, ys = result.costmap.cell_centres()
    cols = (xs >= x0) & (xs <= x1)
    rows = (ys >= y0) & (ys <= y1)
    return result.costmap.data[np.ix_(rows, cols)]


def seen(values):
    """Return the cells that were seen (not unknown)."""
    return values[values != CELL_UNKNOWN]


def occupied_share(values):
    """Share of the seen cells that are occupied (nan when none was seen)."""
    v = seen(values)
    return float(np.mean(v == CELL_OCCUPIED)) if v.size else math.nan


def test_box_top_is_an_obstacle_not_ground():
    box = Box.on_floor(1.3, 0.0, 0.4, 0.4, 0.25)      # top at 0.25 m, seen from 0.6 m
    _, _, robot = run([Floor(), box], pitch_deg=15.0)
    _, _, seed = run([Floor(), box], pitch_deg=15.0, preset=table_4_2)
    top = (1.15, 1.45, -0.15, 0.15)                 # cells inside the top, off its edges
    assert seen(cells(robot, *top)).size >= 20
    assert occupied_share(cells(robot, *top)) == 1.0
    assert occupied_share(cells(seed, *top)) < 0.5   # the seed calls the flat top ground
    # the floor around it stays free
    assert occupied_share(cells(robot, 0.6, 1.0, -0.6, 0.6)) == 0.0


def test_ramp_and_its_landing_are_free_a_steep_ramp_is_not():
    slope = math.radians(15.0)
    run_m = 0.6
    top = run_m * math.tan(slope)
    ramp = Ramp(x_start_m=0.9, y_center_m=0.0, width_m=0.8, length_m=run_m, slope_rad=slope)
    landing = Box((0.9 + run_m, -0.4, 0.0), (2.6, 0.4, top), traversable=True)
    _, _, robot = run([Floor(), ramp, landing], pitch_deg=10.0)
    inside = cells(robot, 0.95, 1.95, -0.3, 0.3)     # ramp and landing, off the side edges
    assert seen(inside).size >= 150
    assert occupied_share(inside) <= 0.03            # >= 97 % free
    # a 45 deg ramp is not climbable: its cells above the step height are obstacles
    steep = Ramp(x_start_m=0.9, y_center_m=0.0, width_m=0.8, length_m=0.4,
                 slope_rad=math.radians(45.0))
    _, _, blocked = run([Floor(), steep], pitch_deg=10.0)
    assert occupied_share(cells(blocked, 1.0, 1.25, -0.3, 0.3)) == 1.0


def test_door_sill_is_free_a_curb_is_occupied():
    sill = Box.on_floor(1.3, 0.0, 0.06, 1.2, 0.03)    # 3 cm: below the 5 cm step height
    _, _, robot = run([Floor(), sill])
    around = cells(robot, 1.2, 1.4, -0.5, 0.5)
    assert seen(around).size >= 30 and occupied_share(around) == 0.0
    curb = Box.on_floor(1.35, 0.0, 0.3, 1.2, 0.10)    # 10 cm: a step the robot cannot take
    _, _, robot = run([Floor(), curb])
    on_curb = cells(robot, 1.25, 1.45, -0.5, 0.5)
    assert seen(on_curb).size >= 30 and occupied_share(on_curb) == 1.0
    _, _, seed = run([Floor(), curb], preset=table_4_2)
    assert occupied_share(cells(seed, 1.25, 1.45, -0.5, 0.5)) < 0.5   # its top is flat


def test_shelf_is_an_obstacle_and_the_floor_seen_under_it_is_ground():
    # a board 0.4-0.43 m up, seen from a camera 0.3 m up: the floor under it is in view
    shelf = Box((1.3, -0.5, 0.40), (1.7, 0.5, 0.43))
    frame, _, robot = run([Floor(), shelf], height=0.3)
    under = cells(robot, 1.35, 1.5, -0.4, 0.4)     # (farther, the board is seen too grazing)
    assert seen(under).size >= 40 and occupied_share(under) == 1.0
    x = frame.points_ground[..., 0]
    hit_shelf = (frame.hit_index == 1) & (x < 1.5)
    hit_floor_under = (frame.hit_index == 0) & (x > 1.35) & (x < 1.65) & (
        np.abs(frame.points_ground[..., 1]) < 0.4)
    assert hit_floor_under.sum() > 200 and hit_shelf.sum() > 200
    labels = robot.labels
    assert np.mean(labels[hit_floor_under] == LABEL_GROUND) > 0.97
    assert np.mean(labels[hit_shelf] == LABEL_OBSTACLE) > 0.9
    _, _, seed = run([Floor(), shelf], height=0.3, preset=table_4_2)
    assert np.mean(seed.labels[hit_shelf] == LABEL_OBSTACLE) < 0.5   # flat: ground to it


def test_overhang_above_the_robot_is_not_marked():
    overhang = Box((1.2, -0.6, 1.15), (1.8, 0.6, 1.25))    # above robot_height_m = 1.0
    frame, _, robot = run([Floor(), overhang])
    assert (frame.hit_index == 1).sum() > 500              # it is in view
    under = cells(robot, 1.25, 1.75, -0.5, 0.5)
    assert seen(under).size >= 40 and occupied_share(under) == 0.0
    assert not (robot.labels[frame.hit_index == 1] == LABEL_OBSTACLE).any()
    # the same board below a taller robot blocks it
    _, _, tall = run([Floor(), overhang], robot_height_m=1.5)
    assert occupied_share(cells(tall, 1.25, 1.75, -0.5, 0.5)) > 0.5


def test_drop_with_the_lower_floor_inside_the_range_is_marked():
    step = StepDown(x_m=1.2, depth_m=0.3)
    frame, _, robot = run([step], pitch_deg=15.0)
    beyond = cells(robot, 1.5, 1.95, -0.5, 0.5)            # lower floor, inside the 2 m range
    assert seen(beyond).size >= 40 and occupied_share(beyond) == 1.0
    assert occupied_share(cells(robot, 0.6, 1.1, -0.5, 0.5)) == 0.0   # upper floor free
    _, _, seed = run([step], pitch_deg=15.0, preset=table_4_2)
    assert occupied_share(cells(seed, 1.5, 1.95, -0.5, 0.5)) == 0.0 or \
        np.isnan(occupied_share(cells(seed, 1.5, 1.95, -0.5, 0.5)))   # the seed cannot see it


def test_drop_with_the_lower_floor_beyond_the_range_is_marked_where_the_floor_ends():
    step = StepDown(x_m=1.6, depth_m=1.0)     # lower floor seen only from about 2.9 m on
    frame, params, robot = run([step])
    assert robot.drop_points.shape[0] > 50
    edge = robot.drop_points
    assert np.all(edge[:, 0] <= 1.6) and np.all(edge[:, 0] >= 1.6 - 0.05)
    # the cells where the floor ends, across the view, are marked
    at_edge = cells(robot, 1.55, 1.6, -0.5, 0.5)
    assert (at_edge == CELL_OCCUPIED).mean() > 0.9
    assert occupied_share(cells(robot, 0.6, 1.5, -0.5, 0.5)) == 0.0
    assert (frame.points_ground.reshape(-1, 3)[robot.labels.reshape(-1) == LABEL_OBSTACLE, 0]
            > 1.6).all()                      # the pixels that saw past the edge are labelled
    # no return beyond the edge: nothing is marked
    depth = frame.depth_mm.copy()
    depth[frame.points_ground[..., 0] > 1.6] = 0
    quiet = Detector(params).process(depth, frame.intrinsics)
    assert quiet.drop_points.shape[0] == 0
    assert not (quiet.costmap.data == CELL_OCCUPIED).any()


def box_before_a_wall():
    """(frame, params, depth in mm as float32, the box's pixels): a box 2.3 m before a wall."""
    frame, params, _ = run([Floor(), Box.on_floor(1.2, 0.0, 0.3, 0.3, 0.5),
                            Wall(3.5, -3.0, 3.5, 3.0)])
    return frame, params, frame.depth_mm.astype(np.float32), frame.hit_index == 1


def test_flying_pixels_between_a_box_and_the_wall_behind_are_not_marked():
    frame, params, depth, on_box = box_before_a_wall()
    # mixed pixels: the column beside the box's left and right silhouette takes depths
    # between the box and the wall behind it, as a time-of-flight sensor gives at edges
    rows = np.flatnonzero(on_box.any(axis=1))
    cols = np.flatnonzero(on_box.any(axis=0))
    flying = np.zeros_like(on_box)
    for col in (cols[0] - 1, cols[-1] + 1):
        flying[rows, col] = ~on_box[rows, col]
    box_depth = np.median(depth[on_box])
    depth[flying] = 0.5 * (box_depth + depth[flying])
    assert flying.sum() > 50
    result = Detector(params).process(depth.astype(np.uint16), frame.intrinsics)
    truth_free = ~on_box & (frame.hit_index != 2)
    flying_points = frame.points_ground[flying & truth_free]
    assert not (result.labels[flying] == LABEL_OBSTACLE).any()
    # the cells beside the box (floor only) stay free
    beside = np.concatenate([cells(result, 1.1, 1.3, 0.25, 0.5).ravel(),
                             cells(result, 1.1, 1.3, -0.5, -0.25).ravel()])
    assert seen(beside).size >= 10 and occupied_share(beside) == 0.0
    assert flying_points.shape[0] > 0


@pytest.mark.parametrize('error', [dict(pitch=3.0), dict(pitch=-3.0), dict(roll=3.0),
                                   dict(roll=-3.0), dict(height=0.05), dict(height=-0.05)])
def test_mount_errors_are_absorbed_by_the_floor_fit(error):
    scenario = next(s for s in evaluation.load_scenarios(SCENARIOS) if s.name == 'corridor')
    frame = list(evaluation.scenario_frames(scenario))[1]
    params = corridor(camera_height_m=frame.height_m, camera_pitch_rad=frame.pitch_rad,
                      camera_roll_rad=frame.roll_rad)
    truth = evaluation.truth_costmap(frame, params) == CELL_OCCUPIED
    exact = Detector(params).process(frame.depth, frame.intrinsics).costmap.data
    wrong = params.replace(
        camera_pitch_rad=params.camera_pitch_rad + math.radians(error.get('pitch', 0.0)),
        camera_roll_rad=params.camera_roll_rad + math.radians(error.get('roll', 0.0)),
        camera_height_m=params.camera_height_m + error.get('height', 0.0))

    def f1(data, against=truth):
        a = data == CELL_OCCUPIED
        return 2 * np.sum(a & against) / (np.sum(a) + np.sum(against))

    fitted = Detector(wrong).process(frame.depth, frame.intrinsics)
    assert fitted.floor.refined
    assert f1(exact) > 0.9
    assert abs(f1(fitted.costmap.data) - f1(exact)) <= 0.02     # the same costmap quality
    assert f1(fitted.costmap.data, exact == CELL_OCCUPIED) >= 0.95   # and nearly the same cells
    # the correction it reports undoes the error
    assert fitted.floor.d_pitch_deg == pytest.approx(-error.get('pitch', 0.0), abs=0.3)
    assert fitted.floor.d_roll_deg == pytest.approx(-error.get('roll', 0.0), abs=0.3)
    assert fitted.floor.d_height_m == pytest.approx(-error.get('height', 0.0), abs=0.01)
    if 'height' not in error:   # without the fit a 3 deg error ruins the costmap
        unfitted = Detector(wrong.replace(refine_floor=False)).process(frame.depth,
                                                                        frame.intrinsics)
        assert f1(unfitted.costmap.data) < f1(exact) - 0.05


def test_floor_fit_falls_back_to_the_mount_and_says_why():
    frame = render_scene('corridor', seed=1)
    params = scene_params(frame, corridor())
    blank = np.zeros_like(frame.depth_mm)
    result = Detector(params).process(blank, frame.intrinsics)
    assert not result.floor.refined and 'floor_min_points' in result.floor.reason
    assert result.floor.height_m == params.camera_height_m
    off = Detector(params.replace(refine_floor=False)).process(frame.depth_mm,
                                                                frame.intrinsics)
    assert not off.floor.refined and off.floor.reason == 'off'
    # a floor 20 deg off the mount is not believed (beyond floor_max_tilt_deg): no fit moves
    # the mount by more than the bound
    tilted = Detector(params.replace(camera_pitch_rad=math.radians(20.0))).process(
        frame.depth_mm, frame.intrinsics)
    assert abs(tilted.floor.d_pitch_deg) <= 5.0 and abs(tilted.floor.d_roll_deg) <= 5.0


def test_seed_presets_ignore_the_robot_level_parameters():
    frame = render_scene('corridor', seed=0)
    base = scene_params(frame, table_4_2(median_kernel=5))
    ref = Detector(base).process(frame.depth_mm, frame.intrinsics)
    other = Detector(base.replace(max_step_height_m=0.2, robot_height_m=0.5,
                                  max_filter_shift=0.5)).process(frame.depth_mm,
                                                                 frame.intrinsics)
    np.testing.assert_array_equal(ref.costmap.data, other.costmap.data)
    np.testing.assert_array_equal(ref.labels, other.labels)
    assert ref.drop_points.shape[0] == 0 and not ref.floor.refined


def test_labels_follow_the_costmap_decision():
    frame, _, result = run([Floor(), Box.on_floor(1.3, 0.0, 0.4, 0.4, 0.25)], noise=True)
    obstacle_voxels = np.unique(result.pixel_voxel[result.labels == LABEL_OBSTACLE])
    obstacle_voxels = obstacle_voxels[obstacle_voxels >= 0]
    assert result.voxel_is_obstacle[obstacle_voxels].all()
    ground_voxels = np.unique(result.pixel_voxel[result.labels == LABEL_GROUND])
    assert not result.voxel_is_obstacle[ground_voxels].any()
    row, col, inside = result.costmap.cell_of(result.voxel_points[obstacle_voxels])
    assert (result.costmap.data[row[inside], col[inside]] == CELL_OCCUPIED).all()


# -- ledges: the open sides of raised traversable surfaces (issue 22) ------------------------

LEDGE_CELL = 0.05
VOXEL = 0.025


def surface_voxels(x0, x1, y0, y1, z):
    """Voxel centroids (N, 3) float32 of a level surface at z over [x0, x1) x [y0, y1) [m]."""
    xs = np.arange(x0 + VOXEL / 2, x1, VOXEL)
    ys = np.arange(y0 + VOXEL / 2, y1, VOXEL)
    gx, gy = np.meshgrid(xs, ys, indexing='ij')
    return np.stack((gx.ravel(), gy.ravel(), np.full(gx.size, z)), axis=1).astype(np.float32)


def ledge_marks(parts, reached_flags, *, step=0.05):
    """Run traversal.ledges on parts (point arrays), each reached or not; (points, marks)."""
    pts = np.concatenate(parts)
    reached = np.concatenate([np.full(len(p), r) for p, r in zip(parts, reached_flags)])
    steep = np.zeros(len(pts), bool)
    above = pts[:, 2] > 1.0
    return pts, traversal.ledges(pts, steep, reached, above, LEDGE_CELL, step, step,
                                 traversal.LEDGE_SHADOW_CELLS)


@pytest.mark.parametrize('rise', [0.18, 0.10])
@pytest.mark.parametrize('edge, last', [(0.5, 0.55), (0.525, 0.6)])
def test_a_raised_reached_surface_beside_the_floor_has_its_edge_cells_marked(rise, edge, last):
    # floor for y < edge, a platform (reached through a ramp elsewhere) for y >= edge; at
    # 0.525 m the edge lies half-way across the cell [0.50, 0.55), which holds floor and
    # platform voxels and is the edge's cell
    floor_pts = surface_voxels(1.0, 2.0, -0.5, edge, 0.0)
    platform = surface_voxels(1.0, 2.0, edge, 1.0, rise)
    pts, marks = ledge_marks([floor_pts, platform], [True, True])
    y = pts[:, 1]
    assert np.all(marks[(y > edge) & (y < 0.55)])          # the platform's part of that cell
    assert not marks[y < edge].any()                       # no floor voxel
    assert not marks[y > last].any()                       # within a cell of the edge


def test_a_far_side_over_its_shadow_is_marked_when_the_floor_beyond_is_not_reached():
    # a platform's far side, its shadow empty, the floor beyond seen but reached by nothing
    # (an island past the shadow): it is still the lower ground the side drops to
    floor_pts = surface_voxels(1.0, 2.0, -0.5, 0.5, 0.0)
    platform = surface_voxels(1.0, 2.0, 0.5, 1.0, 0.18)
    beyond = surface_voxels(1.0, 2.0, 1.3, 1.6, 0.0)
    pts, marks = ledge_marks([floor_pts, platform, beyond], [True, True, False])
    y = pts[:, 1]
    assert np.all(marks[(y > 0.95) & (y < 1.0)])           # the far side's cells
    assert not marks[y > 1.0].any()


def test_a_step_no_higher_than_the_step_height_is_no_ledge():
    floor_pts = surface_voxels(1.0, 2.0, -0.5, 0.5, 0.0)
    sill = surface_voxels(1.0, 2.0, 0.5, 1.0, 0.04)
    _, marks = ledge_marks([floor_pts, sill], [True, True])
    assert not marks.any()


def test_two_surfaces_within_the_floor_band_are_no_ledge():
    # range noise on a far floor: cells 8.5 cm apart, both within a step of z = 0
    low = surface_voxels(1.0, 2.0, -0.5, 0.5, -0.045)
    high = surface_voxels(1.0, 2.0, 0.5, 1.0, 0.04)
    _, marks = ledge_marks([low, high], [True, True])
    assert not marks.any()


def test_a_walkway_at_floor_level_above_a_lower_reached_floor_has_a_ledge():
    # the robot on a walkway (z = 0), the floor beside it 0.18 m lower (reached by a ramp)
    walkway = surface_voxels(1.0, 2.0, -0.5, 0.5, 0.0)
    lower = surface_voxels(1.0, 2.0, 0.5, 1.0, -0.18)
    pts, marks = ledge_marks([walkway, lower], [True, True])
    y = pts[:, 1]
    assert np.all(marks[(y > 0.45) & (y < 0.5)])
    assert not marks[(y < 0.45) | (y > 0.5)].any()


def test_a_raised_surface_that_was_not_reached_is_left_to_the_height_rule():
    # a box top: not reached, so no ledge (it is an obstacle by its height already)
    floor_pts = surface_voxels(1.0, 2.0, -0.5, 0.5, 0.0)
    box_top = surface_voxels(1.0, 2.0, 0.5, 1.0, 0.3)
    _, marks = ledge_marks([floor_pts, box_top], [True, False])
    assert not marks.any()


def test_the_edge_is_found_across_its_shadow_away_from_the_camera_only():
    # seen from the origin, the floor right beyond the platform's far side is hidden: a gap
    # of cells without voxels, then the floor again
    platform = surface_voxels(1.0, 2.0, 0.0, 0.5, 0.18)
    beyond = surface_voxels(1.0, 2.0, 0.7, 1.2, 0.0)
    pts, marks = ledge_marks([platform, beyond], [True, True])
    y = pts[:, 1]
    assert np.all(marks[(y > 0.45) & (y < 0.5)])
    assert not marks[(y < 0.45) | (y > 0.5)].any()
    # the same gap on the camera's side is no shadow of the platform: nothing is inferred
    mirrored = pts * np.float32([1.0, -1.0, 1.0])
    mirrored[:, 1] += np.float32(1.2)     # platform at y 0.7..1.2, floor at 0..0.5
    far_plat = mirrored[:, 2] > 0.1
    _, marks2 = ledge_marks([mirrored[far_plat], mirrored[~far_plat]], [True, True])
    assert not marks2.any()


def test_a_side_face_seen_from_the_floor_is_marked_above_a_step():
    floor_pts = surface_voxels(1.0, 2.0, -0.5, 0.5, 0.0)
    platform = surface_voxels(1.0, 2.0, 0.55, 1.0, 0.18)
    zs = np.arange(0.0125, 0.18, VOXEL)
    xs = np.arange(1.0125, 2.0, VOXEL)
    gx, gz = np.meshgrid(xs, zs, indexing='ij')
    face = np.stack((gx.ravel(), np.full(gx.size, 0.51), gz.ravel()), axis=1).astype(np.float32)
    face_floor = surface_voxels(1.0, 2.0, 0.5, 0.55, 0.0)    # the floor at its foot
    pts, marks = ledge_marks([floor_pts, platform, face, face_floor], [True, True, False, False])
    n_face0 = len(floor_pts) + len(platform)
    on_face = np.zeros(len(pts), bool)
    on_face[n_face0:n_face0 + len(face)] = True
    assert np.all(marks[on_face & (pts[:, 2] > 0.05 + 1e-3)])
    assert not marks[on_face & (pts[:, 2] < 0.05 - 1e-3)].any()
    assert not marks[:len(floor_pts)].any()


def test_ledge_is_never_above_the_robot():
    floor_pts = surface_voxels(1.0, 2.0, -0.5, 0.5, 0.0)
    high = surface_voxels(1.0, 2.0, 0.5, 1.0, 1.2)          # reached, but 1.2 m up
    _, marks = ledge_marks([floor_pts, high], [True, True])
    assert not marks.any()


def test_the_detector_marks_both_open_sides_of_a_ramp_seen_along_it():
    slope = math.radians(12.0)
    run_m = 0.18 / math.tan(slope)
    ramp = Ramp(x_start_m=0.9, y_center_m=0.0, width_m=0.9, length_m=run_m, slope_rad=slope)
    platform = Box((0.9 + run_m, -0.45, 0.0), (3.0, 0.45, 0.18))
    _, _, robot = run([Floor(), ramp, platform], refine_floor=False)
    x0 = 1.3                                            # the ramp over 8 cm up, the platform
    for y0, y1 in ((0.35, 0.5), (-0.5, -0.35)):          # within a cell of each open side
        edge = cells(robot, x0, 1.7, y0, y1)   # the floor beyond the shadow within 2 m
        assert seen(edge).size >= 10
        assert all(np.any(col == CELL_OCCUPIED) for col in edge.T)   # every x along it
    assert occupied_share(cells(robot, x0, 2.0, -0.3, 0.3)) == 0.0   # the middle stays free


# -- the compiled kernels equal the numpy path -----------------------------------------------

def _robot_level_outputs(params, frame):
    """Return the outputs of one robot-level frame that do not depend on the clock."""
    result = Detector(params).process(frame.depth_mm, frame.intrinsics)
    return (result.obstacle_points, result.ground_points, result.labels, result.voxel_points,
            result.voxel_is_obstacle, result.voxel_slope_obstacle, result.voxel_height_m,
            result.drop_points, result.depth_m, result.costmap, result.floor)


@pytest.mark.parametrize('name', ['corridor', 'ramps', 'step_down', 'open_ramp_ahead'])
def test_robot_level_pipeline_identical_with_and_without_jit(name, both_paths):
    frame = render_scene(name, seed=2)
    both_paths(_robot_level_outputs, scene_params(frame, corridor()), frame)


@pytest.mark.numba
def test_traversal_kernels_equal_numpy(both_paths):
    rng = np.random.default_rng(5)
    pts = rng.uniform([0.0, -1.0, -0.4], [2.0, 1.0, 1.5], size=(3000, 3)).astype(np.float32)
    pts[:1500, 2] = rng.normal(0.0, 0.01, 1500)                 # a floor
    steep = rng.random(3000) < 0.3
    # cells of 5 cm (2 x 2 voxels), steps up to 5 cm, down to 4 cm, the robot 1 m tall
    both_paths(traversal.traversable_ground, pts, steep, corridor(max_step_down_m=0.04))
    depth = rng.uniform(0.5, 4.0, size=(60, 80)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.1] = 0.0
    depth[5, 5] = np.nan
    rz = rng.uniform(-0.6, 0.1, size=depth.shape).astype(np.float32)
    assert both_paths(traversal.drop_edge_mask, depth, rz, 0.6, 0.05, 0.05, 3).any()
    raw = depth.copy()
    filtered = raw + rng.normal(0, 0.05, raw.shape).astype(np.float32)
    both_paths(traversal.drop_smeared, filtered, raw, 0.03)   # raw with a NaN: not fused


def test_ledge_kernel_equals_numpy(both_paths):
    rng = np.random.default_rng(22)
    marked = 0
    for trial in range(20):
        n = int(rng.integers(50, 3000))
        pts = rng.uniform([0.3, -1.5, -0.1], [3.0, 1.5, 0.4], size=(n, 3)).astype(np.float32)
        pts[: n // 2, 2] = rng.choice([0.0, 0.03, 0.18, 1.2], n // 2) + rng.normal(0, 0.01, n // 2)
        steep = rng.random(n) < 0.2
        reached = rng.random(n) < 0.6
        above = pts[:, 2] > 1.0
        want = both_paths(traversal.ledges, pts, steep, reached, above, 0.05, 0.05, 0.05,
                          traversal.LEDGE_SHADOW_CELLS)
        marked += int(want.sum())
    assert marked > 100


def test_drop_edge_needs_a_jump_and_seen_floor():
    # a column looking down at a floor that ends: rows 0-4 passed it, rows 5-9 see it
    rz = np.full((10, 1), -0.5, np.float32)
    depth = np.full((10, 1), 1.0, np.float32)            # z = 0.5 - 0.5 = 0: floor
    depth[:5] = 2.0                                       # z = -0.4: passed the floor plane
    mask = traversal.drop_edge_mask(depth, rz, 0.5, 0.05, 0.05)
    assert mask[:, 0].tolist() == [0, 0, 3, 2, 1] + [0] * 5     # rows down to the floor end
    depth[5:] = 0.0                                       # no return below: nothing
    assert not traversal.drop_edge_mask(depth, rz, 0.5, 0.05, 0.05).any()
    depth[5:] = 1.08                                      # a gentle dip, no jump: nothing
    depth[:5] = 1.12
    assert not traversal.drop_edge_mask(depth, rz, 0.5, 0.05, 0.05).any()


def test_floor_samples_ignore_no_return():
    frame = render_scene('flat_floor', seed=0)
    params = scene_params(frame, corridor())
    depth = frame.depth_mm * np.float32(1e-3)
    depth[:, :256] = np.nan
    depth[:, 256:300] = 0.0
    rays = geometry.ray_model(depth.shape, frame.intrinsics, params)
    pts = floor.floor_samples(depth, floor.sample_rays(rays, depth.shape), params)
    assert pts.shape[1] > 100 and np.isfinite(pts).all()
    assert np.abs(pts[2]).max() < 0.05


@pytest.mark.numba
@pytest.mark.parametrize('shape', [(1, 1), (2, 3), (3, 5), (5, 4), (7, 9), (60, 80)])
def test_fused_smear_kernel_equals_numpy(shape, both_paths):
    # the compiled pass computes the 5 x 5 window range itself (no OpenCV): every image size,
    # the borders, holes, flying pixels between two surfaces and planar grazing floors
    rng = np.random.default_rng(shape[0] * 100 + shape[1])
    raw = rng.choice(np.float32([1.0, 2.0, 4.0]), size=shape).astype(np.float32)
    raw += rng.normal(0.0, 0.02, shape).astype(np.float32)
    raw[rng.random(shape) < 0.15] = 0.0
    rows = np.arange(shape[0], dtype=np.float32)[:, None]
    raw[:, :shape[1] // 3] = 1.0 / (0.2 + 0.01 * rows)          # a plane: 1/depth affine
    filtered = raw + rng.normal(0.0, 0.08, shape).astype(np.float32)
    filtered[rng.random(shape) < 0.1] = 0.0
    both_paths(traversal.drop_smeared, filtered, raw, 0.03)


@pytest.mark.numba
@pytest.mark.parametrize('shape', [(1, 1), (2, 5), (4, 3), (60, 80)])
def test_drop_pixels_kernel_equals_the_numpy_mask(shape, both_paths):
    rng = np.random.default_rng(shape[0] + 7 * shape[1])
    depth = rng.uniform(0.5, 2.5, size=shape).astype(np.float32)
    depth[rng.random(shape) < 0.1] = 0.0
    depth.reshape(-1)[::17] = np.nan
    rot = np.eye(3)
    rot[2] = (0.3, 0.3, -0.25)                            # the rays' z between -0.6 and 0.1
    rays = geometry.GroundRays(rng.uniform(-0.6, 0.6, shape[1]),
                               rng.uniform(-0.5, 0.5, shape[0]), rot)
    pixels, offsets = both_paths(traversal.drop_pixels, depth, rays.ru, rays.rv, rays.rot,
                                 0.6, 0.05, 0.05, 3)
    mask = traversal.drop_edge_mask(depth, rays.table()[2], 0.6, 0.05, 0.05, 3)
    np.testing.assert_array_equal(pixels, np.flatnonzero(mask))
    np.testing.assert_array_equal(offsets, mask.reshape(-1)[np.flatnonzero(mask)])
    assert pixels.dtype == np.int64
    if shape == (60, 80):
        assert pixels.size > 10 and set(offsets.tolist()) == {1, 2, 3}


_WARM_UP_CHECK = """
from obstacle_detection.pipeline._compiled import traversal as jit_traversal
from obstacle_detection.pipeline.params import corridor
from obstacle_detection.pipeline.detector import Detector
from obstacle_detection.sim.scenes import render_scene, scene_params
frame = render_scene('step_down', seed=1)
detector = Detector(scene_params(frame, corridor()))
detector.warm_up()
kernels = {name: k for name, k in vars(jit_traversal).items() if hasattr(k, 'signatures')}
before = {name: len(k.signatures) for name, k in kernels.items()}
result = detector.process(frame.depth_mm, frame.intrinsics)
assert result.floor.refined and result.drop_points.shape[0] > 0
after = {name: len(k.signatures) for name, k in kernels.items()}
print(sorted(name for name in kernels if after[name] != before[name]))
"""


@pytest.mark.numba
def test_warm_up_compiles_every_robot_level_kernel_a_frame_uses():
    # the node compiles in the background (Detector.warm_up); a frame must then find every
    # kernel of the smear pass, the floor fit, the traversal and the drops ready (a fresh
    # process: nothing compiled by other tests)
    import subprocess
    import sys
    run = subprocess.run([sys.executable, '-c', _WARM_UP_CHECK], capture_output=True,
                         text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == '[]', f'compiled during the frame: {run.stdout}'


def test_lone_voxels_are_those_without_a_neighbour(kernel_path):
    v = 0.025
    board = np.array([(1.0 + i * v, j * v, 0.5) for i in range(4) for j in range(4)])
    leg = np.array([(1.5, 0.5, k * v) for k in range(8)])          # a 2.5 cm column
    diagonal = np.array([(1.7, -0.2, 0.3), (1.7 + v, -0.2 + v, 0.3 + v)])
    alone = np.array([(1.3, -0.5, 0.4), (1.9, 0.6, 0.2)])          # mixed pixels in the air
    pts = (np.concatenate((board, leg, diagonal, alone)) + v / 2).astype(np.float32)
    lone = traversal.lone_voxels(pts, v, v, v)
    assert not lone[:-2].any() and lone[-2:].all()
    assert traversal.lone_voxels(np.zeros((0, 3), np.float32), v, v, v).shape == (0,)
    assert traversal.lone_voxels(pts[-1:], v, v, v).all()


@pytest.mark.numba
def test_lone_voxel_kernel_equals_numpy(both_paths):
    rng = np.random.default_rng(3)
    pts = rng.uniform([0.0, -1.0, -0.4], [2.0, 1.0, 1.5], size=(4000, 3)).astype(np.float32)
    pts[:2000, 2] = 0.3   # a board: neighbours
    assert both_paths(traversal.lone_voxels, pts, 0.025, 0.025, 0.025).sum() > 100


def test_mixed_pixels_scattered_in_the_air_are_not_marked():
    frame, params, depth, on_box = box_before_a_wall()
    # every 8th pixel of the column beside the box's silhouette, whose near side returned
    # nothing (a dropout blob): mixed depths scattered between the box and the wall
    rows = np.flatnonzero(on_box.any(axis=1))
    col = np.flatnonzero(on_box.any(axis=0))[-1] + 1
    depth[:, col - 3:col + 1] = 0.0
    rows = rows[::8]
    near = np.median(depth[on_box])
    mixed = near + np.linspace(0.1, 0.9, rows.size) * (depth[rows, col] - near)
    depth[rows, col] = mixed[np.random.default_rng(0).permutation(rows.size)]
    result = Detector(params).process(depth.astype(np.uint16), frame.intrinsics)
    # without the lone-voxel rule every one is marked (N1 counts the others); with it, those
    # next to the box, the floor or the wall only
    assert (result.labels[rows, col] == LABEL_OBSTACLE).mean() < 0.4
    assert (result.labels[on_box & (depth > 0)] == LABEL_OBSTACLE).mean() > 0.5


def test_the_band_just_under_the_robot_height_is_marked():
    # a tall cabinet: its face just under the robot's height (1 m) has neighbours above the
    # robot; they support its validation (N1), as they would any obstacle's
    cabinet = Box.on_floor(1.4, 0.0, 0.4, 0.8, 1.6)
    frame, params, result = run([Floor(), cabinet], noise=True)
    z = frame.points_ground[..., 2]
    band = (frame.hit_index == 1) & (z > 0.95) & (z < 0.99) & (frame.depth_mm > 0)
    assert band.sum() > 200
    assert (result.labels[band] == LABEL_OBSTACLE).mean() > 0.95   # 0.63 without the rule
    assert not (result.labels[(frame.hit_index == 1) & (z > 1.05)] == LABEL_OBSTACLE).any()


def test_feet_are_the_candidates_right_under_a_marked_voxel(kernel_path):
    v = 0.025
    column = np.array([(1.0, 0.0, k * v) for k in range(1, 8)])   # 2.5 to 17.5 cm up
    apart = np.array([(1.5, 0.3, 0.05), (1.5, 0.3, 0.20)])          # 4 voxels apart: too far
    pts = (np.concatenate((column, apart)) + v / 2).astype(np.float32)
    candidates = np.ones(pts.shape[0], bool)
    candidates[0] = False                     # within the step: not a candidate
    marked = np.zeros(pts.shape[0], bool)
    marked[4:7] = True                        # the validation kept the top of the column
    marked[-1] = True
    foot = traversal.feet(pts, candidates, marked, v, v, v)
    assert foot.tolist() == [False, True, True, True, False, False, False, False, False]


@pytest.mark.numba
def test_foot_kernel_equals_numpy(both_paths):
    rng = np.random.default_rng(4)
    pts = rng.uniform([0.0, -1.0, -0.4], [2.0, 1.0, 1.5], size=(4000, 3)).astype(np.float32)
    pts[:2000, :2] = np.round(pts[:2000, :2] / 0.1) * 0.1   # columns
    candidates = rng.random(4000) < 0.6
    marked = candidates & (rng.random(4000) < 0.5)
    assert both_paths(traversal.feet, pts, candidates, marked, 0.025, 0.025, 0.025).any()


def test_the_foot_of_a_box_is_marked():
    # the bottom band of a box (5-10 cm up) has floor among its N1 neighbours: the validation
    # lets it go, the marked face above it keeps it
    box = Box.on_floor(1.3, 0.0, 0.4, 0.8, 0.4)
    frame, params, result = run([Floor(), box], noise=True)
    z = frame.points_ground[..., 2]
    band = (frame.hit_index == 1) & (z > 0.06) & (z < 0.1) & (frame.depth_mm > 0)
    assert band.sum() > 100
    assert (result.labels[band] == LABEL_OBSTACLE).mean() > 0.9


def test_unbias_holes_undoes_the_median_where_its_window_was_mostly_no_return():
    import cv2

    # a wall seen at a grazing angle: depth rising 1 % a pixel; its left half 40 % dropouts
    rng = np.random.default_rng(3)
    true = (1.0 * 1.01 ** np.arange(64, dtype=np.float64))[None, :].repeat(40, axis=0)
    raw = np.round(true * 1000.0).astype(np.uint16)
    raw[:, :32][rng.random((40, 32)) < 0.4] = 0
    filtered = cv2.medianBlur(raw, 5).astype(np.float32) / 1000.0
    raw_m = raw.astype(np.float32) / 1000.0
    returned = raw > 0
    left = (slice(2, -2), slice(2, 28))
    # no-returns sort first: the median of a window with holes is nearer than the surface
    bias = (filtered - true)[left][returned[left]] / true[left][returned[left]]
    assert bias.mean() < -0.005
    out = traversal.unbias_holes(filtered.copy(), raw_m, 5)
    holes = cv2.boxFilter((~returned).astype(np.uint8), cv2.CV_16U, (5, 5), normalize=False,
                          borderType=cv2.BORDER_REPLICATE)
    biased = holes >= 5                                       # a fifth of 25
    assert biased[left].mean() > 0.8
    back = biased & returned & (filtered > 0.0)   # a 0 (dropped by drop_smeared) stays 0
    assert back.sum() > 300
    np.testing.assert_array_equal(out[back], raw_m[back])
    assert np.all(out[biased & (filtered == 0.0)] == 0.0)
    assert np.all(out[biased & ~returned] == 0.0)                  # filled holes stay holes
    np.testing.assert_array_equal(out[~biased], filtered[~biased])  # the rest keeps its median
    assert np.all(out[:, 36:] == filtered[:, 36:])


@pytest.mark.numba
def test_unbias_holes_kernel_equals_numpy(both_paths):
    from scipy.ndimage import median_filter

    # known geometry: a grazing wall, its left half 40 % dropouts (the test above), K = 5 and 17
    rng = np.random.default_rng(3)
    true = (1.0 * 1.01 ** np.arange(64, dtype=np.float64))[None, :].repeat(40, axis=0)
    raw = np.round(true * 1000.0).astype(np.float32) / np.float32(1000.0)
    raw[:, :32][rng.random((40, 32)) < 0.4] = 0.0
    for k in (5, 17):
        filtered = median_filter(raw, size=k, mode='nearest')
        filtered[::7, ::5] = 0.0                            # dropped by drop_smeared
        out = both_paths(traversal.unbias_holes, filtered, raw, k)
        assert (out != filtered).sum() > 100
    # random: holes, NaN, inf, negative depths; images smaller than the window
    for _ in range(60):
        h, w = rng.integers(2, 30, 2)
        k = int(rng.choice([1, 3, 5, 7, 17]))
        raw = rng.uniform(0.3, 4.0, (h, w)).astype(np.float32)
        for value, share in ((0.0, rng.random()), (np.nan, 0.05), (np.inf, 0.02), (-1.0, 0.02)):
            raw[rng.random((h, w)) < share] = value
        filtered = rng.uniform(0.0, 4.0, (h, w)).astype(np.float32)
        filtered[rng.random((h, w)) < 0.2] = 0.0
        filtered[rng.random((h, w)) < 0.05] = np.nan
        both_paths(traversal.unbias_holes, filtered, raw, k)
