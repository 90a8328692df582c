"""Tests of the camera mount from TF (obstacle_detection.ros.mount_source) with a tf2 stand-in."""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from obstacle_detection.pipeline.geometry import OPTICAL_TO_BODY, mount_rotation, quaternion_matrix
from obstacle_detection.ros.mount_source import (
    Mount,
    MountSource,
    StaticTransforms,
    mount_from_transform,
)


def _rz(a: float) -> np.ndarray:
    return np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])


def _quaternion(rotation: np.ndarray) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation matrix (w > 0 branch; fine for these test angles)."""
    w = math.sqrt(1.0 + np.trace(rotation)) / 2.0
    return ((rotation[2, 1] - rotation[1, 2]) / (4 * w),
            (rotation[0, 2] - rotation[2, 0]) / (4 * w),
            (rotation[1, 0] - rotation[0, 1]) / (4 * w), w)


def _transform(mount_rotation_matrix: np.ndarray, xyz: tuple[float, float, float]) -> Any:
    x, y, z, w = _quaternion(mount_rotation_matrix)
    return SimpleNamespace(transform=SimpleNamespace(
        translation=SimpleNamespace(x=xyz[0], y=xyz[1], z=xyz[2]),
        rotation=SimpleNamespace(x=x, y=y, z=z, w=w)))


def test_a_level_forward_camera_is_the_optical_to_body_rotation() -> None:
    mount = mount_from_transform(_transform(OPTICAL_TO_BODY, (0.2, 0.1, 0.6)))
    assert mount == Mount(0.2, 0.1, 0.6, 0.0, 0.0, 0.0)


@pytest.mark.parametrize('yaw_deg, pitch_deg, roll_deg', [
    (10.0, 0.0, 0.0), (0.0, 20.0, 0.0), (0.0, 0.0, -3.0), (10.0, 25.0, 3.0), (-90.0, 5.0, 1.0)])
def test_angles_come_back_in_the_pipelines_convention(yaw_deg: float, pitch_deg: float,
                                                      roll_deg: float) -> None:
    yaw, pitch, roll = map(math.radians, (yaw_deg, pitch_deg, roll_deg))
    rotation = _rz(yaw) @ mount_rotation(pitch, roll)     # the pipeline's pitch and roll
    mount = mount_from_transform(_transform(rotation, (0.2, 0.1, 0.6)))
    assert (mount.yaw_rad, mount.pitch_rad, mount.roll_rad) == pytest.approx(
        (yaw, pitch, roll), abs=1e-9)
    assert (mount.x_m, mount.y_m, mount.z_m) == pytest.approx((0.2, 0.1, 0.6))


def test_a_zero_quaternion_is_refused() -> None:
    with pytest.raises(ValueError, match='not a rotation'):
        quaternion_matrix(0.0, 0.0, 0.0, 0.0)


class StandInBuffer:
    """What the node uses of tf2_ros.Buffer: lookup_transform, which may fail."""

    def __init__(self, transform: Any = None) -> None:
        self.transform = transform
        self.calls: list[tuple[str, str]] = []

    def lookup_transform(self, target: str, source: str, time: Any, timeout: Any) -> Any:
        self.calls.append((target, source))
        if self.transform is None:
            raise LookupError(f'"{target}" passed to lookupTransform argument target_frame '
                              'does not exist')
        return self.transform


FALLBACK = Mount(0.0, 0.0, 0.6, 0.0, 0.0, 0.0)


def test_the_transform_is_used_and_cached_for_a_static_mount() -> None:
    buffer = StandInBuffer(_transform(_rz(math.radians(10)) @ OPTICAL_TO_BODY,
                                      (0.2, 0.1, 0.5)))
    source = MountSource(buffer, 'base_footprint', static=True)
    first = source.mount_for('kinect2_ir_optical_frame', None, FALLBACK)
    again = source.mount_for('kinect2_ir_optical_frame', None, FALLBACK)
    assert first == again and first.yaw_rad == pytest.approx(math.radians(10))
    assert buffer.calls == [('base_footprint', 'kinect2_ir_optical_frame')]   # looked up once
    assert source.source == 'TF base_footprint <- kinect2_ir_optical_frame (static, cached)'
    assert source.last_problem is None


def test_a_moving_mount_is_looked_up_per_frame() -> None:
    buffer = StandInBuffer(_transform(OPTICAL_TO_BODY, (0.0, 0.0, 0.7)))
    source = MountSource(buffer, 'base_link', static=False)
    source.mount_for('cam', None, FALLBACK)
    source.mount_for('cam', None, FALLBACK)
    assert len(buffer.calls) == 2


def test_a_failed_lookup_gives_no_mount_and_says_why_then_a_late_transform_is_taken() -> None:
    buffer = StandInBuffer(None)
    source = MountSource(buffer, 'base_footprint')
    assert source.mount_for('cam', None, FALLBACK) is None    # never the parameters
    assert source.source == 'TF base_footprint <- cam: none (frames dropped)'
    assert source.last_problem == (
        "no transform base_footprint <- 'cam' from TF (LookupError: \"base_footprint\" passed "
        'to lookupTransform argument target_frame does not exist)')

    buffer.transform = _transform(OPTICAL_TO_BODY, (0.3, 0.0, 0.4))   # the TF arrives late
    late = source.mount_for('cam', None, FALLBACK)
    assert late == Mount(0.3, 0.0, 0.4, 0.0, 0.0, 0.0) and source.last_problem is None


def test_without_a_buffer_the_parameters_are_used() -> None:
    assert MountSource(None, 'base_footprint').mount_for('cam', None, FALLBACK) is FALLBACK


def _stamped(parent: str, child: str, rotation: np.ndarray, xyz: tuple) -> Any:
    stamped = _transform(rotation, xyz)
    stamped.header = SimpleNamespace(frame_id=parent)
    stamped.child_frame_id = child
    return stamped


def test_recorded_static_transforms_compose_along_the_urdf_chain() -> None:
    """A URDF's chain as robot_state_publisher sends it.

    base_footprint -> base_link (up 0.1) -> camera_link (x 0.2, up 0.5, yaw 10 deg, pitch
    20 deg) -> camera_optical (the optical axes).
    """
    yaw, pitch = math.radians(10.0), math.radians(20.0)
    ry = np.array([[math.cos(pitch), 0, math.sin(pitch)], [0, 1, 0],
                   [-math.sin(pitch), 0, math.cos(pitch)]])
    buffer = StaticTransforms()
    buffer.add(_stamped('base_link', 'camera_link', _rz(yaw) @ ry, (0.2, 0.0, 0.5)))
    buffer.add(_stamped('camera_link', 'camera_optical', OPTICAL_TO_BODY, (0.0, 0.0, 0.0)))
    buffer.add(_stamped('base_footprint', 'base_link', np.eye(3), (0.0, 0.0, 0.1)))
    buffer.add(_stamped('base_link', 'wheel', np.eye(3), (0.0, 0.3, 0.0)))   # another branch

    mount = MountSource(buffer, 'base_footprint').mount_for('camera_optical', None, FALLBACK)
    assert (mount.x_m, mount.y_m, mount.z_m) == pytest.approx((0.2, 0.0, 0.6))
    assert (mount.yaw_rad, mount.pitch_rad, mount.roll_rad) == pytest.approx(
        (yaw, pitch, 0.0), abs=1e-9)
    # between two branches: the camera seen from the wheel
    wheel = mount_from_transform(buffer.lookup_transform('wheel', 'camera_optical'))
    assert (wheel.x_m, wheel.y_m, wheel.z_m) == pytest.approx((0.2, -0.3, 0.5))


def test_a_frame_the_static_transforms_do_not_reach_is_a_lookup_error() -> None:
    buffer = StaticTransforms()
    buffer.add(_stamped('base_link', 'camera_link', np.eye(3), (0.0, 0.0, 0.5)))
    source = MountSource(buffer, 'base_footprint')

    assert source.mount_for('camera_optical', None, FALLBACK) is None
    assert source.last_problem == (
        "no transform base_footprint <- 'camera_optical' from TF (LookupError: "
        '"base_footprint" and "camera_optical" are not connected by the static transforms '
        '(1 recorded: camera_link))')
