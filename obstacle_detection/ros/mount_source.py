"""Where the camera mount comes from: the parameters, or TF when it has the transform."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any


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
        self.source = 'parameters' if buffer is None else f'TF {base_frame} <- ?'

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
