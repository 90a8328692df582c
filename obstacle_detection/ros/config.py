"""The node's configuration from its parameter values: detector, frames, switches (no rclpy)."""

from __future__ import annotations

import ctypes
import functools
import gc
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from obstacle_detection.pipeline import clearing
from obstacle_detection.pipeline.detector import DetectionResult, Detector
from obstacle_detection.pipeline.fusion import FusionParams
from obstacle_detection.pipeline.params import Intrinsics, frame_budget
from obstacle_detection.pipeline.refine import LogisticRefiner, RefinedDetector

from .mount_source import Mount
from .parameters import detector_params_from_ros

#: depth_transport -> topic: image_transport's names for the depth stream.
DEPTH_TRANSPORT_TOPICS = {
    'raw': 'depth/image_raw',
    'compressedDepth': 'depth/image_raw/compressedDepth',
    'compressed': 'depth/image_raw/compressed',
}


@dataclass(frozen=True, eq=False)
class NodeConfig:
    """Everything a frame needs, validated and swapped as one reference on a parameter set."""

    detector: Detector | RefinedDetector
    cloud_frame_id: str
    costmap_frame_id: str
    publish_ground: bool
    publish_overlay: bool
    use_fallback_intrinsics: bool
    fallback_intrinsics: Intrinsics
    camera_info_tolerance_ns: int
    fusion: FusionParams | None      #: None: no fused costmap
    odom_frame: str
    publish_clearing: bool      #: obstacles/clearing_points (pipeline.clearing)
    clearing_range_m: float
    clearing_stride_px: int
    clearing_voxel_m: float     #: the consumer's voxel height (pipeline.clearing.nav2_clouds)
    values: dict[str, Any]   #: the ROS values it was built from

    def mount(self) -> Mount:
        """Return the mount the parameters give (the fallback when TF has none)."""
        values = self.values
        return Mount(x_m=float(values['camera_x_m']), y_m=float(values['camera_y_m']),
                     z_m=float(values['camera_height_m']),
                     roll_rad=math.radians(float(values['camera_roll_deg'])),
                     pitch_rad=math.radians(float(values['camera_pitch_deg'])),
                     yaw_rad=math.radians(float(values['camera_yaw_deg'])))

    def nav2_clouds(self, result: DetectionResult
                    ) -> tuple[np.ndarray | None, np.ndarray | None]:
        """(obstacles/marking_points, obstacles/clearing_points) of a frame, as the node sends.

        Both None without publish_clearing. With clearing_voxel_m > 0 the marks and rays are
        matched for a voxel layer placing the camera by the frame's nominal pose
        (pipeline.clearing.nav2_clouds); with 0 the marks are the result's obstacle points.
        obstacles/points always carries the result's obstacle points, for every other consumer.
        """
        if not self.publish_clearing:
            return None, None
        points = clearing.clearing_cloud(result, stride_px=self.clearing_stride_px,
                                         range_m=self.clearing_range_m)
        if self.clearing_voxel_m == 0.0:
            return result.obstacle_points, points
        pose = result.pose
        return clearing.nav2_clouds(
            result.obstacle_points, points, pose.rotation(nominal=True),
            pose.translation(nominal=True), cell_m=pose.nominal.costmap_resolution_m,
            voxel_m=self.clearing_voxel_m)

    @functools.lru_cache(maxsize=1)   # TF's mount changes rarely: its detector is kept
    def detector_for(self, mount: Mount) -> Detector | RefinedDetector:
        """Return the detector with the camera mounted as ``mount`` (ValueError if not)."""
        return build_detector(dict(
            self.values, camera_x_m=mount.x_m, camera_y_m=mount.y_m, camera_height_m=mount.z_m,
            camera_roll_deg=math.degrees(mount.roll_rad),
            camera_pitch_deg=math.degrees(mount.pitch_rad),
            camera_yaw_deg=math.degrees(mount.yaw_rad)))


def build_detector(values: dict[str, Any]) -> Detector | RefinedDetector:
    """Build the pipeline, refined when ``refiner_model_file`` names a model; ValueError if bad."""
    detector = Detector(detector_params_from_ros(values))
    model_file = str(values.get('refiner_model_file', '')).strip()
    if not model_file:
        return detector
    try:
        refiner = LogisticRefiner.load(model_file)
    except OSError as error:
        raise ValueError(f'refiner_model_file {model_file!r}: {error.strerror or error}') \
            from error
    return RefinedDetector(detector, refiner)


def build_config(values: dict[str, Any], *, check_budget: bool = True) -> NodeConfig:
    """NodeConfig from ``{ros_name: value}`` of every parameter; ValueError naming a bad one.

    check_budget: refuse a set whose frame would take more time or memory than the limits of
    ``pipeline.params.frame_budget`` (docs/budget.md).
    """
    for name in ('cloud_frame_id', 'costmap_frame_id', 'odom_frame'):
        if not str(values[name]).strip():
            raise ValueError(f'{name} must not be empty')
    transport = values['depth_transport']
    if transport not in DEPTH_TRANSPORT_TOPICS:
        raise ValueError(f'depth_transport={transport!r} must be one of '
                         f'{", ".join(map(repr, DEPTH_TRANSPORT_TOPICS))}')
    detector = build_detector(values)
    fusion = (FusionParams(size_m=float(values['fused_size_m']),
                           resolution_m=float(values['fused_resolution_m']))
              if values['fuse'] else None)
    if check_budget:   # a combination of in-range values beyond a frame's budget
        problem = frame_budget(detector.params, **node_budget(values)).problem()
        if problem is not None:
            raise ValueError(problem)
    return NodeConfig(
        detector=detector,
        cloud_frame_id=str(values['cloud_frame_id']),
        costmap_frame_id=str(values['costmap_frame_id']),
        publish_ground=bool(values['publish_ground']),
        publish_overlay=bool(values['publish_overlay']),
        use_fallback_intrinsics=bool(values['use_fallback_intrinsics']),
        fallback_intrinsics=Intrinsics(
            fx=float(values['fallback_fx']), fy=float(values['fallback_fy']),
            cx=float(values['fallback_cx']), cy=float(values['fallback_cy'])),
        camera_info_tolerance_ns=round(float(values['camera_info_tolerance_s']) * 1e9),
        fusion=fusion,
        odom_frame=str(values['odom_frame']),
        publish_clearing=bool(values['publish_clearing']),
        clearing_range_m=float(values['clearing_range_m']),
        clearing_stride_px=int(values['clearing_stride_px']),
        clearing_voxel_m=float(values['clearing_voxel_m']),
        values=dict(values))


def node_budget(values: dict[str, Any]) -> dict[str, Any]:
    """Return the node's own terms of ``frame_budget``: the fused costmap, the clearing cloud."""
    return {'fused_size_m': float(values['fused_size_m']) if values['fuse'] else 0.0,
            'fused_resolution_m': float(values['fused_resolution_m']),
            'clearing_stride_px': (int(values['clearing_stride_px'])
                                   if values['publish_clearing'] else 0)}


def release_memory() -> None:
    """Hand the heap memory freed by a heavier configuration's frames back to the system.

    glibc keeps freed blocks below its (growing) mmap threshold in its arenas, one a thread;
    ``malloc_trim(0)`` returns their free pages (docs/budget.md). Elsewhere: nothing to do.
    """
    gc.collect()
    try:
        ctypes.CDLL('libc.so.6').malloc_trim(0)
    except (OSError, AttributeError):   # not glibc
        pass
