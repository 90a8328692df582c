"""The node's ROS parameters: names, defaults, descriptors, and the map to DetectorParams."""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType

from obstacle_detection.pipeline.params import SEED_TABLE_4_1, DetectorParams

from . import RosInputError

ParamValue = bool | int | float | str

#: The node's name.
NODE_NAME = 'obstacle_detector'
#: The section key of the shipped ``--params-file`` YAMLs: the node in any namespace (rcl matches
#: a key against the node's fully qualified name, so a plain ``obstacle_detector:`` is lost
#: when the node runs in a namespace).
PARAMS_FILE_KEY = f'/**/{NODE_NAME}'
#: Parameters every rclpy node declares itself (rclpy's TimeSource and type description
#: service), and diagnostic_updater's use_fqn (declared as the Updater does, see
#: diagnostics.py): a params file may set them; they are not the node's own.
RCLPY_PARAMETERS = ('use_sim_time', 'start_type_description_service',
                    'diagnostic_updater.use_fqn')

#: DetectorParams fields exposed in degrees -> their ROS parameter name.
DEGREE_FIELDS = {
    'max_slope_rad': 'max_slope_deg',
    'camera_pitch_rad': 'camera_pitch_deg',
    'camera_roll_rad': 'camera_roll_deg',
    'floor_max_tilt_rad': 'floor_max_tilt_deg',
    'camera_yaw_rad': 'camera_yaw_deg',
}

_ROS_TYPES = {bool: ParameterType.PARAMETER_BOOL, int: ParameterType.PARAMETER_INTEGER,
              float: ParameterType.PARAMETER_DOUBLE, str: ParameterType.PARAMETER_STRING}


@dataclass(frozen=True)
class ParamSpec:
    """One ROS parameter of the node."""

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
        name, description, degrees = f.name, meta['description'], f.name in DEGREE_FIELDS
        if degrees:
            name, default = DEGREE_FIELDS[f.name], _degrees(default)
            low, high = _degrees(low), _degrees(high)
            description = description.replace('[rad]', '[deg]')
            if not description.endswith('[deg]'):
                description += ' [deg]'
        specs.append(ParamSpec(name=name, default=default, description=description, low=low,
                               high=high, field=f.name, degrees=degrees,
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
              'clear cells); read at start-up (the topic is advertised only when on)',
              read_only=True),
    ParamSpec('publish_clearing', True,
              'Also publish obstacles/clearing_points: the surfaces the camera saw (every '
              'clearing_stride_px-th pixel), in the depth image\'s own optical frame, so a 3-D '
              'costmap layer (Nav2 VoxelLayer) raytraces from the camera through the space now '
              'empty and forgets obstacles that left; read at start-up (the topic is advertised '
              'only when on)', read_only=True),
    ParamSpec('clearing_range_m', 4.0,
              'Farthest clearing point from the camera: a farther surface gives the point at '
              'this distance on its ray (the space up to it was seen free) [m]', 0.5, 20.0),
    ParamSpec('clearing_stride_px', 4,
              'obstacles/clearing_points keeps every this many-th row and column of the '
              'filtered depth image (4: about 13,000 rays of a 512 x 424 frame) [px]', 1, 64),
    ParamSpec('clearing_voxel_m', 0.1,
              'Voxel height of the 3-D layer the clouds feed (Nav2 VoxelLayer z_resolution; '
              'its cell is costmap_resolution_m): with publish_clearing, '
              'obstacles/marking_points leaves out marks less than a cell inside the outermost '
              'clearing rays (no ray would clear them) and the rays stop before their columns; '
              'a column whose marks span less than a voxel is filled two voxels down, so a ray '
              'grazing its voxel does not free it; 0 = off, the marks as seen. '
              'obstacles/points is never changed [m]', 0.0, 1.0),
    ParamSpec('publish_overlay', False,
              'Also publish obstacles/overlay: rgb8 depth frame with obstacle pixels in red; '
              'read at start-up (the topic is advertised only when on)', read_only=True),
    ParamSpec('reliable_input', False,
              'Subscribe to depth and camera_info with reliable QoS instead of sensor-data '
              '(best effort); read at start-up',
              read_only=True),
    ParamSpec('use_fallback_intrinsics', False,
              'Use fallback_fx/fy/cx/cy while no CameraInfo has arrived (else frames are '
              'skipped until one arrives)'),
    ParamSpec('fuse', False,
              'Also publish obstacles/fused_costmap: the per-frame costmaps fused over time '
              '(log-odds) in a rolling window centred on the robot in odom_frame, moved by the '
              'odometry on odom_topic (without it: fused in place, said once); read at start-up '
              '(the topic and the odometry subscription exist only when on)', read_only=True),
    ParamSpec('odom_topic', 'odom',
              'nav_msgs/Odometry of the robot base in odom_frame, for the fused costmap '
              '(subscribed best effort, so reliable and best-effort publishers both connect); '
              'read at start-up', read_only=True),
    ParamSpec('odom_frame', 'odom', 'Frame of obstacles/fused_costmap (the odometry frame)'),
    ParamSpec('fused_size_m', 4.0,
              'Side of the fused costmap window, centred on the robot [m]', 0.5, 100.0),
    ParamSpec('fused_resolution_m', 0.05, 'Cell size of the fused costmap [m/cell]', 0.01,
              1.0),
    ParamSpec('use_tf', False,
              'Take the camera mount from TF (the robot use; the launch file sets it): the '
              "transform cloud_frame_id <- the depth image's frame_id, at the image stamp; a "
              'frame without one is dropped (a throttled warning, counted on /diagnostics), '
              'never placed by the mount parameters. Needs tf2_ros (a ROS 2 installation): '
              'without it the node refuses to start; read at start-up', read_only=True),
    ParamSpec('tf_timeout_s', 0.05,
              'Longest wait for a TF lookup before the frame is dropped [s]', 0.0, 1.0),
    ParamSpec('tf_static_mount', True,
              'The camera is bolted to the robot: look its transform up once and keep it '
              '(false: look it up for every frame, e.g. a pan-tilt head)'),
    ParamSpec('depth_transport', 'raw',
              "Depth input: 'raw' (sensor_msgs/Image on depth/image_raw), 'compressedDepth' "
              "(CompressedImage on depth/image_raw/compressedDepth, image_transport's PNG or "
              "RVL codec) or 'compressed' (depth/image_raw/compressed, e.g. iai_kinect2's); "
              'read at start-up', read_only=True),
    ParamSpec('camera_info_tolerance_s', 0.02,
              'A depth frame uses the CameraInfo whose stamp is nearest to its own within this '
              'tolerance (the newest one when the camera publishes a single CameraInfo, or when '
              'all recent ones agree) [s]', 0.0, 10.0),
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
              'Not in the seed as a default: a model file from evaluate --train-refiner (seed '
              'section 4.5 logistic regression on slope, depth gradient and the previous '
              "frame's obstacles) refines each frame; '' = rule-based only"),
    ParamSpec('stats_period_s', 10.0,
              'Period of the info log with frames processed, dropped, mean time and fps; '
              '0 = off; read at start-up [s]', 0.0, 3600.0, read_only=True),
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


def _range_problem(spec: ParamSpec, value: Any) -> str | None:
    """Say why a value is outside its parameter's range, in the user's units, or None."""
    if spec.low is None or spec.high is None or isinstance(value, (bool, str)):
        return None
    if not isinstance(value, (int, float)) or not math.isfinite(value):
        return f'{spec.name}={value!r} must be a finite number'
    low_bad = value < spec.low or (spec.open_low and value == spec.low)
    high_bad = value > spec.high or (spec.open_high and value == spec.high)
    if low_bad or high_bad:
        unit = ' [deg]' if spec.degrees else ''
        return f'{spec.name}={value!r} out of range: must be in {spec.range_text}{unit}'
    return None


def detector_params_from_ros(values: Mapping[str, Any]) -> DetectorParams:
    """DetectorParams from ROS parameter values; missing names take the dataclass defaults."""
    for spec in PIPELINE_PARAMS:
        if spec.name in values:
            problem = _range_problem(spec, values[spec.name])
            if problem is not None:
                raise ValueError(problem)
    fields = {spec.field: math.radians(values[spec.name]) if spec.degrees else values[spec.name]
              for spec in PIPELINE_PARAMS if spec.name in values}
    return DetectorParams(**fields)   # the range checks above name every degree field


def params_files_in_args(args: list[str]) -> list[str]:
    """Return the ``--params-file`` paths of a command line, in order."""
    return [args[i + 1] for i in range(len(args) - 1) if args[i] == '--params-file']


def _section_applies(key: str, node_fqn: str) -> bool:
    """Whether a params-file section key (``/**``, ``name``, ``/ns/*``...) names the node."""
    pattern = '/' + str(key).lstrip('/')
    tokens = []
    for part in pattern.strip('/').split('/'):
        if part == '**':
            tokens.append('(/[^/]+)*')
        else:
            tokens.append('/' + re.escape(part).replace(r'\*', '[^/]+'))
    return re.fullmatch(''.join(tokens), node_fqn) is not None


def load_params_yaml(path: Path) -> dict[Any, Any]:
    """Return the parsed YAML mapping of a params file; RosInputError says why there is none."""
    try:
        data = yaml.safe_load(path.read_text(encoding='utf-8'))
    except OSError as err:
        raise RosInputError(f'{path}: cannot read params file ({err.strerror})') from None
    except yaml.YAMLError as err:
        raise RosInputError(f'{path}: not valid YAML ({" ".join(str(err).split())})') from None
    if not isinstance(data, dict):
        raise RosInputError(f'{path}: expected "{PARAMS_FILE_KEY}: ros__parameters: ..."')
    return data


def _read_sections(path: Path, node_fqn: str) -> tuple[dict[str, Any], list[str]]:
    """Return the parameter messages of the sections naming the node, and the other keys."""
    from rclpy.parameter import parameter_dict_from_yaml_file

    data = load_params_yaml(path)
    keys = [key for key in data if _section_applies(str(key), node_fqn)]
    ignored = [str(key) for key in data if key not in keys]
    if not keys:
        return {}, ignored
    try:   # the keys in the order given, each once
        return parameter_dict_from_yaml_file(str(path), target_nodes=keys), ignored
    except (RuntimeError, ValueError, TypeError) as error:
        raise RosInputError(f'{path}: {error}') from None


def params_file_problems(path: str | Path, node_fqn: str = f'/{NODE_NAME}') -> list[str]:
    """Return what the node would silently ignore in a params file, one sentence each."""
    path = Path(path)
    messages, ignored = _read_sections(path, node_fqn)
    return [*(f'{path}: section {key!r} does not name this node ({node_fqn}) and is ignored '
              f'(use "{PARAMS_FILE_KEY}:" or "/**:")' for key in ignored),
            *(_unknown_name(path, name, ' is ignored') for name in messages
              if name not in SPECS_BY_NAME and name not in RCLPY_PARAMETERS)]


def _unknown_name(path: Path, name: str, outcome: str = '') -> str:
    """Say that ``name`` is no parameter of the node (and ``outcome``), with the nearest one."""
    close = difflib.get_close_matches(str(name), [*SPECS_BY_NAME, *RCLPY_PARAMETERS], n=1)
    hint = f' (did you mean {close[0]!r}?)' if close else ''
    return (f'{path}: unknown parameter {name!r}{outcome}{hint}; `detector --help` lists the '
            'parameters')


def _checked_values(path: Path, messages: Mapping[str, Any]) -> dict[str, ParamValue]:
    """Return the values of the node's parameters in ``messages``; RosInputError on a type.

    One behaviour for the node and the tools. A name the node does not declare is left out (as
    ROS ignores overrides a node does not declare: a robot's params file shared by many nodes
    under "/**:" must not stop this one); params_file_problems says it, with the nearest name.
    A value of another type is refused with the file, the name and the fix, as rcl refuses it.
    """
    from rclpy.parameter import Parameter

    values: dict[str, ParamValue] = {}
    for name, message in messages.items():
        spec = SPECS_BY_NAME.get(name)
        if spec is None:   # rclpy's own (use_sim_time) or unknown: see params_file_problems
            continue
        value = Parameter.from_parameter_msg(message).value
        want = type(spec.default)
        if type(value) is not want:
            fix = f': write {value}.0' if want is float and type(value) is int else ''
            raise RosInputError(f'{path}: parameter {name!r} must be a {want.__name__}, got '
                                f'{value!r}{fix}')
        values[name] = value
    return values


def check_params_file(path: str | Path, node_fqn: str = f'/{NODE_NAME}') -> None:
    """Raise RosInputError, naming file, parameter and fix, for a file the node cannot start on.

    The node's start-up check (before rcl, whose refusal names neither file nor fix).
    """
    path = Path(path)
    _checked_values(path, _read_sections(path, node_fqn)[0])


def read_params_file(path: str | Path) -> dict[str, ParamValue]:
    """Return the parameter values a node parameter file sets: ``{ros_name: value}``.

    Names the node does not declare are left out (params_file_problems says them).
    """
    path = Path(path)
    messages, _ = _read_sections(path, f'/{NODE_NAME}')
    if not messages:
        raise RosInputError(f'{path}: no section naming the node (e.g. '
                            f'"{PARAMS_FILE_KEY}:" or "/**:")')
    return _checked_values(path, messages)


def read_params_files(paths: list[str | Path] | tuple[str | Path, ...]
                      ) -> dict[str, ParamValue]:
    """Return the values several node parameter files set, merged in order as ROS does."""
    values: dict[str, ParamValue] = {}
    for path in paths:
        values.update(read_params_file(path))
    return values
