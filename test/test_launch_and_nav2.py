"""The launch file and the Nav2 costmap example agree with the node, setup.py and corridor.yaml.

There is no ``launch`` package in the pip-installed ROS wheels: the launch file imports it only
where it builds the launch description, so it is imported here and its ``node_settings`` (the
detector Node's arguments from the launch arguments) run; what it names must be installed by
setup.py and be the node's topics. The Nav2 YAML is parsed and compared with the node's topic names
and with params/corridor.yaml; the detector's clouds of rendered scenes pass the voxel layer's
height and range filters (as Nav2 Jazzy's ObservationBuffer and VoxelLayer apply them).
test/test_nav2_sequences.py plays the layer itself over rendered sequences.
"""

from __future__ import annotations

import ast
import importlib.util
import math
import py_compile
import sysconfig
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest
import yaml

import ros_env
from obstacle_detection.cli import support as tool_support
from obstacle_detection.ros.compressed_depth import TRANSPORT_SUFFIXES
from obstacle_detection.ros.parameters import NODE_NAME, PARAMS_FILE_KEY
from obstacle_detection.sim.scenes import render_scene
from obstacle_detection.cli import bag_processor

REPO = Path(__file__).resolve().parents[1]
LAUNCH = REPO / 'launch' / 'detector.launch.py'
NAV2 = REPO / 'params' / 'nav2_costmap.yaml'
CORRIDOR = REPO / 'params' / 'corridor.yaml'
PACKAGE = 'obstacle_detection'


def _launch_module() -> ModuleType:
    """Import the launch file (it imports the ``launch`` packages only when launched)."""
    spec = importlib.util.spec_from_file_location('detector_launch', LAUNCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _node_topics(method: str) -> dict[str, str]:
    """Topic -> message type of the node's ``create_<method>`` calls (node.py) and outputs."""
    tree = ast.parse((REPO / 'obstacle_detection' / 'ros' / 'node.py').read_text(encoding='utf-8'))
    topics = {}
    for call in ast.walk(tree):
        if isinstance(call, ast.Call) and isinstance(call.func, ast.Attribute) \
                and call.func.attr == f'create_{method}' and len(call.args) >= 2 \
                and isinstance(call.args[1], ast.Constant) and isinstance(call.args[0], ast.Name):
            topics[call.args[1].value] = call.args[0].id
    from obstacle_detection.ros.node import DEPTH_TRANSPORTS, OUTPUTS

    if method == 'subscription':   # the depth topic follows depth_transport (raw by default)
        msg_type, topic = DEPTH_TRANSPORTS['raw']
        topics[topic] = msg_type.__name__
    else:   # the outputs' publishers are made from their table
        topics.update({topic: kind.__name__ for kind, topic, _ in OUTPUTS.values()})
    return topics


def _corridor() -> dict[str, Any]:
    return yaml.safe_load(CORRIDOR.read_text(encoding='utf-8'))[PARAMS_FILE_KEY]['ros__parameters']


def _costmap() -> dict[str, Any]:
    return yaml.safe_load(NAV2.read_text(encoding='utf-8'))['local_costmap']['local_costmap'][
        'ros__parameters']


def _layer() -> dict[str, Any]:
    """Return the costmap's VoxelLayer (the one obstacle layer of the example)."""
    costmap = _costmap()
    layers = [costmap[name] for name in costmap['plugins']
              if costmap[name]['plugin'] == 'nav2_costmap_2d::VoxelLayer']
    assert len(layers) == 1
    return layers[0]


def _sources() -> dict[str, dict[str, Any]]:
    """Topic -> settings of each observation source of the voxel layer."""
    layer = _layer()
    return {layer[name]['topic']: layer[name] for name in layer['observation_sources'].split()}


# --------------------------------------------------------------------------------------------
# The launch file


def test_launch_file_compiles_and_defines_the_entry_point(tmp_path: Path) -> None:
    py_compile.compile(str(LAUNCH), cfile=str(tmp_path / 'launch.pyc'), doraise=True)
    tree = ast.parse(LAUNCH.read_text(encoding='utf-8'))
    functions = {node.name for node in tree.body if isinstance(node, ast.FunctionDef)}
    assert 'generate_launch_description' in functions


def test_launch_arguments_and_their_choices() -> None:
    launch = _launch_module()
    arguments = {name: (default, choices) for name, default, choices, _ in launch.ARGUMENTS}

    assert {'params_file', 'use_tf', 'camera', 'publish_ground', 'use_sim_time',
            'namespace', 'log_level'} <= set(arguments)
    # booleans carry no choices: DeclareLaunchArgument.execute (launch/actions/
    # declare_launch_argument.py) compares choices as exact strings, refusing Nav2's 'True'
    for name in ('use_sim_time', 'use_tf', 'publish_ground'):
        assert arguments[name][1] is None, name
    assert arguments['use_sim_time'][0] == ''       # not passed unless given
    assert arguments['use_tf'][0] == 'true'         # on a robot the mount comes from TF
    assert arguments['camera'][0] == 'generic'
    assert set(arguments['camera'][1]) == set(launch.CAMERA_PRESETS) == {
        'generic', 'realsense', 'kinect2'}
    for name, (default, choices) in arguments.items():
        assert choices is None or default in choices, name


def test_default_launch_keeps_the_node_topics_and_takes_the_mount_from_tf() -> None:
    launch = _launch_module()
    subscriptions = _node_topics('subscription')

    settings = launch.node_settings({}, '/opt/share/obstacle_detection')

    assert subscriptions == {'depth/image_raw': 'Image', 'depth/camera_info': 'CameraInfo'}
    assert sorted(settings['remappings']) == sorted(
        [(topic, topic) for topic in subscriptions]
        + [(f'depth/image_raw/{suffix}', f'depth/image_raw/{suffix}')
           for suffix in TRANSPORT_SUFFIXES])
    assert settings['parameters'] == ['/opt/share/obstacle_detection/params/corridor.yaml',
                                      {'use_tf': True}]
    assert settings['ros_arguments'] == ['--log-level', 'info']
    assert (settings['package'], settings['executable'], settings['name'],
            settings['namespace']) == (PACKAGE, 'detector', NODE_NAME, '')


@pytest.mark.parametrize(('camera', 'depth', 'info'), [
    ('kinect2', tool_support.DEFAULT_DEPTH_TOPIC, tool_support.DEFAULT_INFO_TOPIC),
    # realsense2_camera (ros2-master): rs_launch.py's camera_namespace and camera_name both
    # default to 'camera'; its README lists /camera/camera/depth/image_rect_raw and
    # /camera/camera/depth/camera_info
    ('realsense', '/camera/camera/depth/image_rect_raw', '/camera/camera/depth/camera_info'),
])
def test_camera_presets_remap_the_inputs_and_their_transports(camera: str, depth: str,
                                                              info: str) -> None:
    settings = _launch_module().node_settings({'camera': camera}, '/s')

    assert sorted(settings['remappings']) == sorted(
        [('depth/image_raw', depth), ('depth/camera_info', info)]
        + [(f'depth/image_raw/{suffix}', f'{depth}/{suffix}') for suffix in TRANSPORT_SUFFIXES])


def test_given_topics_override_the_preset() -> None:
    launch = _launch_module()

    given = launch.node_settings({'camera': 'realsense', 'depth_topic': '/cam/depth',
                                  'camera_info_topic': '/cam/info'}, '/s')

    assert ('depth/image_raw', '/cam/depth') in given['remappings']
    assert ('depth/image_raw/compressedDepth', '/cam/depth/compressedDepth') in \
        given['remappings']
    assert ('depth/camera_info', '/cam/info') in given['remappings']


@pytest.mark.parametrize(('values', 'overrides'), [
    ({}, {'use_tf': True}),
    ({'use_tf': 'false'}, {'use_tf': False}),
    ({'use_tf': 'False', 'publish_ground': 'True'}, {'use_tf': False, 'publish_ground': True}),
    ({'publish_ground': 'false'}, {'use_tf': True, 'publish_ground': False}),
    # nav2_bringup's launch files pass 'True' / 'False' (tb3_simulation_launch.py declares
    # use_sim_time 'true', bringup_launch.py 'false', both handed on as given)
    ({'use_sim_time': 'True'}, {'use_tf': True, 'use_sim_time': True}),
    ({'use_sim_time': 'False'}, {'use_tf': True, 'use_sim_time': False}),
    ({'use_sim_time': ' true '}, {'use_tf': True, 'use_sim_time': True}),
    ({'use_sim_time': '1', 'use_tf': '0'}, {'use_tf': False, 'use_sim_time': True}),
])
def test_booleans_read_as_launch_reads_a_condition(values: dict[str, str],
                                                   overrides: dict[str, bool]) -> None:
    settings = _launch_module().node_settings({'params_file': 'mine.yaml', **values}, '/s')

    assert settings['parameters'] == ['mine.yaml', overrides]


@pytest.mark.parametrize(('name', 'value'), [('use_sim_time', 'yes'), ('use_tf', 'on'),
                                             ('publish_ground', 'TRUE!')])
def test_a_bad_boolean_is_refused_by_name(name: str, value: str) -> None:
    with pytest.raises(ValueError, match=f'{name}:={value} is not a boolean'):
        _launch_module().node_settings({name: value}, '/s')


def test_log_level_reaches_the_node_arguments_and_a_bad_one_is_refused() -> None:
    launch = _launch_module()

    assert launch.node_settings({'log_level': 'DEBUG'}, '/s')['ros_arguments'] == [
        '--log-level', 'debug']
    with pytest.raises(ValueError, match='log_level:=loud is not a level'):
        launch.node_settings({'log_level': 'loud'}, '/s')


def test_an_unknown_camera_preset_is_refused_by_name() -> None:
    with pytest.raises(ValueError, match='camera:=zed is not a preset'):
        _launch_module().node_settings({'camera': 'zed'}, '/s')


def test_launch_node_name_is_the_params_files_section() -> None:
    corridor = yaml.safe_load(CORRIDOR.read_text(encoding='utf-8'))

    assert _launch_module().NODE_NAME == NODE_NAME and list(corridor) == [PARAMS_FILE_KEY]


def test_everything_the_launch_file_names_is_installed(prefix: Path) -> None:
    share = prefix / 'share' / PACKAGE
    settings = _launch_module().node_settings({}, str(share))

    assert (prefix / 'lib' / settings['package'] / settings['executable']).is_file()
    assert Path(settings['parameters'][0]).is_file()
    assert (share / 'launch' / LAUNCH.name).read_bytes() == LAUNCH.read_bytes()
    assert (share / 'params' / NAV2.name).read_bytes() == NAV2.read_bytes()
    relative = Path(sysconfig.get_path('purelib')).relative_to(sysconfig.get_path('data'))
    assert (prefix / relative / PACKAGE / 'ros' / 'compressed_depth.py').is_file()


# --------------------------------------------------------------------------------------------
# What the node gets: launch_ros's command line, resolved by rcl
#
# launch_ros (jazzy) turns a Node action into a command line; rcl (through rclpy.init) then
# resolves the node's name, namespace and parameters from it. The command line is ported from
# launch_ros/actions/node.py: Node.__init__ (executable, then ``ros_arguments`` after their own
# ``--ros-args``, then ``--ros-args -r __node:=NAME``), Node._perform_substitutions (``-r
# __ns:=NS`` from prefix_namespace and make_namespace_absolute of
# launch_ros/utilities/namespace_utils.py; the group's SetParameter values, the
# ``global_params`` of launch_ros/actions/set_parameter.py SetParameter.execute, as ``-p
# name:=value`` FIRST, "so they can be overridden with specific parameters of this Node"; then
# each parameters entry, a dict written by Node._create_params_file_from_dict under the node's
# full name; then ``-r from:=to``). The resolution is rclpy's own, on a probe node.


def _prefix_namespace(base: str | None, ns: str | None) -> str | None:
    """launch_ros.utilities.namespace_utils.prefix_namespace."""
    if base is None and ns is None:
        return None
    if ns is None:
        combined = base
    elif not base or ns.startswith('/'):
        combined = ns
    else:
        combined = ('' if base == '/' else base) + '/' + ns
    return combined if combined == '/' else combined.rstrip('/')


def _launch_ros_arguments(settings: dict[str, Any], tmp_path: Path, *,
                          global_params: tuple[tuple[str, str], ...] = (),
                          pushed_namespace: str | None = None) -> tuple[list[str], str]:
    """Return (the node's arguments after its executable, its full name) as launch_ros does."""
    namespace = _prefix_namespace(pushed_namespace, settings['namespace'])
    namespace = '/' + namespace if not namespace.startswith('/') else namespace
    full_name = _prefix_namespace(namespace, settings['name'])
    args = ['--ros-args', *settings['ros_arguments'],
            '--ros-args', '-r', f'__node:={settings["name"]}', '-r', f'__ns:={namespace}']
    for name, value in global_params:
        args += ['-p', f'{name}:={value}']
    for entry in settings['parameters']:
        if isinstance(entry, dict):   # a new file each time, as NamedTemporaryFile
            path = tmp_path / f'launch_params_{len(list(tmp_path.glob("launch_params_*")))}.yaml'
            path.write_text(yaml.dump({full_name: {'ros__parameters': entry}}))
            entry = str(path)
        args += ['--params-file', entry]
    for source, target in settings['remappings']:
        args += ['-r', f'{source}:={target}']
    return args, full_name


def _resolved(args: list[str]) -> dict[str, Any]:
    """Return what rcl gives a node started with ``args``: name, parameters, topics, level."""
    from rclpy.node import Node

    with ros_env.rclpy_context('test_launch_and_nav2', ['detector', *args]) as context:
        node = Node('probe', context=context, start_parameter_services=False,
                    automatically_declare_parameters_from_overrides=True)
        try:
            return {'name': node.get_fully_qualified_name(),
                    'parameters': {name: p.value for name, p in
                                   node.get_parameters_by_prefix('').items()},
                    'depth': node.resolve_topic_name('depth/image_raw'),
                    'info': node.resolve_topic_name('depth/camera_info'),
                    'log_level': node.get_logger().get_effective_level()}
        finally:
            node.destroy_node()


@pytest.mark.parametrize(('given', 'clock'), [('True', True), ('False', False),
                                              ('true', True), ('false', False)])
def test_use_sim_time_given_reaches_the_node(given: str, clock: bool, tmp_path: Path) -> None:
    settings = _launch_module().node_settings(
        {'params_file': str(CORRIDOR), 'use_sim_time': given}, '/s')
    args, _ = _launch_ros_arguments(settings, tmp_path)

    assert _resolved(args)['parameters']['use_sim_time'] is clock


@pytest.mark.parametrize('parent', ['True', 'False'])
def test_a_parents_set_parameter_use_sim_time_reaches_the_node(parent: str,
                                                               tmp_path: Path) -> None:
    """GroupAction([SetParameter('use_sim_time', use_sim_time), IncludeLaunchDescription(...)])."""
    launch = _launch_module()
    given = launch.node_settings({'params_file': str(CORRIDOR)}, '/s')
    # what this launch file passed before: use_sim_time always, false unless given
    always = launch.node_settings({'params_file': str(CORRIDOR)}, '/s')
    always['parameters'][1]['use_sim_time'] = False

    args, _ = _launch_ros_arguments(given, tmp_path, global_params=(('use_sim_time', parent),))
    old_args, _ = _launch_ros_arguments(always, tmp_path,
                                        global_params=(('use_sim_time', parent),))

    assert 'use_sim_time' not in given['parameters'][1]
    assert _resolved(args)['parameters']['use_sim_time'] is (parent == 'True')
    assert _resolved(old_args)['parameters']['use_sim_time'] is False   # the parent was lost


@pytest.mark.parametrize(('pushed', 'namespace', 'full_name'), [
    (None, '', f'/{NODE_NAME}'),
    (None, 'front', f'/front/{NODE_NAME}'),
    ('robot1', 'front', f'/robot1/front/{NODE_NAME}'),   # PushROSNamespace in the parent
    ('robot1', '', f'/robot1/{NODE_NAME}'),
])
def test_in_a_namespace_the_params_file_and_overrides_still_apply(
        pushed: str | None, namespace: str, full_name: str, tmp_path: Path) -> None:
    launch = _launch_module()
    settings = launch.node_settings({'params_file': str(CORRIDOR), 'namespace': namespace,
                                     'use_sim_time': 'True', 'use_tf': 'false',
                                     'camera': 'realsense', 'log_level': 'debug'}, '/s')
    args, expected_name = _launch_ros_arguments(settings, tmp_path, pushed_namespace=pushed)
    from rclpy.logging import LoggingSeverity

    node = _resolved(args)

    assert node['name'] == expected_name == full_name
    parameters = node['parameters']
    corridor = _corridor()
    # the file's section /**/obstacle_detector matches in any namespace
    assert parameters['camera_height_m'] == corridor['camera_height_m']
    assert parameters['median_kernel'] == corridor['median_kernel']
    # the launch's overrides, keyed by the full name, too
    assert (parameters['use_sim_time'], parameters['use_tf']) == (True, False)
    assert (node['depth'], node['info']) == ('/camera/camera/depth/image_rect_raw',
                                             '/camera/camera/depth/camera_info')
    assert node['log_level'] == LoggingSeverity.DEBUG


def test_generic_topics_follow_the_namespace(tmp_path: Path) -> None:
    settings = _launch_module().node_settings({'params_file': str(CORRIDOR),
                                               'namespace': 'front'}, '/s')
    args, _ = _launch_ros_arguments(settings, tmp_path, pushed_namespace='robot1')

    node = _resolved(args)

    assert (node['depth'], node['info']) == ('/robot1/front/depth/image_raw',
                                             '/robot1/front/depth/camera_info')
    assert (node['parameters']['use_tf'], node['parameters']['use_sim_time']) == (True, False)


# --------------------------------------------------------------------------------------------
# The Nav2 costmap example


def test_nav2_sources_are_the_nodes_clouds() -> None:
    clouds = {name for name, kind in _node_topics('publisher').items() if kind == 'PointCloud2'}
    sources = _sources()

    assert {topic.lstrip('/') for topic in sources} == {'obstacles/marking_points',
                                                        'obstacles/clearing_points'}
    assert {topic.lstrip('/') for topic in sources} <= clouds
    assert all(topic.startswith('/') for topic in sources)  # the node runs without namespace
    assert all(source['data_type'] == 'PointCloud2' for source in sources.values())
    points = sources['/obstacles/marking_points']
    clearing = sources['/obstacles/clearing_points']
    assert (points['marking'], points['clearing']) == (True, False)
    assert (clearing['marking'], clearing['clearing']) == (False, True)
    # rays start at the cloud frame's origin: the camera for the clearing cloud (its frame is
    # the depth image's), so no sensor_frame may move them elsewhere
    assert all(source['sensor_frame'] == '' for source in sources.values())


def test_nav2_is_told_when_the_clouds_stop_and_leaves_no_unknown_space() -> None:
    assert all(source['expected_update_rate'] > 0.0 for source in _sources().values())
    assert all(source['observation_persistence'] == 0.0 for source in _sources().values())
    assert _costmap()['track_unknown_space'] is False


def test_corridor_publishes_the_clearing_cloud_nav2_reads() -> None:
    params = _corridor()

    assert params['publish_clearing'] is True
    assert _sources()['/obstacles/clearing_points']['raytrace_max_range'] >= \
        params['clearing_range_m']


def _lowest_obstacle_m(params: dict[str, Any]) -> float:
    """Return the lowest z of a detector point: TDBG, or the robot-level rules' drop view."""
    lowest = float(params['tdbg_m'])
    if params.get('robot_level') and 'drop_view_m' in params:
        lowest = min(lowest, -float(params['drop_view_m']))
    return lowest


def _grid_top_m(layer: dict[str, Any]) -> float:
    """Top of the voxel grid: a point at or above it is not marked (worldToMap3D) [m]."""
    return layer['origin_z'] + layer['z_voxels'] * layer['z_resolution']


def test_nav2_heights_agree_with_the_corridor_region_of_interest() -> None:
    params = _corridor()
    top = float(params['camera_height_m']) + float(params['smar_m'])
    layer = _layer()
    points = _sources()['/obstacles/marking_points']

    for settings in (layer, points):
        assert settings['max_obstacle_height'] == pytest.approx(top)
        assert settings['min_obstacle_height'] <= _lowest_obstacle_m(params)
    assert 1 <= layer['z_voxels'] <= 16                   # nav2_voxel_grid's 16 bits
    # voxel 0 holds what lies below the floor (drop view, marked at origin_z); the floor band
    # starts at voxel 1: rays to the floor end 0.1 m short of it, above the drop marks
    assert layer['origin_z'] <= 0.0 < layer['origin_z'] + layer['z_resolution'] + 1e-9
    assert _grid_top_m(layer) > top                       # every mark fits in the grid
    # rays start at the camera, inside the grid below its raytrace top (origin + (n - 0.5) dz)
    assert layer['origin_z'] < float(params['camera_height_m']) < \
        layer['origin_z'] + (layer['z_voxels'] - 0.5) * layer['z_resolution']
    clearing = _sources()['/obstacles/clearing_points']
    assert clearing['min_obstacle_height'] <= _lowest_obstacle_m(params)
    assert clearing['max_obstacle_height'] >= _grid_top_m(layer)   # cut at the top, not lost


def test_nav2_ranges_and_window_cover_the_corridor_region_of_interest() -> None:
    params = _corridor()
    costmap = _costmap()
    reach = math.hypot(float(params['max_range_m']), float(params['lateral_limit_m']))
    top = float(params['camera_height_m']) + float(params['smar_m'])
    points = _sources()['/obstacles/marking_points']

    # the voxel layer measures the marking range in 3-D from the cloud frame's origin
    assert points['obstacle_max_range'] > math.hypot(reach, top)
    assert points['obstacle_max_range'] > math.hypot(reach, _lowest_obstacle_m(params))
    assert points['obstacle_min_range'] <= float(params['min_range_m'])
    assert _sources()['/obstacles/clearing_points']['raytrace_min_range'] == 0.0
    assert min(costmap['width'], costmap['height']) / 2 >= reach
    assert costmap['resolution'] == pytest.approx(float(params['costmap_resolution_m']))
    assert costmap['robot_base_frame'] == params['cloud_frame_id']
    # the node matches its marks and rays to the layer's cell and voxel (clearing.nav2_clouds)
    assert _layer()['z_resolution'] == pytest.approx(float(params['clearing_voxel_m']))


@pytest.mark.parametrize('scene', ['corridor', 'step_down'])
def test_every_detector_point_passes_the_voxel_layer_filters(scene: str) -> None:
    values = bag_processor.node_param_values(CORRIDOR)
    config = bag_processor.config_from_values(values, str(CORRIDOR))
    params = config.detector.params
    frame = render_scene(scene, seed=1, height_m=params.camera_height_m,
                         pitch_rad=params.camera_pitch_rad, roll_rad=params.camera_roll_rad)
    result = config.detector.process(frame.depth_mm, frame.intrinsics)
    layer, source = _layer(), _sources()['/obstacles/marking_points']
    marks, clearing = config.nav2_clouds(result)     # what the node sends the voxel layer
    points = marks.astype(np.float64)

    assert points.shape[0] > 100 and clearing.shape[0] > 1000
    z = points[:, 2]
    assert z.min() >= max(layer['min_obstacle_height'], source['min_obstacle_height'])
    assert z.max() <= min(layer['max_obstacle_height'], source['max_obstacle_height'])
    assert np.linalg.norm(points, axis=1).max() < source['obstacle_max_range']
    # clearing rays from the camera (the cloud frame's origin) are no longer than Nav2 traces
    assert np.linalg.norm(clearing, axis=1).max() <= \
        _sources()['/obstacles/clearing_points']['raytrace_max_range']
