"""The frame gate shared by the node and bag_process: each refusal and the fallback note."""

from __future__ import annotations

import dataclasses

import numpy as np
from builtin_interfaces.msg import Time

from obstacle_detection.pipeline.params import KINECT_V2_SD, KINECT_V2_SD_SIZE, Intrinsics
from obstacle_detection.ros import frame_gate
from obstacle_detection.ros.conversions import array_to_image, intrinsics_to_camera_info

WIDTH, HEIGHT = KINECT_V2_SD_SIZE
STAMP = Time(sec=3, nanosec=5)


def _camera(width: int = WIDTH, height: int = HEIGHT,
            intrinsics: Intrinsics = KINECT_V2_SD) -> frame_gate.CameraState:
    info = intrinsics_to_camera_info(intrinsics, width, height, stamp=STAMP, frame_id='cam')
    return frame_gate.CameraState.from_camera_info(info)


def _choose(camera: frame_gate.CameraState | None, *, use_fallback: bool = False,
            shape: tuple[int, int] = (HEIGHT, WIDTH)) -> frame_gate.Verdict:
    return frame_gate.choose_intrinsics(camera, shape, use_fallback=use_fallback,
                                        fallback=Intrinsics(100.0, 101.0, 50.0, 40.0),
                                        no_camera='none here')


def test_decode_returns_the_depth_of_a_raw_image() -> None:
    depth = np.arange(12, dtype=np.uint16).reshape(3, 4)
    decoded = frame_gate.decode(array_to_image(depth, stamp=STAMP, frame_id='cam'))
    assert isinstance(decoded, np.ndarray)
    np.testing.assert_array_equal(decoded, depth)


def test_decode_views_the_message_pixels_when_no_copy_is_needed() -> None:
    depth = np.arange(12, dtype=np.uint16).reshape(3, 4)
    msg = array_to_image(depth, stamp=STAMP, frame_id='cam')
    view = frame_gate.decode(msg)
    assert np.shares_memory(view, np.frombuffer(msg.data, np.uint8))   # no copy in the node
    big = array_to_image(depth, stamp=STAMP, frame_id='cam')
    big.is_bigendian = 1
    big.data = depth.astype('>u2').tobytes()
    swapped = frame_gate.decode(big)
    np.testing.assert_array_equal(swapped, depth)                         # swapped: a copy
    assert not np.shares_memory(swapped, np.frombuffer(big.data, np.uint8))


def test_decode_refuses_a_colour_encoding() -> None:
    colour = array_to_image(np.zeros((3, 4, 3), np.uint8), stamp=STAMP, frame_id='cam',
                            encoding='rgb8')
    skip = frame_gate.decode(colour)
    assert isinstance(skip, frame_gate.Skip)
    assert skip.kind.startswith('image:') and "unsupported depth encoding 'rgb8'" in skip.reason


def test_camera_info_gives_its_intrinsics_at_its_size() -> None:
    camera = _camera()
    assert camera.intrinsics == KINECT_V2_SD and camera.error is None
    assert camera.stamp_ns == 3_000_000_005
    verdict = _choose(camera)
    assert verdict.intrinsics == KINECT_V2_SD and verdict.skip is None and verdict.note is None


def test_a_frame_of_another_size_than_its_camera_info_is_skipped() -> None:
    verdict = _choose(_camera(), shape=(HEIGHT // 2, WIDTH // 2))
    assert verdict.intrinsics is None and verdict.skip.kind == 'size'
    assert verdict.skip.reason == (f'image is {WIDTH // 2}x{HEIGHT // 2} but CameraInfo is '
                                   f'{WIDTH}x{HEIGHT}')


def test_an_implausible_camera_info_is_refused_with_its_problem() -> None:
    camera = _camera(intrinsics=Intrinsics(1e9, 1e9, 256.0, 212.0))  # field of view ~0 deg
    assert camera.intrinsics is None and camera.error
    verdict = _choose(camera)
    assert verdict.intrinsics is None and verdict.skip.reason == camera.error
    assert verdict.skip.kind.startswith('camera_info:')


def test_without_camera_info_the_fallback_is_used_and_said() -> None:
    verdict = _choose(None, use_fallback=True)
    assert verdict.intrinsics == Intrinsics(100.0, 101.0, 50.0, 40.0)
    assert verdict.note == ('no CameraInfo yet: using the fallback intrinsics fx=100 fy=101 '
                            'cx=50 cy=40')
    refused = _choose(None, use_fallback=False)
    assert refused.intrinsics is None and refused.note is None
    assert refused.skip == frame_gate.Skip('no_camera_info', 'none here')


def test_check_depth_refuses_a_frame_without_valid_depth() -> None:
    msg = array_to_image(np.zeros((4, 4), np.float32), stamp=STAMP, frame_id='cam')
    nan = np.full((4, 4), np.nan, np.float32)
    assert frame_gate.check_depth(nan, msg).kind == 'no_depth'
    assert frame_gate.check_depth(np.zeros((4, 4), np.uint16), msg).kind == 'no_depth'
    good = np.full((4, 4), 1.5, np.float32)
    assert frame_gate.check_depth(good, msg) is None
    lone = np.zeros((9, 9), np.uint16)
    lone[5, 7] = 1500                  # off the every-4th-pixel sample: the whole frame counts
    assert frame_gate.check_depth(lone, msg) is None


def test_problem_kind_ignores_the_numbers() -> None:
    assert frame_gate.problem_kind('depth', 'median 1500.0 m is implausible') == \
        frame_gate.problem_kind('depth', 'median 2.5e3 m is implausible')


def test_gate_and_bag_process_load_without_rclpy_or_the_node() -> None:
    import subprocess
    import sys

    probe = ('import sys, obstacle_detection.ros.frame_gate, obstacle_detection.ros.config; '
             "print('rclpy' in sys.modules); "
             'import obstacle_detection.tools.bag_process; '
             "print('obstacle_detection.ros.node' in sys.modules, 'rclpy.node' in sys.modules)")
    done = subprocess.run([sys.executable, '-c', probe], capture_output=True, text=True,
                          timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ['False', 'False', 'False']


def test_a_camera_info_read_from_k_says_so_and_one_read_from_p_does_not() -> None:
    info = intrinsics_to_camera_info(KINECT_V2_SD, WIDTH, HEIGHT, stamp=STAMP, frame_id='cam')
    info.p = [360.0, 0.0, 250.0, 0.0, 0.0, 362.0, 209.0, 0.0, 0.0, 0.0, 1.0, 0.0]
    from_p = frame_gate.CameraState.from_camera_info(info)
    info.p = [0.0] * 12
    from_k = frame_gate.CameraState.from_camera_info(info)

    assert from_p.intrinsics == Intrinsics(360.0, 362.0, 250.0, 209.0) and from_p.note is None
    assert from_k.intrinsics == KINECT_V2_SD and 'P is all zero' in from_k.note


def _stamped(camera: frame_gate.CameraState, stamp_s: float) -> frame_gate.CameraState:
    return dataclasses.replace(camera, stamp_ns=round(stamp_s * 1e9))


def test_a_frame_takes_the_camera_info_nearest_its_stamp_not_the_latest() -> None:
    other = Intrinsics(300.0, 300.0, 250.0, 200.0)
    a, b = _stamped(_camera(), 1.00), _stamped(_camera(intrinsics=other), 1.10)
    tolerance = 20_000_000
    assert frame_gate.camera_for([a, b], round(1.005e9), tolerance) is a
    assert frame_gate.camera_for([a, b], round(1.095e9), tolerance) is b
    assert frame_gate.camera_for([], round(1.0e9), tolerance) is None
    skip = frame_gate.camera_for([a, b], round(1.5e9), tolerance)   # far from both, they differ
    assert isinstance(skip, frame_gate.Skip) and 'disagree' in skip.reason
    same = [_stamped(_camera(), 1.0), _stamped(_camera(), 1.2)]    # one camera: the newest
    assert frame_gate.camera_for(same, round(5.0e9), tolerance) is same[-1]


def test_bag_process_pairs_a_frame_with_its_camera_info_as_the_node_does() -> None:
    from obstacle_detection.cli import bag_processor
    from obstacle_detection.ros.config import build_config
    from obstacle_detection.ros.parameters import ALL_PARAMS

    config = build_config({spec.name: spec.default for spec in ALL_PARAMS})
    depth = array_to_image(np.full((HEIGHT, WIDTH), 1500, np.uint16), stamp=Time(sec=1),
                           frame_id='cam')
    right = _stamped(_camera(), 1.0)
    later = _stamped(_camera(width=WIDTH // 2, height=HEIGHT // 2), 1.1)   # the latest, wrong
    messages, result, reason, _ = bag_processor.process_frame(
        depth, [right, later], config, with_ground=False, with_overlay=False)
    assert reason == '' and result.intrinsics == KINECT_V2_SD
    _, _, reason, _ = bag_processor.process_frame(
        depth, [later], config, with_ground=False, with_overlay=False)
    assert reason == f'image is {WIDTH}x{HEIGHT} but CameraInfo is {WIDTH // 2}x{HEIGHT // 2}'
