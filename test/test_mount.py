"""Camera mount from the floor plane: recovery on ray-cast scenes, failures, the CLI."""

import math

import cv2
import numpy as np
import pytest

from obstacle_detection.labels import CELL_OCCUPIED, LABEL_GROUND, LABEL_OBSTACLE
from obstacle_detection.evaluation import runner as evaluation
from obstacle_detection.pipeline import geometry, mount
from obstacle_detection.cli import support as tool_support
from obstacle_detection.pipeline.params import KINECT_V2_SD, Intrinsics, table_4_2
from obstacle_detection.evaluation.datasets import read_depth_png
from obstacle_detection.pipeline.detector import Detector
from obstacle_detection.sim.primitives import Box, Floor, Wall
from obstacle_detection.sim.render import render, Scene
from obstacle_detection.sim.scenes import render_scene
from obstacle_detection.tools import estimate_mount as tool

#: Recovery tolerances on noisy Kinect-v2-like frames (measured errors are below 1 mm and
#: 0.05 deg; these leave room for noise, not for a wrong convention or plane).
HEIGHT_TOL_M = 0.01
ANGLE_TOL_DEG = 0.5
#: Intrinsics of the 10 x 10 frames of the argument checks.
SMALL = Intrinsics(365.0, 365.0, 5.0, 5.0)


def depth_m(frame) -> np.ndarray:
    """Return the rendered frame's measured depth [m], float32, 0 = no return."""
    return frame.depth_mm * np.float32(1e-3)


def assert_mount(estimate, height_m, pitch_rad, roll_rad):
    assert estimate.height_m == pytest.approx(height_m, abs=HEIGHT_TOL_M)
    assert estimate.pitch_deg == pytest.approx(math.degrees(pitch_rad), abs=ANGLE_TOL_DEG)
    assert estimate.roll_deg == pytest.approx(math.degrees(roll_rad), abs=ANGLE_TOL_DEG)


@pytest.mark.parametrize('pitch_deg, roll_deg', [(0.0, 0.0), (30.0, 10.0), (-10.0, -15.0),
                                                 (60.0, -5.0)])
def test_mount_from_plane_inverts_the_mount_rotation(pitch_deg, roll_deg):
    pitch, roll = math.radians(pitch_deg), math.radians(roll_deg)
    normal = geometry.mount_rotation(pitch, roll)[2]   # the floor's up, optical frame
    height, pitch_back, roll_back = mount.mount_from_plane(2.0 * normal, 2.0 * 0.7)
    assert (height, pitch_back, roll_back) == pytest.approx((0.7, pitch, roll), abs=1e-12)


@pytest.mark.parametrize('scene, height_m, pitch_deg, roll_deg', [
    ('flat_floor', 0.3, 0.0, 0.0),
    ('flat_floor', 1.2, 45.0, 10.0),
    ('corridor', 0.6, 15.0, -10.0),
    ('corridor', 1.0, 30.0, 4.0),
    ('people', 0.8, 5.0, 7.0),
    ('people', 0.45, 40.0, -3.0),
])
def test_recovers_the_mount_of_a_rendered_scene(scene, height_m, pitch_deg, roll_deg):
    pitch, roll = math.radians(pitch_deg), math.radians(roll_deg)
    frame = render_scene(scene, seed=1, height_m=height_m, pitch_rad=pitch, roll_rad=roll)
    estimate = mount.estimate_mount(depth_m(frame), frame.intrinsics)
    assert_mount(estimate, height_m, pitch, roll)
    floor = frame.hit_index == 0
    assert estimate.inlier_fraction == pytest.approx(
        np.count_nonzero(floor & (frame.depth_mm > 0) & (depth_m(frame) <= 4.0))
        / estimate.n_points, abs=0.02)


def test_the_same_frame_gives_the_same_estimate():
    frame = render_scene('corridor', seed=2, height_m=0.7, pitch_rad=0.3)
    assert mount.estimate_mount(depth_m(frame), frame.intrinsics) == \
        mount.estimate_mount(depth_m(frame), frame.intrinsics)


def test_a_table_top_filling_most_of_the_view_is_not_the_floor():
    # a 2.4 x 2.1 m table top 0.75 m high seen from 1.2 m: 86 % of the points are on it, the
    # floor shows only in front of it (8 %), and a box stands under it
    scene = Scene('table', (Floor(), Box((0.5, -1.2, 0.7), (2.6, 1.2, 0.75)),
                            Box.on_floor(0.8, 0.5, 0.3, 0.3, 0.4)),
                  height_m=1.2, pitch_rad=math.radians(20.0), roll_rad=math.radians(-5.0))
    frame = render(scene, seed=3)
    valid = frame.depth_mm > 0
    assert np.mean(frame.hit_index[valid] == 1) > 0.8
    estimate = mount.estimate_mount(depth_m(frame), frame.intrinsics)
    assert_mount(estimate, 1.2, scene.pitch_rad, scene.roll_rad)


def test_a_wall_filling_the_view_has_no_floor():
    scene = Scene('wall', (Wall(1.0, 5.0, 1.0, -5.0, -5.0, 5.0),), height_m=0.6)
    frame = render(scene, seed=0)
    with pytest.raises(ValueError, match='no plausible floor'):
        mount.estimate_mount(depth_m(frame), frame.intrinsics)


def test_a_frame_without_depth_has_too_few_points():
    with pytest.raises(ValueError, match='too few points'):
        mount.estimate_mount(np.zeros((424, 512), np.float32), KINECT_V2_SD)


def test_a_steep_camera_needs_the_prior_pitch():
    frame = render_scene('flat_floor', height_m=0.5, pitch_rad=math.radians(70.0))
    with pytest.raises(ValueError, match='prior_pitch_rad'):
        mount.estimate_mount(depth_m(frame), frame.intrinsics)
    estimate = mount.estimate_mount(depth_m(frame), frame.intrinsics,
                                    prior_pitch_rad=math.radians(65.0))
    assert_mount(estimate, 0.5, math.radians(70.0), 0.0)


@pytest.mark.parametrize('kwargs, match', [
    ({'max_range_m': float('nan')}, 'max_range_m'),
    ({'max_range_m': 0.0}, 'max_range_m'),
    ({'prior_pitch_rad': 2.0}, 'prior_pitch_rad'),
])
def test_bad_arguments_are_named(kwargs, match):
    depth = np.ones((10, 10), np.float32)
    with pytest.raises(ValueError, match=match):
        mount.estimate_mount(depth, SMALL, **kwargs)


def test_with_the_estimated_mount_the_pipeline_sees_only_ground():
    pitch, roll = math.radians(35.0), math.radians(6.0)
    frame = render_scene('flat_floor', seed=4, height_m=0.9, pitch_rad=pitch, roll_rad=roll)
    estimate = mount.estimate_mount(depth_m(frame), frame.intrinsics)
    params = table_4_2(median_kernel=5, camera_height_m=estimate.height_m,
                       camera_pitch_rad=estimate.pitch_rad, camera_roll_rad=estimate.roll_rad)
    result = Detector(params).process(frame.depth_mm, frame.intrinsics)
    assert np.count_nonzero(result.labels == LABEL_GROUND) > 10_000
    assert not (result.labels == LABEL_OBSTACLE).any()
    assert not (result.costmap.data == CELL_OCCUPIED).any()
    # the check has teeth: the level default mount sees the 35 deg floor as a slope
    wrong = Detector(params.replace(camera_height_m=0.9, camera_pitch_rad=0.0,
                                    camera_roll_rad=0.0)).process(frame.depth_mm,
                                                                  frame.intrinsics)
    assert (wrong.costmap.data == CELL_OCCUPIED).any()


# -- tools/estimate_mount.py -------------------------------------------------------------------

@pytest.fixture(scope='module')
def tilted_frame():
    return render_scene('people', seed=2, height_m=0.75, pitch_rad=math.radians(20.0),
                        roll_rad=math.radians(-4.0))


def write_big_endian_pgm(path, depth):
    height, width = depth.shape
    path.write_bytes(f'P5 {width} {height} 65535\n'.encode() + depth.astype('>u2').tobytes())


def intrinsics_arg(intr):
    return f'{intr.fx},{intr.fy},{intr.cx},{intr.cy}'


def test_opencv_reads_a_16_bit_pgm_big_endian(tmp_path, tilted_frame):
    path = tmp_path / 'depth.pgm'
    write_big_endian_pgm(path, tilted_frame.depth_mm)
    np.testing.assert_array_equal(read_depth_png(path), tilted_frame.depth_mm)


@pytest.mark.parametrize('suffix, scale', [('png', 5000.0), ('pgm', 1000.0)])
def test_cli_prints_the_mount_and_writes_a_params_file(tmp_path, capsys, tilted_frame,
                                                       suffix, scale):
    depth_units = np.round(tilted_frame.depth_mm.astype(np.float64) * scale / 1000.0)
    depth_units = depth_units.astype(np.uint16)
    path = tmp_path / f'depth.{suffix}'
    if suffix == 'png':
        assert cv2.imwrite(str(path), depth_units)
    else:
        write_big_endian_pgm(path, depth_units)
    params_out = tmp_path / 'mount.yaml'
    assert tool.main(['--depth', str(path), '--depth-scale', str(scale),
                      '--intrinsics', intrinsics_arg(tilted_frame.intrinsics),
                      '--params-out', str(params_out)]) == 0
    out = capsys.readouterr().out
    assert 'height 0.75' in out and 'pitch 20.0' in out and 'roll -4.0' in out
    assert out.endswith(f'wrote {params_out}\n')
    params = evaluation.load_params_file(params_out)
    assert (params.camera_height_m, math.degrees(params.camera_pitch_rad),
            math.degrees(params.camera_roll_rad)) == pytest.approx((0.75, 20.0, -4.0), abs=0.02)


def test_cli_reports_a_missing_floor(tmp_path, capsys):
    scene = Scene('wall', (Wall(1.0, 5.0, 1.0, -5.0, -5.0, 5.0),), height_m=0.6)
    frame = render(scene, seed=0)
    path = tmp_path / 'wall.png'
    cv2.imwrite(str(path), frame.depth_mm)
    assert tool.main(['--depth', str(path), '--intrinsics',
                      intrinsics_arg(frame.intrinsics)]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f'error: {path}: cannot estimate the mount: no plausible floor')
    assert err.count('\n') == 1


def test_cli_refuses_an_8_bit_image(tmp_path, capsys):
    path = tmp_path / 'colour.png'
    cv2.imwrite(str(path), np.zeros((8, 8, 3), np.uint8))
    assert tool.main(['--depth', str(path), '--intrinsics', '1,1,4,4']) == 1
    assert '16-bit single channel' in capsys.readouterr().err


def test_cli_says_when_the_depth_looks_like_another_unit(tmp_path, capsys, tilted_frame):
    # the frame in TUM units (5000 per metre) read as millimetres: 5 times too deep
    tum = np.round(tilted_frame.depth_mm.astype(np.float64) * 5.0).astype(np.uint16)
    path = tmp_path / 'tum.png'
    assert cv2.imwrite(str(path), tum)
    argv = ['--depth', str(path), '--intrinsics', intrinsics_arg(tilted_frame.intrinsics)]
    assert tool.main(argv) == 1
    err = capsys.readouterr().err
    assert err.startswith(f'error: {path}: cannot estimate the mount: too few points')
    median_mm = float(np.median(tilted_frame.depth_mm[tilted_frame.depth_mm > 0]))
    assert '--depth-scale 5000 (TUM RGB-D format, 0.2 mm)' in err
    assert f'{median_mm / 1000:.2f} m' in err  # the median at the suggested scale
    # with the suggested scale it works
    assert tool.main([*argv, '--depth-scale', '5000']) == 0
    assert 'height 0.75' in capsys.readouterr().out


def test_unit_warning_names_the_scale_that_fits():
    metres = np.full((4, 4), 2.5)
    assert tool_support.depth_unit_warning((metres * 1000).astype(np.uint16), 1000) is None
    text = tool_support.depth_unit_warning((metres * 5000).astype(np.uint16), None)
    assert 'its median is 12.50 m' in text and '--depth-scale 5000' in text and '2.50 m' in text
    text = tool_support.depth_unit_warning((metres * 1000).astype(np.uint16), 10000)
    assert 'its median is 0.25 m, below' in text and '--depth-scale 1000' in text
    # plausible, but nothing within the range a caller needs: another scale is suggested
    far = (np.full((4, 4), 1.5) * 5000).astype(np.uint16)
    assert tool_support.depth_unit_warning(far, 1000) is None
    text = tool_support.depth_unit_warning(far, 1000, out_of_range_m=4.0)
    assert 'little of it lies within 4 m' in text and 'would make its median 1.50 m' in text
    assert tool_support.depth_unit_warning(metres.astype(np.float32), 1000) is None


def test_cli_rejects_a_bad_depth_scale_as_usage(capsys):
    assert tool.main(['--depth', 'x.png', '--intrinsics', '1,1,4,4', '--depth-scale', '0']) == 2
    assert capsys.readouterr().err.startswith('estimate_mount: error: argument --depth-scale')


def test_cli_rejects_malformed_intrinsics(capsys):
    with pytest.raises(SystemExit):
        tool.main(['--depth', 'x.png', '--intrinsics', '1,2,3'])
    assert 'fx,fy,cx,cy' in capsys.readouterr().err
