"""Launch the obstacle detector on a robot (ROS 2 launch file, installed by setup.py).

    ros2 launch obstacle_detection detector.launch.py            # Kinect v2, corridor.yaml
    ros2 launch obstacle_detection detector.launch.py camera:=generic
        depth_topic:=/camera/depth/image_rect_raw camera_info_topic:=/camera/depth/camera_info
    ros2 launch obstacle_detection detector.launch.py params_file:=/path/mine.yaml
        publish_ground:=true                                     # for a Nav2 clearing source

(each command on one line).

Arguments (``ros2 launch ... --show-args`` lists them):

- ``params_file``: the node's parameter YAML (default: the installed ``params/corridor.yaml``).
- ``camera``: ``kinect2`` remaps the node's inputs to iai_kinect2's / kinect2_bridge's SD
  topics (``/kinect2/sd/image_depth_rect``, ``/kinect2/sd/camera_info``); ``generic`` keeps the
  node's own names (``depth/image_raw``, ``depth/camera_info``, in ``namespace``).
- ``depth_topic`` / ``camera_info_topic``: when not empty, the input topics, whatever the preset.
- ``use_tf``: ``true`` sets the node's ``use_tf`` parameter (camera mount from TF instead of the
  mount parameters); ``false`` (default) passes nothing, so the params file decides.
- ``publish_ground``: ``true`` / ``false`` overrides the params file's ``publish_ground``
  (Nav2's clearing source needs ``true``); empty (default) keeps the file's value.
- ``use_sim_time``: ``true`` / ``false`` (default ``false``) sets rclpy's own ``use_sim_time``
  parameter of the node (the clock from ``/clock``, as every Nav2 bringup passes it); it
  overrides a params file's value.
- ``namespace``: the node's namespace (default none: outputs on ``/obstacles/...``). The shipped
  params files key the node as ``/**/obstacle_detector:``, so they apply in any namespace (a
  file of your own keyed ``obstacle_detector:`` names only the node without a namespace).

The ``launch`` packages (not among the pip-installed ROS wheels) are imported only where
the launch description is built, so tests import this file and run :func:`node_settings`.
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
    'kinect2': ('/kinect2/sd/image_depth_rect', '/kinect2/sd/camera_info'),
    'generic': ('depth/image_raw', 'depth/camera_info'),
}
#: (name, default, choices or None, description) of every launch argument; the params_file
#: default ('') means the installed DEFAULT_PARAMS_FILE.
ARGUMENTS = [
    ('params_file', '', None,
     'parameter YAML of the node (default: the installed params/corridor.yaml)'),
    ('camera', 'kinect2', ['kinect2', 'generic'],
     'input topics: kinect2 = kinect2_bridge SD topics, generic = depth/image_raw etc.'),
    ('depth_topic', '', None, 'depth Image topic, overriding the camera preset'),
    ('camera_info_topic', '', None, 'CameraInfo topic, overriding the camera preset'),
    ('use_tf', 'false', ['true', 'false'],
     'true: the camera mount from TF (node parameter use_tf); false: from the params file'),
    ('publish_ground', '', ['', 'true', 'false'],
     'override publish_ground (true for a Nav2 clearing source); empty: as the params file'),
    ('use_sim_time', 'false', ['true', 'false'],
     "rclpy's use_sim_time parameter of the node (the clock from /clock), as Nav2 passes it"),
    ('namespace', '', None, 'namespace of the node and its topics'),
]


def node_settings(values: dict[str, str], share_dir: str) -> dict[str, Any]:
    """Return the detector Node's keyword arguments for the launch arguments' ``values``.

    values: argument name -> value (strings, as launch gives them; missing ones take their
    ARGUMENTS default). share_dir: the package's installed share folder. Plain data, so tests
    run it without the ``launch`` packages. Raises ValueError naming an unknown camera preset.
    """
    values = {name: default for name, default, _, _ in ARGUMENTS} | dict(values)
    if values['camera'] not in CAMERA_PRESETS:
        raise ValueError(f'camera:={values["camera"]} is not a preset: expected one of '
                         f'{", ".join(CAMERA_PRESETS)}')
    params_file = values['params_file'] or f'{share_dir}/{DEFAULT_PARAMS_FILE}'
    depth_topic, info_topic = CAMERA_PRESETS[values['camera']]
    depth_topic = values['depth_topic'] or depth_topic
    info_topic = values['camera_info_topic'] or info_topic
    overrides: dict[str, bool] = {'use_sim_time': values['use_sim_time'] == 'true'}
    if values['use_tf'] == 'true':
        overrides['use_tf'] = True
    if values['publish_ground']:
        overrides['publish_ground'] = values['publish_ground'] == 'true'
    remaps = [(DEPTH_INPUT, depth_topic), (INFO_INPUT, info_topic)] + [
        (f'{DEPTH_INPUT}/{suffix}', f'{depth_topic}/{suffix}') for suffix in TRANSPORT_SUFFIXES]
    return {'package': PACKAGE, 'executable': EXECUTABLE, 'name': NODE_NAME,
            'namespace': values['namespace'],
            'parameters': [params_file, overrides],
            'remappings': remaps, 'output': 'screen', 'emulate_tty': True}


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
