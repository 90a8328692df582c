"""Launch the obstacle detector on a robot (ROS 2 launch file, installed by setup.py).

    ros2 launch obstacle_detection detector.launch.py      # generic topics, mount from TF
    ros2 launch obstacle_detection detector.launch.py camera:=realsense
    ros2 launch obstacle_detection detector.launch.py depth_topic:=/cam/depth/image_rect_raw
        camera_info_topic:=/cam/depth/camera_info use_tf:=false params_file:=/path/mine.yaml

(each command on one line). Included from a bringup (as nav2_bringup includes its launch files):
``IncludeLaunchDescription(PythonLaunchDescriptionSource(<share>/launch/detector.launch.py),
launch_arguments={'use_sim_time': use_sim_time, ...}.items())``.

Arguments (``ros2 launch ... --show-args`` lists them):

- ``params_file``: the node's parameter YAML (default: the installed ``params/corridor.yaml``).
- ``camera``: the input topics. ``generic`` (default) keeps the node's own names,
  ``depth/image_raw`` and ``depth/camera_info`` in ``namespace``; ``realsense``:
  realsense2_camera's ``rs_launch.py`` defaults (``/camera/camera/depth/image_rect_raw``,
  ``/camera/camera/depth/camera_info``); ``kinect2``: kinect2_bridge's SD topics
  (``/kinect2/sd/image_depth_rect``, ``/kinect2/sd/camera_info``; iai_kinect2 has no Jazzy
  release: its bags, or a port keeping its names).
- ``depth_topic`` / ``camera_info_topic``: when not empty, the input topics, whatever the preset.
- ``use_tf``: ``true`` (default) takes the camera mount from TF (the robot's URDF through
  robot_state_publisher: base frame <- the depth image's frame_id); ``false`` takes it from the
  params file's ``camera_*`` parameters.
- ``publish_ground``: ``true`` / ``false`` overrides the params file's ``publish_ground``;
  empty (default) keeps the file's value.
- ``use_sim_time``: ``true`` / ``false`` sets rclpy's ``use_sim_time`` of the node; empty
  (default) passes nothing, so a parent's ``SetParameter('use_sim_time', ...)`` (as Nav2's
  navigation_launch.py sets it) or the params file decides.
- ``namespace``: the node's namespace (default none: outputs on ``/obstacles/...``). The shipped
  params files key the node as ``/**/obstacle_detector:``, so they apply in any namespace (a
  file of your own keyed ``obstacle_detector:`` names only the node without a namespace).
- ``log_level``: the node's log level (``debug``, ``info``, ``warn``, ``error``, ``fatal``), as
  nav2_bringup's ``log_level``.

Booleans follow launch's own reading of a condition (launch/conditions/
evaluate_condition_expression_impl.py): ``true``/``1`` and ``false``/``0`` in any case, so Nav2's
``True``/``False`` pass. The ``launch`` packages (not among the pip-installed ROS wheels) are
imported only where the launch description is built, so tests import this file and run
:func:`node_settings`.
"""

from typing import Any


PACKAGE = 'obstacle_detection'
EXECUTABLE = 'detector'
NODE_NAME = 'obstacle_detector'
#: The default params file, relative to the package's share folder.
DEFAULT_PARAMS_FILE = 'params/corridor.yaml'
#: The node's input topics (relative names, as it subscribes).
DEPTH_INPUT = 'depth/image_raw'
INFO_INPUT = 'depth/camera_info'
#: image_transport's compressed topics under a depth topic: remapped along with it, so that a
#: node subscribing to ``depth/image_raw/compressedDepth`` (CompressedImage) follows the preset.
TRANSPORT_SUFFIXES = ('compressedDepth', 'compressed')
#: Camera preset -> (depth topic, camera info topic) the inputs are remapped to.
CAMERA_PRESETS = {
    'generic': (DEPTH_INPUT, INFO_INPUT),
    'realsense': ('/camera/camera/depth/image_rect_raw', '/camera/camera/depth/camera_info'),
    'kinect2': ('/kinect2/sd/image_depth_rect', '/kinect2/sd/camera_info'),
}
#: launch's strings of a true and a false condition (compared stripped and lower-case).
TRUE_VALUES, FALSE_VALUES = ('true', '1'), ('false', '0')
#: rcutils' severities, as ``--log-level`` takes them.
LOG_LEVELS = ('debug', 'info', 'warn', 'error', 'fatal')
#: (name, default, choices or None, description) of every launch argument; the params_file
#: default ('') means the installed DEFAULT_PARAMS_FILE. Booleans have no choices (launch
#: compares choices as exact strings, which would refuse Nav2's 'True'): node_settings checks.
ARGUMENTS = [
    ('params_file', '', None,
     'parameter YAML of the node (default: the installed params/corridor.yaml)'),
    ('camera', 'generic', list(CAMERA_PRESETS),
     'input topics: generic = depth/image_raw, depth/camera_info; realsense = rs_launch.py '
     'defaults (/camera/camera/depth/...); kinect2 = kinect2_bridge SD topics'),
    ('depth_topic', '', None, 'depth Image topic, overriding the camera preset'),
    ('camera_info_topic', '', None, 'CameraInfo topic, overriding the camera preset'),
    ('use_tf', 'true', None,
     'true: the camera mount from TF (robot URDF); false: from the params file'),
    ('publish_ground', '', None,
     'true/false: override publish_ground; empty: as the params file'),
    ('use_sim_time', '', None,
     "true/false: rclpy's use_sim_time of the node; empty: not passed (a parent's "
     'SetParameter or the params file decides)'),
    ('namespace', '', None, 'namespace of the node and its topics'),
    ('log_level', 'info', None, 'log level of the node: debug, info, warn, error or fatal'),
]


def launch_bool(name: str, value: str) -> bool:
    """Read a boolean launch argument as launch reads a condition; ValueError names it."""
    text = value.strip().lower()
    if text in TRUE_VALUES + FALSE_VALUES:
        return text in TRUE_VALUES
    raise ValueError(f'{name}:={value} is not a boolean: expected true, false, 1 or 0 '
                     '(any case)')


def node_settings(values: dict[str, str], share_dir: str) -> dict[str, Any]:
    """Return the detector Node's keyword arguments for the launch arguments' ``values``.

    values: argument name -> value (strings, as launch gives them; missing ones take their
    ARGUMENTS default). share_dir: the package's installed share folder. Plain data, so tests
    run it without the ``launch`` packages. Raises ValueError naming a bad argument.
    """
    values = {name: default for name, default, _, _ in ARGUMENTS} | dict(values)
    if values['camera'] not in CAMERA_PRESETS:
        raise ValueError(f'camera:={values["camera"]} is not a preset: expected one of '
                         f'{", ".join(CAMERA_PRESETS)}')
    log_level = values['log_level'].strip().lower()
    if log_level not in LOG_LEVELS:
        raise ValueError(f'log_level:={values["log_level"]} is not a level: expected one of '
                         f'{", ".join(LOG_LEVELS)}')
    params_file = values['params_file'] or f'{share_dir}/{DEFAULT_PARAMS_FILE}'
    depth_topic, info_topic = CAMERA_PRESETS[values['camera']]
    depth_topic = values['depth_topic'] or depth_topic
    info_topic = values['camera_info_topic'] or info_topic
    overrides = {'use_tf': launch_bool('use_tf', values['use_tf'])}
    for name in ('publish_ground', 'use_sim_time'):   # passed only when given
        if values[name].strip():
            overrides[name] = launch_bool(name, values[name])
    remaps = [(DEPTH_INPUT, depth_topic), (INFO_INPUT, info_topic)] + [
        (f'{DEPTH_INPUT}/{suffix}', f'{depth_topic}/{suffix}') for suffix in TRANSPORT_SUFFIXES]
    return {'package': PACKAGE, 'executable': EXECUTABLE, 'name': NODE_NAME,
            'namespace': values['namespace'],
            'parameters': [params_file, overrides],
            'remappings': remaps, 'ros_arguments': ['--log-level', log_level],
            'output': 'screen', 'emulate_tty': True}


def _detector(context: Any) -> list:
    """Build the detector Node from the launch arguments' values (an OpaqueFunction)."""
    from launch.substitutions import LaunchConfiguration
    from launch_ros.actions import Node
    from launch_ros.substitutions import FindPackageShare

    values = {name: LaunchConfiguration(name).perform(context) for name, *_ in ARGUMENTS}
    return [Node(**node_settings(values, FindPackageShare(PACKAGE).perform(context)))]


def generate_launch_description() -> Any:
    """Declare the arguments and the detector node (a launch.LaunchDescription)."""
    from launch import LaunchDescription
    from launch.actions import DeclareLaunchArgument, OpaqueFunction

    declared = [DeclareLaunchArgument(name, default_value=default, choices=choices,
                                      description=description)
                for name, default, choices, description in ARGUMENTS]
    return LaunchDescription([*declared, OpaqueFunction(function=_detector)])
