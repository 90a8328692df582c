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
- ``namespace``: the node's namespace (default none: outputs on ``/obstacles/...``). A params
  file section must then name the node with it (``/<namespace>/obstacle_detector:``) or be
  ``/**:``.

The constants below are plain literals so that tests can read them without the ``launch``
packages (which the pip-installed ROS wheels do not include).
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

PACKAGE = 'obstacle_detection'
EXECUTABLE = 'detector'
NODE_NAME = 'obstacle_detector'
#: The default params file, relative to the package's share folder.
DEFAULT_PARAMS_FILE = 'params/corridor.yaml'
#: The node's input topics (relative names, as it subscribes).
DEPTH_INPUT = 'depth/image_raw'
INFO_INPUT = 'depth/camera_info'
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
    ('namespace', '', None, 'namespace of the node and its topics'),
]


def _detector(context: object) -> list:
    """Build the detector Node from the launch arguments' values."""
    def value(name: str) -> str:
        return LaunchConfiguration(name).perform(context)

    params_file = value('params_file') or FindPackageShare(PACKAGE).perform(context) + (
        '/' + DEFAULT_PARAMS_FILE)
    depth_topic, info_topic = CAMERA_PRESETS[value('camera')]
    depth_topic = value('depth_topic') or depth_topic
    info_topic = value('camera_info_topic') or info_topic
    overrides = {}
    if value('use_tf') == 'true':
        overrides['use_tf'] = True
    if value('publish_ground'):
        overrides['publish_ground'] = value('publish_ground') == 'true'
    return [Node(
        package=PACKAGE, executable=EXECUTABLE, name=NODE_NAME, namespace=value('namespace'),
        parameters=[params_file, overrides] if overrides else [params_file],
        remappings=[(DEPTH_INPUT, depth_topic), (INFO_INPUT, info_topic)],
        output='screen', emulate_tty=True)]


def generate_launch_description() -> LaunchDescription:
    """Declare the arguments and the detector node."""
    declared = [DeclareLaunchArgument(name, default_value=default, choices=choices,
                                      description=description)
                for name, default, choices, description in ARGUMENTS]
    return LaunchDescription([*declared, OpaqueFunction(function=_detector)])
