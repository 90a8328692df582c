"""The scene generator against geometry whose answer is known in closed form."""

import math

import numpy as np
import pytest

from eval_helpers import to_ground
from obstacle_detection.labels import GT_ABOVE_ROBOT, GT_NO_RETURN, GT_OBSTACLE, GT_TRAVERSABLE
from obstacle_detection.sim import scenes
from obstacle_detection.pipeline.geometry import back_project
from obstacle_detection.pipeline.params import DetectorParams, Intrinsics, KINECT_V2_SD
from obstacle_detection.sim.noise import (KINECT_V2_NOISE, KINECT_V2_TOF_NOISE, NOISE_MODELS,
                                          NoiseModel)
from obstacle_detection.sim.primitives import Box, Cylinder, Floor, StepDown, Wall
from obstacle_detection.sim.render import render, Scene
from obstacle_detection.sim.scenes import render_scene, scene_params
from obstacle_detection.sim.truth import DROP_EDGE_BAND_M

HEIGHT_M = 0.6
QHD = Intrinsics(fx=540.0, fy=540.0, cx=479.5, cy=269.5)   # another camera, 960x540


def wall_scene(distance_m: float, *, dark: bool = False) -> Scene:
    """Return a floor and a wide wall across the view at x = distance_m, level camera."""
    return Scene('wall', (Floor(), Wall(distance_m, 6.0, distance_m, -6.0, 0.0, 3.0,
                                        dark=dark)), height_m=HEIGHT_M)


# -- flat floor -------------------------------------------------------------------------------

def test_level_camera_floor_depth_per_row():
    height_m = 0.8
    frame = render_scene('flat_floor', noise=False, height_m=height_m)
    intr = frame.intrinsics
    rows = np.arange(frame.depth_mm.shape[0])
    below = rows > intr.cy
    expected = np.zeros(rows.size)
    expected[below] = height_m * intr.fy / (rows[below] - intr.cy)
    in_band = (expected >= 0.5) & (expected <= 4.5)
    assert in_band.sum() > 100
    depth = frame.depth_mm[in_band].astype(float) * 1e-3
    np.testing.assert_allclose(depth, np.broadcast_to(expected[in_band, None], depth.shape),
                               atol=1e-3)
    np.testing.assert_allclose(frame.depth_true_m[in_band],
                               np.broadcast_to(expected[in_band, None], depth.shape), rtol=1e-5)
    assert not frame.depth_mm[~in_band].any()


def test_level_camera_sees_no_floor_above_the_horizon():
    frame = render_scene('flat_floor', noise=False)
    horizon = int(math.floor(frame.intrinsics.cy))
    assert not frame.depth_mm[:horizon + 1].any()
    assert np.all(frame.labels[:horizon + 1] == GT_NO_RETURN)
    assert np.isnan(frame.points_ground[:horizon + 1]).all()


def test_flat_floor_hits_are_traversable_ground_at_z_zero():
    frame = render_scene('flat_floor', noise=False, pitch_rad=math.radians(20.0))
    returned = frame.depth_mm > 0
    assert returned.sum() > 10000
    assert np.all(frame.labels[returned] == GT_TRAVERSABLE)
    hits = np.isfinite(frame.points_ground[..., 0])
    np.testing.assert_allclose(frame.points_ground[hits][:, 2], 0.0, atol=1e-5)


@pytest.mark.parametrize('pitch_deg', [10.0, 20.0, 30.0, 45.0])
def test_pitched_camera_centre_pixel_depth(pitch_deg):
    pitch = math.radians(pitch_deg)
    frame = render_scene('flat_floor', noise=False, pitch_rad=pitch)
    u, v = int(KINECT_V2_SD.cx), int(KINECT_V2_SD.cy)
    assert frame.depth_true_m[v, u] == pytest.approx(HEIGHT_M / math.sin(pitch), rel=1e-6)
    assert abs(int(frame.depth_mm[v, u]) - 1e3 * HEIGHT_M / math.sin(pitch)) <= 0.5


def test_pitched_floor_scene_defaults_to_30_degrees():
    frame = render_scene('pitched_floor', noise=False)
    assert frame.pitch_rad == pytest.approx(math.radians(30.0))
    u, v = int(KINECT_V2_SD.cx), int(KINECT_V2_SD.cy)
    assert frame.depth_true_m[v, u] == pytest.approx(2.0 * HEIGHT_M, rel=1e-6)


@pytest.mark.parametrize('pitch_deg, roll_deg', [(0.0, 0.0), (30.0, 0.0), (25.0, 10.0),
                                                 (45.0, -15.0)])
def test_pipeline_back_projection_puts_the_floor_at_z_zero(pitch_deg, roll_deg):
    """The generator and geometry.mount_transform share one mount convention."""
    frame = render_scene('flat_floor', noise=False, pitch_rad=math.radians(pitch_deg),
                         roll_rad=math.radians(roll_deg))
    points, index = back_project(frame.depth_true_m, frame.intrinsics)
    ground = to_ground(points, scene_params(frame))
    assert index.size > 10000
    np.testing.assert_allclose(ground[:, 2], 0.0, atol=2e-4)
    np.testing.assert_allclose(ground, frame.points_ground.reshape(-1, 3)[index], atol=2e-4)


# -- walls, boxes, ramps, cylinders, steps ----------------------------------------------------

@pytest.mark.parametrize('distance_m', [1.0, 2.5])
def test_wall_straight_ahead(distance_m):
    frame = render(wall_scene(distance_m), noise=False)
    u, v = int(KINECT_V2_SD.cx), int(KINECT_V2_SD.cy)
    assert frame.depth_mm[v, u] == round(1e3 * distance_m)
    assert frame.labels[v, u] == GT_OBSTACLE
    on_wall = frame.hit_index == 1
    # a fronto-parallel plane has the same depth in every pixel
    np.testing.assert_allclose(frame.depth_true_m[on_wall], distance_m, rtol=1e-6)
    assert np.all(frame.labels_seed[on_wall] == GT_OBSTACLE)
    # robot level: the wall is an obstacle up to the robot's height (1 m), above it not
    high = frame.points_ground[..., 2] > 1.0
    assert np.all(frame.labels[on_wall & ~high] == GT_OBSTACLE)
    assert np.all(frame.labels[on_wall & high] == GT_ABOVE_ROBOT)
    assert (on_wall & high).any()


def test_box_faces_are_obstacle():
    box = Box((1.0, -0.2, 0.0), (1.4, 0.2, 0.3))
    frame = render(Scene('box', (Floor(), box), pitch_rad=math.radians(25.0)), noise=False)
    on_box = frame.hit_index == 1
    points = frame.points_ground[on_box]
    front = np.isclose(points[:, 0], 1.0, atol=1e-6)
    top = np.isclose(points[:, 2], 0.3, atol=1e-6)
    assert front.sum() > 500 and top.sum() > 500
    assert np.all(front | top)   # only these two faces face the camera
    assert np.all(frame.labels[on_box] == GT_OBSTACLE)
    assert np.all(frame.hit_labels[frame.hit_index == 0] == GT_TRAVERSABLE)


def test_ramps_gentle_traversable_steep_obstacle():
    frame = render_scene('ramps', noise=False)
    gentle, steep = frame.primitives[1], frame.primitives[2]
    assert gentle.slope_rad == pytest.approx(math.radians(15.0))
    assert steep.slope_rad == pytest.approx(math.radians(45.0))
    for index, ramp, label in ((1, gentle, GT_TRAVERSABLE), (2, steep, GT_OBSTACLE)):
        on_ramp = frame.hit_index == index
        if label == GT_TRAVERSABLE:   # away from its open sides and end (ledges, issue 22)
            x, y = frame.points_ground[..., 0], frame.points_ground[..., 1]
            band = DROP_EDGE_BAND_M + 1e-3
            on_ramp &= ((np.abs(y - ramp.y_center_m) < ramp.width_m / 2 - band)
                        & (x < ramp.x_start_m + ramp.length_m - band))
        assert on_ramp.sum() > 2000
        assert np.all(frame.labels[on_ramp] == label)
        x, z = frame.points_ground[on_ramp][:, 0], frame.points_ground[on_ramp][:, 2]
        np.testing.assert_allclose(z, (x - ramp.x_start_m) * math.tan(ramp.slope_rad),
                                   atol=1e-5)


def test_cylinder_silhouette_width():
    radius, distance = 0.2, 2.0
    scene = Scene('person', (Floor(), Cylinder(distance, 0.0, radius, 1.7)))
    frame = render(scene, noise=False)
    row = int(KINECT_V2_SD.cy)
    width_px = np.count_nonzero(frame.labels[row] == GT_OBSTACLE)
    exact = 2.0 * KINECT_V2_SD.fx * radius / math.sqrt(distance ** 2 - radius ** 2)
    assert abs(width_px - exact) <= 2.0
    assert width_px == pytest.approx(2.0 * radius * KINECT_V2_SD.fx / distance, rel=0.05)
    # nearest point of the cylinder, straight ahead, at its front surface
    assert frame.depth_true_m[row, int(KINECT_V2_SD.cx)] == pytest.approx(distance - radius,
                                                                          rel=1e-6)


def test_step_down_lower_floor_and_riser():
    frame = render_scene('step_down', noise=False, pitch_rad=math.radians(20.0))
    step = frame.primitives[0]
    on_step = frame.hit_index == 0
    points = frame.points_ground[on_step]
    labels = frame.hit_labels[on_step]
    upper = points[:, 0] < step.x_m
    np.testing.assert_allclose(points[upper, 2], 0.0, atol=1e-6)
    np.testing.assert_allclose(points[~upper, 2], -0.3, atol=1e-6)
    assert upper.sum() > 1000 and (~upper).sum() > 1000
    assert np.all(labels[upper] == GT_TRAVERSABLE)
    assert np.all(labels[~upper] == GT_OBSTACLE)


def test_small_drop_is_traversable():
    frame = render(Scene('curb', (StepDown(x_m=1.2, depth_m=0.05),), pitch_rad=0.3),
                   noise=False)
    lower = frame.points_ground[..., 2] < -0.01
    assert lower.sum() > 1000
    assert np.all(frame.hit_labels[lower] == GT_TRAVERSABLE)


def test_riser_is_obstacle():
    # looking down past the vertical from just beyond the edge: the riser faces the camera
    scene = Scene('edge', (StepDown(x_m=-0.1, depth_m=0.3),), pitch_rad=math.radians(75.0))
    frame = render(scene, noise=False)
    riser = np.isclose(frame.points_ground[..., 0], -0.1, atol=1e-6)
    assert riser.sum() > 1000
    assert np.all(frame.hit_labels[riser] == GT_OBSTACLE)
    z = frame.points_ground[riser][:, 2]
    assert z.min() >= -0.3 - 1e-6 and z.max() <= 1e-6


def test_bumpy_floor_hits_lie_on_the_surface_and_are_traversable():
    frame = render_scene('farm_row', noise=False, seed=5)
    floor = frame.primitives[0]
    on_floor = frame.hit_index == 0
    points = frame.points_ground[on_floor].astype(np.float64)
    near = frame.depth_true_m[on_floor] < 4.5
    assert near.sum() > 20000
    surface = floor.height(points[near, 0], points[near, 1])
    np.testing.assert_allclose(points[near, 2], surface, atol=2e-4)
    assert np.ptp(points[near, 2]) > 0.04   # the bumps are there, a few cm each way
    assert np.all(np.abs(points[near, 2]) <= floor.bump_amplitude_m + 1e-4)
    assert np.all(frame.labels[on_floor & (frame.depth_mm > 0)] == GT_TRAVERSABLE)
    assert np.all(frame.labels[frame.hit_index > 0] != GT_TRAVERSABLE)


# -- sensor model -----------------------------------------------------------------------------

def test_same_seed_same_frame_other_seed_or_frame_differs():
    a = render_scene('corridor', seed=3)
    b = render_scene('corridor', seed=3)
    np.testing.assert_array_equal(a.depth_mm, b.depth_mm)
    np.testing.assert_array_equal(a.labels, b.labels)
    assert np.any(render_scene('corridor', seed=4).depth_mm != a.depth_mm)
    assert np.any(render_scene('corridor', seed=3, frame_index=1).depth_mm != a.depth_mm)


def test_depth_outside_the_valid_band_is_no_return():
    for distance in (0.45, 4.8):   # 4.8 m: 11 sigma beyond the band
        for noise in (False, True):
            frame = render(wall_scene(distance), noise=noise)
            assert not frame.depth_mm[frame.hit_index == 1].any()
    frame = render_scene('corridor', seed=1)
    returned = frame.depth_mm[frame.depth_mm > 0]
    assert returned.min() >= 500 and returned.max() <= 4500
    exact = render_scene('corridor', noise=False)
    band = (exact.depth_true_m >= 0.5005) & (exact.depth_true_m <= 4.4995)
    np.testing.assert_array_equal(exact.depth_mm > 0, band)


def test_noise_free_depth_is_the_rounded_true_depth():
    frame = render_scene('people', noise=False)
    returned = frame.depth_mm > 0
    error_mm = frame.depth_mm[returned] - 1e3 * frame.depth_true_m[returned].astype(np.float64)
    assert np.abs(error_mm).max() <= 0.5 + 1e-3   # rounded to the nearest millimetre


def test_border_pixels_are_no_return():
    frame = render(wall_scene(2.0), seed=2)
    border = np.ones(frame.depth_mm.shape, dtype=bool)
    border[4:-4, 4:-4] = False
    assert not frame.depth_mm[border].any()
    assert frame.depth_mm[~border].mean() > 0


def test_labels_are_no_return_exactly_where_depth_is_zero():
    frame = render_scene('dark_materials', seed=7)
    np.testing.assert_array_equal(frame.labels == GT_NO_RETURN, frame.depth_mm == 0)
    returned = frame.depth_mm > 0
    np.testing.assert_array_equal(frame.labels[returned], frame.hit_labels[returned])


@pytest.mark.parametrize('dark, rate', [(False, 0.01), (True, 0.4)])
def test_dropout_fraction(dark, rate):
    model = NoiseModel(dropout_rate=0.01, dark_dropout_rate=0.4, border_px=0)
    frame = render(wall_scene(2.0, dark=dark), noise=model, seed=11)
    on_wall = frame.hit_index == 1
    assert on_wall.sum() > 50000
    fraction = np.mean(frame.depth_mm[on_wall] == 0)
    assert fraction == pytest.approx(rate, abs=0.1 * rate)


def test_dark_dropouts_in_blobs_keep_the_rate_and_come_in_blobs():
    model = NoiseModel(dropout_rate=0.0, dark_dropout_rate=0.4, border_px=0, dark_blob_px=6.0)
    frame = render(wall_scene(2.0, dark=True), noise=model, seed=11)
    on_wall = frame.hit_index == 1
    dropped = on_wall & (frame.depth_mm == 0)
    assert np.mean(dropped[on_wall]) == pytest.approx(0.4, abs=0.01)
    inner = dropped[1:-1, 1:-1]
    all_four = (dropped[:-2, 1:-1] & dropped[2:, 1:-1] & dropped[1:-1, :-2]
                & dropped[1:-1, 2:])
    assert np.mean(all_four[inner]) > 0.8          # pepper at 40 %: 0.4 ** 4 = 0.03
    plain = render(wall_scene(2.0, dark=False), noise=model, seed=11)
    assert not np.any(plain.depth_mm[plain.hit_index == 1] == 0)


def test_default_dropout_rate_is_under_one_percent():
    frame = render(wall_scene(2.0), seed=12)
    inner = frame.hit_index[4:-4, 4:-4] == 1
    fraction = np.mean(frame.depth_mm[4:-4, 4:-4][inner] == 0)
    assert 0.004 < fraction < 0.011


def test_noise_std_at_two_metres():
    frame = render(wall_scene(2.0), seed=13)
    returned = (frame.hit_index == 1) & (frame.depth_mm > 0)
    error_mm = frame.depth_mm[returned].astype(float) - 2000.0
    model = KINECT_V2_NOISE
    expected = (model.depth_sigma_base_mm
                + model.depth_sigma_quad_mm_per_m2 * (2.0 - model.depth_sigma_ref_m) ** 2)
    assert expected == pytest.approx(4.875)
    assert np.std(error_mm) == pytest.approx(expected, rel=0.05)
    assert abs(np.mean(error_mm)) < 0.1


# -- named scenes ------------------------------------------------------------------------------

# Every scene at the Kinect's size; another camera (size and intrinsics) on one scene of each
# kind (with and without obstacles): the scenes share the renderer that takes them.
@pytest.mark.parametrize('name, size, intrinsics', [
    *((name, (512, 424), KINECT_V2_SD) for name in scenes.SCENE_NAMES),
    ('flat_floor', (960, 540), QHD), ('corridor', (960, 540), QHD)])
def test_every_named_scene_renders(name, size, intrinsics):
    frame = render_scene(name, seed=1, size=size, intrinsics=intrinsics)
    width, height = size
    assert frame.depth_mm.shape == (height, width) and frame.depth_mm.dtype == np.uint16
    assert frame.depth_true_m.shape == (height, width)
    assert frame.depth_true_m.dtype == np.float32
    assert frame.labels.shape == (height, width) and frame.labels.dtype == np.uint8
    assert frame.points_ground.shape == (height, width, 3)
    assert frame.points_ground.dtype == np.float32
    np.testing.assert_array_equal(np.isnan(frame.points_ground[..., 0]), frame.hit_index < 0)
    counts = np.bincount(frame.labels.ravel(), minlength=3) / frame.labels.size
    assert counts[GT_TRAVERSABLE] > 0.0
    if name in ('flat_floor', 'pitched_floor'):
        assert counts[GT_OBSTACLE] == 0.0
    else:
        assert counts[GT_OBSTACLE] > 0.01


def test_corridor_has_walls_in_view_and_boxes_ahead():
    frame = render_scene('corridor', noise=False)
    walls = np.isin(frame.hit_index, (1, 2))
    assert frame.depth_true_m[walls].min() < 2.0
    boxes = frame.hit_index >= 3
    x = frame.points_ground[boxes][:, 0]
    assert boxes.sum() > 1000 and x.min() >= 0.7 and x.max() <= 2.2


def test_person_walks_left_to_right():
    centroids = []
    for k in range(0, 50, 10):
        frame = render_scene('person_walking', noise=False, frame_index=k)
        cols = np.nonzero(frame.labels == GT_OBSTACLE)[1]
        person_cols = np.nonzero(frame.hit_index == 2)[1]
        assert person_cols.size > 1000
        centroids.append((cols.mean(), person_cols.mean()))
    obstacle_cols, person = np.array(centroids).T
    assert np.all(np.diff(obstacle_cols) > 0.0)
    assert np.all(np.diff(person) > 10.0)


def test_dark_materials_drop_many_more_pixels():
    frame = render_scene('dark_materials', seed=2)
    dark = np.array([p.dark for p in frame.primitives])[frame.hit_index] & (frame.hit_index >= 0)
    inner = np.zeros(frame.depth_mm.shape, dtype=bool)
    inner[4:-4, 4:-4] = True
    near = (frame.depth_true_m > 0.6) & (frame.depth_true_m < 4.4)
    lost_dark = np.mean(frame.depth_mm[dark & inner & near] == 0)
    lost_plain = np.mean(frame.depth_mm[~dark & inner & near & (frame.hit_index >= 0)] == 0)
    assert lost_dark > 0.3 and lost_plain < 0.02


def test_scene_params_carry_the_mount():
    frame = render_scene('flat_floor', noise=False, height_m=0.9, pitch_rad=0.2, roll_rad=-0.1)
    base = DetectorParams(max_range_m=3.0)
    params = scene_params(frame, base)
    assert (params.camera_height_m, params.camera_pitch_rad, params.camera_roll_rad) == (
        0.9, 0.2, -0.1)
    assert params.max_range_m == 3.0
    assert scene_params(frame).median_kernel == DetectorParams().median_kernel


# -- bad input -------------------------------------------------------------------------------

def test_unknown_scene_name():
    with pytest.raises(ValueError, match="unknown scene 'moon'"):
        render_scene('moon')


@pytest.mark.parametrize('kwargs, match', [
    (dict(seed=-1), 'seed=-1'),
    (dict(size=(0, 424)), r'size=\(0, 424\)'),
    (dict(frame_index=-2), 'frame_index=-2'),
    (dict(height_m=-0.5), 'height_m=-0.5'),
    (dict(pitch_rad=2.0), 'pitch_rad=2.0'),
])
def test_bad_render_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        render_scene('flat_floor', **kwargs)


# -- time-of-flight artefacts (issue 9) -------------------------------------------------------

FLYING_ONLY = NoiseModel(depth_sigma_base_mm=0.0, depth_sigma_quad_mm_per_m2=0.0,
                         dropout_rate=0.0, dark_dropout_rate=0.0, border_px=0,
                         flying_pixel_rate=1.0)


def box_before_wall() -> Scene:
    """Return a box 1.5 m ahead in front of a wall at 3 m: depth edges around the box."""
    return Scene('edges', (Floor(), Wall(3.0, 5.0, 3.0, -5.0, 0.0, 3.0),
                           Box.on_floor(1.5, 0.0, 0.4, 0.4, 0.8)), height_m=HEIGHT_M)


def window_range(depth: np.ndarray, hit: np.ndarray, size: int):
    """Nearest and farthest true depth in each pixel's size x size window (reference loop)."""
    h, w = depth.shape
    r = size // 2
    near = np.full(depth.shape, np.inf)
    far = np.zeros(depth.shape)
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            ys = np.clip(np.arange(h) + dy, 0, h - 1)
            xs = np.clip(np.arange(w) + dx, 0, w - 1)
            d = depth[np.ix_(ys, xs)]
            ok = hit[np.ix_(ys, xs)]
            near = np.minimum(near, np.where(ok, d, np.inf))
            far = np.maximum(far, np.where(ok, d, 0.0))
    return near, far


def test_flying_pixels_lie_between_foreground_and_background_at_edges_only():
    frame = render(box_before_wall(), noise=FLYING_ONLY, seed=3)
    true = frame.depth_true_m.astype(np.float64)
    hit = frame.hit_index >= 0
    near, far = window_range(true, hit, 5)
    measured = frame.depth_mm.astype(np.float64) * 1e-3
    flying = frame.flying
    assert flying.sum() > 200
    # between the nearest and farthest surface of its window, mostly off its own surface
    assert np.all(measured[flying] >= near[flying] - 1e-3)
    assert np.all(measured[flying] <= far[flying] + 1e-3)
    assert np.median(np.abs(measured[flying] - true[flying])) > 0.05
    # only where a depth edge is within 2 px (jump above 5 cm and 8 % of the near depth)
    edge = far - near > np.maximum(0.05, 0.08 * near)
    assert np.all(edge[flying])
    # the box's silhouette against the wall 1.5 m behind: every pixel next to it flies
    near3, far3 = window_range(true, hit, 3)
    ring1 = hit & (far3 - near3 > 1.0)
    assert ring1.sum() > 100 and np.all(flying[ring1])
    # elsewhere the depth is exact, and flying pixels are not scored
    np.testing.assert_allclose(measured[~flying & hit], true[~flying & hit], atol=6e-4)
    assert np.all(frame.labels[flying] == GT_NO_RETURN)
    assert np.all(frame.hit_labels[flying] != GT_NO_RETURN)


def test_flying_pixels_are_deterministic_per_seed_and_frame_and_about_half_next_to_edges():
    model = KINECT_V2_TOF_NOISE
    a = render(box_before_wall(), noise=model, seed=5, frame_index=2)
    b = render(box_before_wall(), noise=model, seed=5, frame_index=2)
    c = render(box_before_wall(), noise=model, seed=5, frame_index=3)
    np.testing.assert_array_equal(a.flying, b.flying)
    np.testing.assert_array_equal(a.depth_mm, b.depth_mm)
    assert (a.flying != c.flying).any()
    near, far = window_range(a.depth_true_m.astype(np.float64), a.hit_index >= 0, 3)
    ring1 = (a.hit_index >= 0) & (far - near > 1.0) & (a.depth_mm > 0)
    assert 0.4 < a.flying[ring1].mean() < 0.6


def test_dark_surfaces_are_noisier():
    model = NoiseModel(dropout_rate=0.0, dark_dropout_rate=0.0, dark_sigma_factor=2.0)
    spreads = []
    for dark in (False, True):
        frame = render(wall_scene(2.0, dark=dark), noise=model, seed=1)
        on_wall = (frame.hit_index == 1) & (frame.depth_mm > 0)
        spreads.append(np.std(frame.depth_mm[on_wall] * 1e-3 - frame.depth_true_m[on_wall]))
    assert spreads[1] == pytest.approx(2.0 * spreads[0], rel=0.05)


def test_far_surfaces_drop_more_returns():
    model = NoiseModel(depth_sigma_base_mm=0.0, depth_sigma_quad_mm_per_m2=0.0,
                       dropout_rate=0.0075, far_dropout_rate=0.1, border_px=0)
    lost = []
    for distance in (2.0, 4.4):
        frame = render(wall_scene(distance), noise=model, seed=2)
        lost.append(np.mean(frame.depth_mm[frame.hit_index == 1] == 0))
    assert lost[0] == pytest.approx(0.0075, abs=0.002)
    expected = 0.0075 + 0.1 * (4.4 - 3.0) / 1.5
    assert lost[1] == pytest.approx(expected, abs=0.01)


def test_default_noise_has_no_time_of_flight_artefacts():
    frame = render(box_before_wall(), seed=3)
    assert not frame.flying.any()
    frame = render(box_before_wall(), noise=NOISE_MODELS['kinect_v2_tof'], seed=3)
    assert frame.flying.any()
