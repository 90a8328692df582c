"""The robot-level ground truth (issue 9) against scenes whose answer is known by construction."""

import math

import numpy as np
import pytest

from obstacle_detection.labels import GT_ABOVE_ROBOT, GT_NO_RETURN, GT_OBSTACLE, GT_TRAVERSABLE
from obstacle_detection.pipeline.params import DetectorParams
from obstacle_detection.sim.primitives import Box, Cylinder, Floor, Ramp, RampSide, StepDown
from obstacle_detection.sim.render import render, Scene
from obstacle_detection.sim.scenes import chair, render_scene, table
from obstacle_detection.sim.truth import DROP_EDGE_BAND_M, TruthRules


def exact(primitives, *, height_m=0.6, pitch_deg=0.0, rules=None):
    """Render primitives without noise from a camera at height_m, pitched pitch_deg down."""
    return render(Scene('t', tuple(primitives), height_m=height_m,
                        pitch_rad=math.radians(pitch_deg)), noise=False, rules=rules)


def on(frame, index, *, z=None, tol=1e-3):
    """Return the returned pixels of primitive ``index`` (at height z within tol, if given)."""
    mask = (frame.hit_index == index) & (frame.depth_mm > 0)
    if z is not None:
        mask &= np.abs(frame.points_ground[..., 2] - z) < tol
    return mask


def test_box_top_is_an_obstacle_and_the_floor_around_it_traversable():
    frame = exact([Floor(), Box.on_floor(1.5, 0.0, 0.4, 0.4, 0.3)])
    top = on(frame, 1, z=0.3)
    assert top.sum() > 200
    assert np.all(frame.labels[top] == GT_OBSTACLE)
    assert np.all(frame.labels[on(frame, 1)] == GT_OBSTACLE)
    assert np.all(frame.labels[on(frame, 0)] == GT_TRAVERSABLE)


def test_landing_reached_by_a_passable_ramp_is_traversable_and_unreached_it_is_not():
    ramp = Ramp(x_start_m=1.1, y_center_m=0.0, width_m=0.8, length_m=0.6,
                slope_rad=math.radians(10.0))
    rise = ramp.top_height_m
    landing = Box((1.7, -0.4, 0.0), (3.0, 0.4, rise))
    with_ramp = exact([Floor(), ramp, landing])
    # away from the open sides (ledges, issue 22: a band of DROP_EDGE_BAND_M is an obstacle)
    pts = with_ramp.points_ground
    inner = ((np.abs(pts[..., 1]) < 0.4 - DROP_EDGE_BAND_M - 1e-3)
             & (pts[..., 0] < 3.0 - DROP_EDGE_BAND_M - 1e-3))
    top = on(with_ramp, 2, z=rise)
    assert (top & inner).sum() > 200
    assert np.all(with_ramp.labels[top & inner] == GT_TRAVERSABLE)
    assert np.all(with_ramp.labels[on(with_ramp, 1) & inner] == GT_TRAVERSABLE)
    # the same platform without its ramp is 0.106 m up: more than a step, an obstacle
    alone = exact([Floor(), landing])
    assert np.all(alone.labels[on(alone, 1, z=rise)] == GT_OBSTACLE)
    # and behind a ramp steeper than theta it is unreachable too
    steep = Ramp(x_start_m=1.6, y_center_m=0.0, width_m=0.8, length_m=0.1,
                 slope_rad=math.atan(rise / 0.1))
    assert steep.slope_rad > math.radians(30.0)
    blocked = exact([Floor(), steep, landing])
    assert np.all(blocked.labels[on(blocked, 2, z=rise)] == GT_OBSTACLE)
    assert np.all(blocked.labels[on(blocked, 1)] == GT_OBSTACLE)


def test_ramp_traversability_follows_theta_of_the_rules():
    ramp = Ramp(x_start_m=1.1, y_center_m=0.0, width_m=0.8, length_m=1.0,
                slope_rad=math.radians(15.0))
    frame = exact([Floor(), ramp])
    pts = frame.points_ground   # away from its open sides and end (ledges, issue 22)
    inner = ((np.abs(pts[..., 1]) < 0.4 - DROP_EDGE_BAND_M - 1e-3)
             & (pts[..., 0] < 2.1 - DROP_EDGE_BAND_M - 1e-3))
    assert np.all(frame.labels[on(frame, 1) & inner] == GT_TRAVERSABLE)
    strict = exact([Floor(), ramp], rules=TruthRules(max_slope_rad=math.radians(10.0)))
    assert on(strict, 1).sum() > 1000
    assert np.all(strict.labels[on(strict, 1)] == GT_OBSTACLE)
    assert np.all(strict.labels_seed[on(strict, 1)] == GT_TRAVERSABLE)   # the seed: 15 < 30


def test_sill_is_traversable_sides_included_and_a_curb_is_an_obstacle():
    sill = Box((1.4, -0.5, 0.0), (1.48, 0.5, 0.03))
    curb = Box((1.4, -0.5, 0.0), (1.55, 0.5, 0.10))
    frame = exact([Floor(), sill])
    assert on(frame, 1).sum() > 50
    assert np.all(frame.labels[on(frame, 1)] == GT_TRAVERSABLE)
    frame = exact([Floor(), curb])
    assert on(frame, 1, z=0.10).sum() > 50
    assert np.all(frame.labels[on(frame, 1)] == GT_OBSTACLE)


def test_step_height_is_a_rule():
    step = Box((1.4, -0.5, 0.0), (1.6, 0.5, 0.04))
    assert np.all(exact([Floor(), step]).labels[on(exact([Floor(), step]), 1)]
                  == GT_TRAVERSABLE)
    strict = exact([Floor(), step], rules=TruthRules(max_step_height_m=0.03))
    assert np.all(strict.labels[on(strict, 1)] == GT_OBSTACLE)


def test_shelf_board_is_an_obstacle_and_the_floor_under_it_traversable():
    board = Box((1.2, -0.5, 0.35), (1.6, 0.5, 0.37))
    frame = exact([Floor(), board], height_m=0.2)   # a low camera sees under the board
    underside = on(frame, 1, z=0.35)
    assert underside.sum() > 200
    assert np.all(frame.labels[on(frame, 1)] == GT_OBSTACLE)
    x, y = frame.points_ground[..., 0], frame.points_ground[..., 1]
    under = on(frame, 0) & (x > 1.2) & (x < 1.6) & (np.abs(y) < 0.5)
    assert under.sum() > 200
    assert np.all(frame.labels[under] == GT_TRAVERSABLE)


def test_table_top_underside_and_legs_are_obstacles():
    parts = table(1.6, 0.0, 0.6, 0.8, 0.72)
    frame = exact((Floor(),) + parts)
    ids = range(1, 1 + len(parts))
    hits = np.isin(frame.hit_index, list(ids)) & (frame.depth_mm > 0)
    assert on(frame, 1, z=0.69).sum() > 100       # the underside, seen from 0.6 m
    assert np.all(frame.labels[hits] == GT_OBSTACLE)
    assert set(frame.object_names[1:]) == {'table'}
    seat = chair(1.2, 0.0)
    assert {p.name for p in seat} == {'chair'} and len(seat) == 6


def test_overhang_above_the_robot_is_not_an_obstacle():
    overhang = Box((1.2, -0.6, 1.15), (1.8, 0.6, 1.2))
    frame = exact([Floor(), overhang])
    assert on(frame, 1).sum() > 200
    assert np.all(frame.labels[on(frame, 1)] == GT_ABOVE_ROBOT)
    assert np.all(frame.labels_seed[on(frame, 1)] == GT_OBSTACLE)
    taller = exact([Floor(), overhang], rules=TruthRules(robot_height_m=1.5))
    assert np.all(taller.labels[on(taller, 1)] == GT_OBSTACLE)


def test_height_above_the_robot_is_measured_from_the_ground_under_the_point():
    # a post standing on a landing 0.4 m up (reached by a ramp): 1.0 m above the landing is
    # 1.4 m above the floor
    ramp = Ramp(x_start_m=0.5, y_center_m=0.0, width_m=2.0, length_m=1.5,
                slope_rad=math.atan(0.4 / 1.5))
    landing = Box((2.0, -1.0, 0.0), (4.0, 1.0, 0.4))
    post = Cylinder(2.5, 0.0, radius_m=0.1, height_m=1.5, base_z_m=0.4)
    frame = exact([Floor(), ramp, landing, post], height_m=1.0)
    z = frame.points_ground[..., 2]
    hits = on(frame, 3)
    assert (hits & (z > 1.1) & (z < 1.35)).sum() > 20
    assert np.all(frame.labels[hits & (z < 1.39)] == GT_OBSTACLE)
    assert np.all(frame.labels[hits & (z > 1.41)] == GT_ABOVE_ROBOT)


def test_lower_floor_beyond_a_drop_is_an_obstacle_and_its_edge_is_flagged():
    frame = exact([StepDown(x_m=1.3, depth_m=0.3)], height_m=1.0, pitch_deg=25.0)
    x = frame.points_ground[..., 0]
    z = frame.points_ground[..., 2]
    returned = frame.depth_mm > 0
    lower = returned & (z < -0.29)
    upper = returned & (z > -1e-6)
    assert lower.sum() > 1000 and upper.sum() > 1000
    assert np.all(frame.labels[lower] == GT_OBSTACLE)
    assert np.all(frame.labels[upper] == GT_TRAVERSABLE)
    edge = frame.drop_edge & returned
    assert edge.sum() > 100
    assert np.all(upper[edge])
    assert np.all(x[edge] >= 1.3 - DROP_EDGE_BAND_M - 1e-6) and np.all(x[edge] <= 1.3 + 1e-6)
    assert not (upper & ~frame.drop_edge & (x > 1.3 - DROP_EDGE_BAND_M + 1e-3)).any()


def test_a_small_step_down_is_driven_over():
    frame = exact([StepDown(x_m=1.3, depth_m=0.03)], height_m=1.0, pitch_deg=25.0)
    returned = frame.depth_mm > 0
    assert np.all(frame.labels[returned] == GT_TRAVERSABLE)
    assert not frame.drop_edge.any()


def test_bumpy_ground_is_traversable_and_a_low_bush_an_obstacle():
    frame = render_scene('orchard', seed=0, noise=False)
    names = np.array(frame.object_names + ('',))[frame.hit_index]
    returned = frame.depth_mm > 0
    assert np.all(frame.labels[returned & (frame.hit_index == 0)] == GT_TRAVERSABLE)
    bush = returned & np.char.startswith(names, 'bush')
    assert bush.sum() > 500
    assert np.all(frame.labels[bush] == GT_OBSTACLE)


def test_rules_from_params_read_the_detector_fields():
    params = DetectorParams().replace(max_slope_rad=0.3, max_step_height_m=0.08,
                                      robot_height_m=1.4)
    rules = TruthRules.from_params(params)
    assert (rules.max_slope_rad, rules.max_step_height_m, rules.robot_height_m) == (0.3, 0.08, 1.4)
    assert rules.max_step_down_m == params.max_step_down_m
    assert TruthRules.from_params(rules) == rules


def _open_platform(side_y: float):
    # a 12 deg ramp from x = 1.0 up to 0.18 m, a platform beyond it, |y| <= 0.4 (issue 22)
    slope = math.radians(12.0)
    run = 0.18 / math.tan(slope)
    ramp = Ramp(x_start_m=1.0, y_center_m=side_y + 0.4, width_m=0.8, length_m=run,
                slope_rad=slope)
    platform = Box((1.0 + run, side_y, 0.0), (1.0 + run + 1.2, side_y + 0.8, 0.18))
    return [RampSide(1.0, side_y, run, slope), Floor(), ramp, platform], run


def test_open_side_of_a_reached_ramp_and_platform_is_a_ledge():
    # straight ahead, both sides open: seen along it, a band of DROP_EDGE_BAND_M along each
    # side where the surface stands more than a step above the floor is an obstacle
    prims, run = _open_platform(-0.4)
    frame = exact(prims[1:])
    pts = frame.points_ground
    edge_dist = 0.4 - np.abs(pts[..., 1])
    ramp_z = (pts[..., 0] - 1.0) * math.tan(math.radians(12.0))
    for index in (1, 2):   # the ramp, the platform
        mine = on(frame, index) & (pts[..., 0] < 1.0 + run + 1.2 - DROP_EDGE_BAND_M - 1e-3)
        high = mine & (np.minimum(ramp_z, 0.18) > 0.05 + 1e-3)
        band = high & (edge_dist < DROP_EDGE_BAND_M - 1e-3)
        assert band.sum() > 20
        assert np.all(frame.labels[band] == GT_OBSTACLE)
        inner = mine & (edge_dist > DROP_EDGE_BAND_M + 1e-3)
        assert inner.sum() > 200
        assert np.all(frame.labels[inner] == GT_TRAVERSABLE)
    # where the ramp is no higher than a step, its side is no ledge
    low = on(frame, 1) & (ramp_z < 0.05 - 1e-3) & (edge_dist < DROP_EDGE_BAND_M - 1e-3)
    assert low.sum() > 20
    assert np.all(frame.labels[low] == GT_TRAVERSABLE)


def test_open_side_face_seen_from_the_floor_is_an_obstacle_above_a_step():
    prims, run = _open_platform(0.25)
    frame = exact(prims)
    side = on(frame, 0)
    z = frame.points_ground[..., 2]
    ramp_z = (frame.points_ground[..., 0] - 1.0) * math.tan(math.radians(12.0))
    climbable = side & (ramp_z < 0.05 - 1e-3)
    assert side.sum() > 100 and climbable.sum() > 5
    assert np.all(frame.labels[side & (ramp_z > 0.05 + 1e-3)] == GT_OBSTACLE)
    assert np.all(frame.labels[climbable] == GT_TRAVERSABLE)   # a riser no higher than a step
    assert np.all(frame.labels[on(frame, 1)] == GT_TRAVERSABLE)   # the floor beside it
    assert np.all(z[side] >= -1e-6)


def test_a_platform_beside_a_drop_keeps_its_drop_and_gets_no_ledge():
    # the lower floor beyond a drop is not reached: a drop (flagged), not a ledge
    frame = exact([StepDown(x_m=1.4, depth_m=0.3)])
    upper = on(frame, 0, z=0.0)
    assert np.all(frame.labels[upper] == GT_TRAVERSABLE)


@pytest.mark.parametrize('name', ['office', 'dark_office', 'ramp_landing', 'dock_edge',
                                  'dock_edge_high', 'curb_sill', 'shelf', 'orchard',
                                  'open_ramp', 'open_ramp_ahead', 'dark_furniture',
                                  'thin_legs'])
def test_new_scenes_keep_labels_consistent_with_depth(name):
    frame = render_scene(name, seed=1)
    np.testing.assert_array_equal(frame.labels == GT_NO_RETURN, frame.depth_mm == 0)
    np.testing.assert_array_equal(frame.labels_seed == GT_NO_RETURN, frame.depth_mm == 0)
    assert frame.hit_index.dtype == np.int16
    assert any(frame.object_names)
    # every named object within the 2 m range is in view
    seen = {frame.object_names[i] for i in np.unique(frame.hit_index[frame.depth_mm > 0])}
    near = {p.name for p in frame.primitives
            if p.name and (p.bounds() is None or p.bounds()[0][0] < 2.0)}
    assert near and near <= seen
