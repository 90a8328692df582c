"""The node's configuration from its parameter values: detector, frames, switches (no rclpy)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from obstacle_detection.pipeline.detector import Detector
from obstacle_detection.pipeline.fusion import FusionParams
from obstacle_detection.pipeline.params import Intrinsics
from obstacle_detection.pipeline.refine import LogisticRefiner, RefinedDetector

from .mount_source import Mount
from .parameters import SPECS_BY_NAME, detector_params_from_ros, fallback_intrinsics_from_ros

#: depth_transport -> topic: image_transport's names for the depth stream.
DEPTH_TRANSPORT_TOPICS = {
    'raw': 'depth/image_raw',
    'compressedDepth': 'depth/image_raw/compressedDepth',
    'compressed': 'depth/image_raw/compressed',
}


@dataclass(frozen=True)
class NodeConfig:
    """Everything a frame needs, validated and swapped as one reference on a parameter set."""

    detector: Detector | RefinedDetector
    cloud_frame_id: str
    costmap_frame_id: str
    publish_ground: bool
    publish_overlay: bool
    use_fallback_intrinsics: bool
    fallback_intrinsics: Intrinsics
    stats_period_s: float
    camera_info_tolerance_ns: int = 20_000_000
    fusion: FusionParams | None = None      #: None: no fused costmap
    odom_frame: str = 'odom'
    publish_clearing: bool = False      #: obstacles/clearing_points (pipeline.clearing)
    clearing_range_m: float = 4.0
    clearing_stride_px: int = 4
    values: dict[str, Any] = field(default_factory=dict)   #: the ROS values it was built from

    def mount(self) -> Mount:
        """Return the mount the parameters give (the fallback when TF has none)."""
        values = self.values
        return Mount(x_m=float(values.get('camera_x_m', 0.0)),
                     y_m=float(values.get('camera_y_m', 0.0)),
                     z_m=float(values.get('camera_height_m', 0.6)),
                     roll_rad=math.radians(float(values.get('camera_roll_deg', 0.0))),
                     pitch_rad=math.radians(float(values.get('camera_pitch_deg', 0.0))),
                     yaw_rad=math.radians(float(values.get('camera_yaw_deg', 0.0))))

    def detector_for(self, mount: Mount) -> Detector | RefinedDetector:
        """Return the detector with the camera mounted as ``mount`` (ValueError if not)."""
        values = dict(self.values, camera_height_m=mount.z_m,
                      camera_roll_deg=math.degrees(mount.roll_rad),
                      camera_pitch_deg=math.degrees(mount.pitch_rad))
        extra = {'camera_x_m': mount.x_m, 'camera_y_m': mount.y_m,
                 'camera_yaw_deg': math.degrees(mount.yaw_rad)}
        for name, value in extra.items():
            if name in SPECS_BY_NAME:
                values[name] = value
            elif abs(value) > 1e-6:
                raise ValueError(f'this pipeline has no {name}: the camera must sit above the '
                                 f'base frame origin, facing forward ({mount.describe()})')
        return build_detector(values)


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


def _value(values: dict[str, Any], name: str) -> Any:
    """Return a parameter's value, or its default when ``values`` lacks it."""
    return values[name] if name in values else SPECS_BY_NAME[name].default


def build_config(values: dict[str, Any]) -> NodeConfig:
    """NodeConfig from ``{ros_name: value}`` of every parameter; ValueError naming a bad one."""
    for name in ('cloud_frame_id', 'costmap_frame_id', 'odom_frame'):
        if not str(values[name]).strip():
            raise ValueError(f'{name} must not be empty')
    transport = values.get('depth_transport', 'raw')
    if transport not in DEPTH_TRANSPORT_TOPICS:
        raise ValueError(f'depth_transport={transport!r} must be one of '
                         f'{", ".join(map(repr, DEPTH_TRANSPORT_TOPICS))}')
    return NodeConfig(
        detector=build_detector(values),
        cloud_frame_id=str(values['cloud_frame_id']),
        costmap_frame_id=str(values['costmap_frame_id']),
        publish_ground=bool(values['publish_ground']),
        publish_overlay=bool(values['publish_overlay']),
        use_fallback_intrinsics=bool(values['use_fallback_intrinsics']),
        fallback_intrinsics=fallback_intrinsics_from_ros(values),
        stats_period_s=float(values['stats_period_s']),
        camera_info_tolerance_ns=round(float(values['camera_info_tolerance_s']) * 1e9),
        fusion=(FusionParams(size_m=float(values['fused_size_m']),
                             resolution_m=float(values['fused_resolution_m']))
                if values.get('fuse') else None),
        odom_frame=str(values.get('odom_frame', 'odom')),
        publish_clearing=bool(_value(values, 'publish_clearing')),
        clearing_range_m=float(_value(values, 'clearing_range_m')),
        clearing_stride_px=int(_value(values, 'clearing_stride_px')),
        values=dict(values))
