"""The node's ROS parameters: names, defaults, descriptors, and the map to DetectorParams.

Every DetectorParams field becomes one ROS parameter of the same name, except the three angles,
which a person writes in degrees (DESIGN.md): ``max_slope_rad`` -> ``max_slope_deg``,
``camera_pitch_rad`` -> ``camera_pitch_deg``, ``camera_roll_rad`` -> ``camera_roll_deg``,
``floor_max_tilt_rad`` -> ``floor_max_tilt_deg``.
Descriptions and ranges come from the dataclass's field metadata. The node's own parameters
(frames, output switches, QoS, intrinsics fallback, statistics) follow.

This module builds ``rcl_interfaces`` messages but never imports rclpy, so tools (the parameter
table) and tests use it without a ROS graph.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType

from .params import SEED_TABLE_4_1, DetectorParams, Intrinsics

ParamValue = bool | int | float | str

#: The node's name: the section of a ``--params-file`` it reads.
NODE_NAME = 'obstacle_detector'

#: DetectorParams fields exposed in degrees -> their ROS parameter name.
DEGREE_FIELDS = {
    'max_slope_rad': 'max_slope_deg',
    'camera_pitch_rad': 'camera_pitch_deg',
    'camera_roll_rad': 'camera_roll_deg',
    'floor_max_tilt_rad': 'floor_max_tilt_deg',
}

_ROS_TYPES = {bool: ParameterType.PARAMETER_BOOL, int: ParameterType.PARAMETER_INTEGER,
              float: ParameterType.PARAMETER_DOUBLE, str: ParameterType.PARAMETER_STRING}


@dataclass(frozen=True)
class ParamSpec:
    """One ROS parameter of the node.

    ``field`` names the DetectorParams field it sets (None for a node-only parameter);
    ``degrees`` means the ROS value is in degrees and the field in radians. ``low``/``high`` is
    the inclusive range given to ROS; ``open_low``/``open_high`` mark a bound that the dataclass
    itself refuses (with its own message).
    """

    name: str
    default: ParamValue
    description: str
    low: float | int | None = None
    high: float | int | None = None
    read_only: bool = False
    field: str | None = None
    degrees: bool = False
    open_low: bool = False
    open_high: bool = False

    @property
    def range_text(self) -> str:
        """The allowed range as an interval, e.g. ``(0, 90)`` or ``[1, 31]``; '' if none."""
        if self.low is None or self.high is None:
            return ''
        return (f'{"(" if self.open_low else "["}{self.low:g}, '
                f'{self.high:g}{")" if self.open_high else "]"}')

    @property
    def type_name(self) -> str:
        """'bool', 'int', 'float' or 'str'."""
        return type(self.default).__name__

    def to_field(self, value: ParamValue) -> ParamValue:
        """Convert a ROS value to the DetectorParams field value (degrees -> radians)."""
        return math.radians(value) if self.degrees else value

    def descriptor(self) -> ParameterDescriptor:
        """Build the rcl_interfaces ParameterDescriptor: type, description, range, read-only."""
        desc = ParameterDescriptor(name=self.name, type=_ROS_TYPES[type(self.default)],
                                   description=self.description, read_only=self.read_only)
        if self.low is not None and self.high is not None:
            if isinstance(self.default, float):
                desc.floating_point_range = [FloatingPointRange(
                    from_value=float(self.low), to_value=float(self.high), step=0.0)]
            elif isinstance(self.default, int) and not isinstance(self.default, bool):
                # Step 1 even for the odd-only median kernel: an even K reaches the on-set
                # callback, which refuses it with the dataclass's own message.
                desc.integer_range = [IntegerRange(
                    from_value=int(self.low), to_value=int(self.high), step=1)]
        return desc


def _degrees(value: float) -> float:
    # math.degrees(pi / 6) is 29.999999999999996; a person wrote 30.
    return round(math.degrees(value), 9)


def _pipeline_specs() -> list[ParamSpec]:
    defaults = DetectorParams()
    specs = []
    for f in dataclasses.fields(DetectorParams):
        meta = f.metadata
        default = getattr(defaults, f.name)
        low, high = meta.get('min'), meta.get('max')
        if f.name in DEGREE_FIELDS:
            description = meta['description'].replace('[rad]', '[deg]')
            if not description.endswith('[deg]'):
                description += ' [deg]'
            specs.append(ParamSpec(
                name=DEGREE_FIELDS[f.name], default=_degrees(default), description=description,
                low=_degrees(low), high=_degrees(high), field=f.name, degrees=True,
                open_low=bool(meta.get('open_min')), open_high=bool(meta.get('open_max'))))
            continue
        if isinstance(default, float):
            low, high = float(low), float(high)
        specs.append(ParamSpec(name=f.name, default=default, description=meta['description'],
                               low=low, high=high, field=f.name,
                               open_low=bool(meta.get('open_min')),
                               open_high=bool(meta.get('open_max'))))
    return specs


#: DetectorParams fields as ROS parameters (dataclass field order).
PIPELINE_PARAMS: tuple[ParamSpec, ...] = tuple(_pipeline_specs())

#: The node's own parameters.
NODE_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec('cloud_frame_id', 'base_footprint',
              'Frame of obstacles/points and obstacles/ground_points: the ground frame (x '
              'forward, y left, z up, origin on the ground under the camera)'),
    ParamSpec('costmap_frame_id', 'base_footprint',
              'Frame of obstacles/costmap, whose grid lies in its z = 0 plane: the ground frame'),
    ParamSpec('publish_ground', False,
              'Also publish the traversable voxels on obstacles/ground_points (lets a costmap '
              'clear cells)'),
    ParamSpec('publish_overlay', False,
              'Also publish obstacles/overlay: rgb8 depth frame with obstacle pixels in red'),
    ParamSpec('reliable_input', False,
              'Subscribe to depth and camera_info with reliable QoS instead of sensor-data '
              '(best effort); read at start-up', read_only=True),
    ParamSpec('use_fallback_intrinsics', False,
              'Use fallback_fx/fy/cx/cy while no CameraInfo has arrived (else frames are '
              'skipped until one arrives)'),
    ParamSpec('fallback_fx', SEED_TABLE_4_1.fx,
              'Fallback focal length fx (seed Table 4.1: f = 580) [px]', 0.0, 100000.0,
              open_low=True),
    ParamSpec('fallback_fy', SEED_TABLE_4_1.fy,
              'Fallback focal length fy (seed Table 4.1: f = 580) [px]', 0.0, 100000.0,
              open_low=True),
    ParamSpec('fallback_cx', SEED_TABLE_4_1.cx,
              'Fallback principal point cx (seed Table 4.1: Centerx = 200) [px]',
              -100000.0, 100000.0),
    ParamSpec('fallback_cy', SEED_TABLE_4_1.cy,
              'Fallback principal point cy (seed Table 4.1: Centery = 130) [px]',
              -100000.0, 100000.0),
    ParamSpec('refiner_model_file', '',
              'Not in the seed as a default: a model file from tools/train_refiner.py (seed '
              'section 4.5 logistic regression on slope, depth gradient and the previous '
              "frame's obstacles) refines each frame; '' = rule-based only"),
    ParamSpec('stats_period_s', 10.0,
              'Period of the info log with frames processed, dropped, mean time and fps; '
              '0 = off [s]', 0.0, 3600.0),
)

ALL_PARAMS: tuple[ParamSpec, ...] = PIPELINE_PARAMS + NODE_PARAMS
SPECS_BY_NAME: dict[str, ParamSpec] = {spec.name: spec for spec in ALL_PARAMS}


def pipeline_params_to_ros(params: DetectorParams) -> dict[str, ParamValue]:
    """``{ros_name: value}`` of a DetectorParams (radians -> degrees where exposed so)."""
    values = {}
    for spec in PIPELINE_PARAMS:
        value = getattr(params, spec.field)
        values[spec.name] = _degrees(value) if spec.degrees else value
    return values


def detector_params_from_ros(values: Mapping[str, Any]) -> DetectorParams:
    """DetectorParams from ROS parameter values; missing names take the dataclass defaults.

    Raises ValueError naming the bad value (the dataclass's validation).
    """
    fields = {spec.field: spec.to_field(values[spec.name])
              for spec in PIPELINE_PARAMS if spec.name in values}
    return DetectorParams(**fields)


def fallback_intrinsics_from_ros(values: Mapping[str, Any]) -> Intrinsics:
    """Build the fallback Intrinsics from fallback_fx/fy/cx/cy (ValueError on a zero focal)."""
    return Intrinsics(fx=float(values['fallback_fx']), fy=float(values['fallback_fy']),
                      cx=float(values['fallback_cx']), cy=float(values['fallback_cy']))


class ParamsFileError(ValueError):
    """A ``--params-file`` that cannot be read, or that names or types a parameter wrongly."""


def read_params_file(path: str | Path) -> dict[str, ParamValue]:
    """Return the parameter values a node parameter file sets: ``{ros_name: value}``.

    The file has the ``--params-file`` format (``obstacle_detector: ros__parameters: {...}``;
    ``/**`` and ``/obstacle_detector`` sections are read too, in that order). Unlike the node,
    which ignores undeclared names, an unknown name is an error here (a typo would otherwise
    go unnoticed); as for the node, a value must have its parameter's type (1.0, not 1, for a
    floating-point one). Only the names in the file are returned. Raises ParamsFileError
    naming the file and the parameter; the values themselves are validated by
    :func:`detector_params_from_ros`.
    """
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text(encoding='utf-8'))
    except OSError as err:
        raise ParamsFileError(f'{path}: cannot read params file ({err.strerror})') from err
    except yaml.YAMLError as err:
        raise ParamsFileError(f'{path}: not valid YAML ({err})') from err
    if not isinstance(data, dict):
        raise ParamsFileError(f'{path}: expected "{NODE_NAME}: ros__parameters: ..."')
    sections = [data[key] for key in ('/**', NODE_NAME, f'/{NODE_NAME}') if key in data]
    if not sections:
        raise ParamsFileError(f'{path}: no "{NODE_NAME}" (or "/**") section')
    values: dict[str, ParamValue] = {}
    for section in sections:
        params = section.get('ros__parameters') if isinstance(section, dict) else None
        if not isinstance(params, dict):
            raise ParamsFileError(f'{path}: a section lacks "ros__parameters"')
        for name, value in params.items():
            spec = SPECS_BY_NAME.get(name)
            if spec is None:
                raise ParamsFileError(f'{path}: unknown parameter {name!r}')
            want = type(spec.default)
            if type(value) is not want:
                raise ParamsFileError(f'{path}: parameter {name!r} must be a {want.__name__}, '
                                      f'got {value!r}')
            values[name] = value
    return values
