"""Where the camera mount comes from: the parameters, or TF when it has the transform."""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from obstacle_detection.pipeline.geometry import mount_angles, quaternion_matrix


@dataclass(frozen=True)
class Mount:
    """The camera pose in the base frame: position [m] and roll, pitch, yaw [rad]."""

    x_m: float = 0.0
    y_m: float = 0.0
    z_m: float = 0.6
    roll_rad: float = 0.0
    pitch_rad: float = 0.0
    yaw_rad: float = 0.0

    def describe(self) -> str:
        """Return one line with the pose in metres and degrees."""
        return (f'x {self.x_m:.3f} m, y {self.y_m:.3f} m, z {self.z_m:.3f} m, roll '
                f'{math.degrees(self.roll_rad):.2f} deg, pitch '
                f'{math.degrees(self.pitch_rad):.2f} deg, yaw '
                f'{math.degrees(self.yaw_rad):.2f} deg')


def mount_from_transform(transform: Any) -> Mount:
    """Return the Mount of a ``geometry_msgs/Transform`` (or TransformStamped), base <- optical."""
    transform = getattr(transform, 'transform', transform)
    q, t = transform.rotation, transform.translation
    roll, pitch, yaw = mount_angles(quaternion_matrix(q.x, q.y, q.z, q.w))
    return Mount(float(t.x), float(t.y), float(t.z), roll, pitch, yaw)


class MountSource:
    """Give each frame its mount: the parameters, or TF's transform (none while TF has none).

    With a buffer (use_tf) a frame whose transform is missing gets no mount: the node drops it
    and says why (``last_problem``) rather than place it with the parameters, which Nav2,
    placing the clearing cloud through TF, would not agree with.
    """

    def __init__(self, buffer: Any, base_frame: str, *, static: bool = True,
                 timeout: Any = None) -> None:
        self.buffer = buffer
        self.base_frame = base_frame
        self.static = static
        self.timeout = timeout   #: of a lookup: a rclpy Duration
        self._cache: dict[str, Mount] = {}
        self.last_problem: str | None = None
        self.source = 'parameters'

    def mount_for(self, frame_id: str, stamp: Any, parameters: Mount) -> Mount | None:
        """Return the mount for an image of ``frame_id`` at ``stamp`` (a rclpy Time).

        None when TF has no transform (``last_problem`` says which frames and tf2's error).
        """
        self.last_problem = None
        if self.buffer is None:
            self.source = 'parameters'
            return parameters
        if self.static and frame_id in self._cache:
            self.source = f'TF {self.base_frame} <- {frame_id} (static, cached)'
            return self._cache[frame_id]
        try:
            transform = self.buffer.lookup_transform(self.base_frame, frame_id, stamp,
                                                     self.timeout)
            mount = mount_from_transform(transform)
        except Exception as error:  # noqa: BLE001 - tf2's exceptions are not importable here
            self.last_problem = (f'no transform {self.base_frame} <- {frame_id!r} from TF '
                                 f'({type(error).__name__}: {error})')
            self.source = f'TF {self.base_frame} <- {frame_id}: none (frames dropped)'
            return None
        self._cache[frame_id] = mount
        self.source = f'TF {self.base_frame} <- {frame_id}'
        return mount


class StaticTransforms:
    """The part of ``tf2_ros.Buffer`` a MountSource uses, from recorded static transforms.

    For tools that read a bag (no TF listener): ``add`` each ``geometry_msgs/TransformStamped``
    of its ``/tf_static``; ``lookup_transform`` composes them along the tree (stamps ignored:
    static transforms hold at every time) or raises LookupError naming the missing link.
    """

    def __init__(self) -> None:
        self._parent: dict[str, tuple[str, np.ndarray]] = {}   # child -> (parent, 4x4)

    def __len__(self) -> int:
        return len(self._parent)

    def add(self, transform: Any) -> None:
        """Add one TransformStamped (parent header.frame_id, child child_frame_id)."""
        t, q = transform.transform.translation, transform.transform.rotation
        matrix = np.eye(4)
        matrix[:3, :3] = quaternion_matrix(q.x, q.y, q.z, q.w)
        matrix[:3, 3] = (t.x, t.y, t.z)
        self._parent[str(transform.child_frame_id).lstrip('/')] = (
            str(transform.header.frame_id).lstrip('/'), matrix)

    def _to_root(self, frame: str) -> tuple[list[str], list[np.ndarray]]:
        """Return the frames from ``frame`` up to its root, and frame's pose in each of them."""
        chain, poses, pose = [frame], [np.eye(4)], np.eye(4)
        while frame in self._parent and len(chain) <= len(self._parent):
            frame, matrix = self._parent[frame]
            pose = matrix @ pose
            chain.append(frame)
            poses.append(pose)
        return chain, poses

    def lookup_transform(self, target: str, source: str, time: Any = None,
                         timeout: Any = None) -> Any:
        """Return the transform target <- source (``.transform.translation/.rotation``)."""
        source_chain, source_poses = self._to_root(source.lstrip('/'))
        target_chain, target_poses = self._to_root(target.lstrip('/'))
        common = next((f for f in source_chain if f in target_chain), None)
        if common is None:
            raise LookupError(f'"{target}" and "{source}" are not connected by the static '
                              f'transforms ({len(self._parent)} recorded: '
                              f'{", ".join(sorted(self._parent)) or "none"})')
        # poses[i]: the frame's pose in chain[i]; target <- common <- source
        matrix = (np.linalg.inv(target_poses[target_chain.index(common)])
                  @ source_poses[source_chain.index(common)])
        x, y, z, w = Rotation.from_matrix(matrix[:3, :3]).as_quat()
        return SimpleNamespace(transform=SimpleNamespace(
            translation=SimpleNamespace(x=matrix[0, 3], y=matrix[1, 3], z=matrix[2, 3]),
            rotation=SimpleNamespace(x=x, y=y, z=z, w=w)))
