"""Scene sequences: rendering from a robot pose, trajectories, odometry, ground truth."""

import math

import numpy as np
import pytest

from obstacle_detection.evaluation.camera import scaled_intrinsics
from obstacle_detection.labels import GT_NO_RETURN, GT_OBSTACLE
from obstacle_detection.pipeline.params import KINECT_V2_SD
from obstacle_detection.sim.primitives import Box, Floor
from obstacle_detection.sim.render import render, Scene
from obstacle_detection.sim.sequences import (PERFECT_ODOMETRY, SEQUENCE_NAMES, BodyPitch,
                                          OdometryModel, SceneSequence, edge_person_y_at,
                                          odometry_poses, person_y_at)

SMALL = (128, 106)
SMALL_K = scaled_intrinsics(KINECT_V2_SD, 128 / 512)
CABINET_FRONT_X_M = 2.0375


def small_frame(sequence: SceneSequence, index: int, noise: bool = False):
    return sequence.frame(index, noise=noise, intrinsics=SMALL_K, size=SMALL)


def test_render_from_a_pose_sees_the_scene_moved_into_the_base_frame():
    # a box 1.5 m ahead and 0.2 m left of a robot at (0.5, -0.3) turned 90 deg left
    pose = (0.5, -0.3, math.pi / 2)
    in_base = Scene('base', (Floor(), Box.on_floor(1.5, 0.2, 0.3, 0.5, 0.4)))
    in_world = Scene('world', (Floor(), Box.on_floor(0.5 - 0.2, -0.3 + 1.5, 0.5, 0.3, 0.4)))
    a = render(in_base, noise=False, intrinsics=SMALL_K, size=SMALL)
    b = render(in_world, noise=False, intrinsics=SMALL_K, size=SMALL, pose=pose)
    assert np.abs(a.depth_mm.astype(int) - b.depth_mm.astype(int)).max() <= 1
    assert np.mean(a.labels != b.labels) < 0.002
    assert (a.labels == GT_OBSTACLE).sum() > 100
    both = np.isfinite(a.points_ground).all(axis=2) & np.isfinite(b.points_ground).all(axis=2)
    np.testing.assert_allclose(a.points_ground[both], b.points_ground[both], atol=2e-4)


def test_drive_trajectory_follows_its_velocity_profile():
    seq = SceneSequence('drive_past_boxes', odometry=PERFECT_ODOMETRY)
    # 0.5 s still, 3.3 s at 0.5 m/s, 0.5 s still, 2 s turning at 45 deg/s, 3 s, 0.5 s: 9.8 s
    assert len(seq) == 295 and seq.rate_hz == 30.0
    np.testing.assert_allclose(seq.pose_true(15), (0.0, 0.0, 0.0), atol=1e-12)
    np.testing.assert_allclose(seq.pose_true(45), (0.5, 0.0, 0.0), atol=1e-12)
    np.testing.assert_allclose(seq.pose_true(114), (1.65, 0.0, 0.0), atol=1e-12)
    np.testing.assert_allclose(seq.pose_true(129), (1.65, 0.0, 0.0), atol=1e-12)
    np.testing.assert_allclose(seq.pose_true(159), (1.65, 0.0, math.pi / 4), atol=1e-12)
    np.testing.assert_allclose(seq.pose_true(189), (1.65, 0.0, math.pi / 2), atol=1e-12)
    np.testing.assert_allclose(seq.pose_true(294), (1.65, 1.5, math.pi / 2), atol=1e-9)
    assert seq.pose_odom(294) == seq.pose_true(294)          # perfect odometry


def test_the_robot_stops_inside_the_blind_zone_of_the_cabinet():
    seq = SceneSequence('drive_past_boxes')
    assert CABINET_FRONT_X_M - seq.pose_true(120)[0] == pytest.approx(0.3875)
    cabinet = 1   # index of the cabinet in the world's primitives
    far, near = small_frame(seq, 60), small_frame(seq, 120)
    seen_far = (far.frame.hit_index == cabinet) & (far.frame.labels != GT_NO_RETURN)
    seen_near = (near.frame.hit_index == cabinet) & (near.frame.labels != GT_NO_RETURN)
    assert seen_far.sum() > 200
    assert (near.frame.hit_index == cabinet).sum() > 1000    # it fills the view...
    assert seen_near.sum() == 0                               # ...and returns nothing
    # the truth is in the base frame: the cabinet face 2.0375 - 1.0 m ahead at frame 60
    face = far.frame.points_ground[seen_far]
    front = face[np.abs(face[:, 0] - np.min(face[:, 0])) < 0.01]
    np.testing.assert_allclose(front[:, 0], CABINET_FRONT_X_M - seq.pose_true(60)[0],
                               atol=1e-4)


def test_odometry_drifts_like_its_model():
    true = np.array([[0.1 * i, 0.0, 0.0] for i in range(11)])           # 1 m straight
    scaled = odometry_poses(true, OdometryModel(0.1, 0.0, 0.0), seed=0)
    np.testing.assert_allclose(scaled[-1], (1.1, 0.0, 0.0), atol=1e-12)
    turn = np.array([[0.0, 0.0, math.radians(9.0 * i)] for i in range(11)])   # 90 deg on the spot
    turned = odometry_poses(turn, OdometryModel(0.0, -0.1, 0.0), seed=0)
    np.testing.assert_allclose(turned[-1], (0.0, 0.0, math.radians(81.0)), atol=1e-12)
    seq = SceneSequence('drive_past_boxes')
    error = math.dist(seq.pose_odom(294)[:2], seq.pose_true(294)[:2])
    assert 0.01 < error < 0.1                                 # 2 % of 3.15 m, and noise
    still = SceneSequence('person_crossing')
    assert all(still.pose_odom(i) == (0.0, 0.0, 0.0) for i in range(len(still)))


def test_the_person_walks_in_stops_and_leaves():
    assert person_y_at(0.0) == pytest.approx(1.9)
    assert person_y_at(1.9) == pytest.approx(0.0)
    assert person_y_at(2.5) == 0.0 and person_y_at(2.9) == 0.0
    assert person_y_at(3.9) == pytest.approx(-1.0)
    assert person_y_at(10.0) == pytest.approx(-2.1)
    seq = SceneSequence('person_crossing')
    person = len(seq.scene_at(0).primitives) - 1
    standing = small_frame(seq, 75)                           # t = 2.5 s
    hit = (standing.frame.hit_index == person) & (standing.frame.labels == GT_OBSTACLE)
    points = standing.frame.points_ground[hit]
    assert hit.sum() > 100
    assert np.abs(np.median(points[:, 1])) < 0.05 and 1.35 < np.median(points[:, 0]) < 1.45
    gone = small_frame(seq, len(seq) - 1)
    assert not (gone.frame.hit_index == person).any()


def test_frames_are_seeded_and_carry_stamps():
    seq = SceneSequence('person_crossing', seed=3)
    a, b = small_frame(seq, 10, noise=True), small_frame(seq, 10, noise=True)
    np.testing.assert_array_equal(a.frame.depth_mm, b.frame.depth_mm)
    assert a.stamp_s == pytest.approx(10 / 30) and a.index == 10
    other = SceneSequence('person_crossing', seed=4)
    assert not np.array_equal(small_frame(other, 10, noise=True).frame.depth_mm,
                              a.frame.depth_mm)


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError, match='unknown sequence .*drive_past_boxes'):
        SceneSequence('parking_lot')
    assert set(SEQUENCE_NAMES) == {'drive_past_boxes', 'person_crossing', 'drive_by_table',
                                   'person_leaving_edge'}
    seq = SceneSequence('person_crossing')
    with pytest.raises(ValueError, match='frame index 177'):
        seq.pose_true(177)
    with pytest.raises(ValueError, match='seed'):
        SceneSequence('person_crossing', seed=-1)


def test_the_held_out_person_stops_near_the_edge_of_the_view_and_leaves_on_that_side():
    assert edge_person_y_at(0.0) == pytest.approx(-1.6)
    assert edge_person_y_at(2.0) == pytest.approx(0.9) and edge_person_y_at(2.8) == 0.9
    assert edge_person_y_at(10.0) == pytest.approx(2.2)
    seq = SceneSequence('person_leaving_edge')
    person = len(seq.scene_at(0).primitives) - 1
    standing = small_frame(seq, 75)
    hit = standing.frame.hit_index == person
    bearing = np.degrees(np.arctan2(standing.frame.points_ground[hit][:, 1],
                                    standing.frame.points_ground[hit][:, 0]))
    assert hit.sum() > 100 and 20.0 < np.median(bearing) < 30.0
    assert not (small_frame(seq, len(seq) - 1).frame.hit_index == person).any()


def test_the_body_pitch_moves_the_camera_but_not_the_truth_in_base_footprint():
    level = SceneSequence('drive_by_table', odometry=PERFECT_ODOMETRY)
    rocking = SceneSequence('drive_by_table', odometry=PERFECT_ODOMETRY,
                            body_pitch=BodyPitch(amplitude_deg=2.0, period_s=1.2,
                                                 phase_deg=90.0))
    assert rocking.body_pitch_rad(0) == pytest.approx(math.radians(2.0))
    assert rocking.body_pitch_rad(18) == pytest.approx(math.radians(-2.0))   # half a period
    a, b = small_frame(level, 0), small_frame(rocking, 0)
    assert b.frame.pitch_rad == pytest.approx(math.radians(2.0))
    assert b.frame.height_m == pytest.approx(0.6 * math.cos(math.radians(2.0)))
    assert b.pose_true == a.pose_true and b.pose_odom == a.pose_odom
    assert np.mean(a.frame.depth_mm != b.frame.depth_mm) > 0.5      # another view
    # the same world in base_footprint: floor at z = 0, box_right's front face where it is
    for f in (a, b):
        pts, names = f.frame.points_ground, f.frame.object_names
        floor = f.frame.hit_index == 0
        assert np.abs(pts[floor][:, 2]).max() < 1e-4
        box = f.frame.hit_index == names.index('box_right')
        assert np.percentile(pts[box][:, 0], 1) == pytest.approx(0.9625, abs=2e-3)
