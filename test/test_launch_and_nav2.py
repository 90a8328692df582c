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

from obstacle_detection.cli import support as tool_support
from obstacle_detection.ros.compressed_depth import TRANSPORT_SUFFIXES
from obstacle_detection.ros.parameters import NODE_NAME, PARAMS_FILE_KEY
from obstacle_detection.sim.scenes import render_scene
from obstacle_detection.cli import bag_processor
from obstacle_detection.pipeline.clearing import clearing_cloud

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
            'namespace'} <= set(arguments)
    assert arguments['use_sim_time'] == ('false', ['true', 'false'])   # as Nav2's bringup
    assert set(arguments['camera'][1]) == set(launch.CAMERA_PRESETS) == {'kinect2', 'generic'}
    for name, (default, choices) in arguments.items():
        assert choices is None or default in choices, name


def test_kinect2_default_remaps_the_node_inputs_to_kinect2_bridge() -> None:
    launch = _launch_module()
    subscriptions = _node_topics('subscription')
    depth, info = tool_support.DEFAULT_DEPTH_TOPIC, tool_support.DEFAULT_INFO_TOPIC

    settings = launch.node_settings({}, '/opt/share/obstacle_detection')

    assert subscriptions == {'depth/image_raw': 'Image', 'depth/camera_info': 'CameraInfo'}
    assert sorted(settings['remappings']) == sorted(
        [('depth/image_raw', depth), ('depth/camera_info', info)]
        + [(f'depth/image_raw/{suffix}', f'{depth}/{suffix}') for suffix in TRANSPORT_SUFFIXES])
    assert settings['parameters'] == ['/opt/share/obstacle_detection/params/corridor.yaml',
                                      {'use_sim_time': False}]
    assert (settings['package'], settings['executable'], settings['name'],
            settings['namespace']) == (PACKAGE, 'detector', NODE_NAME, '')


def test_generic_camera_keeps_the_node_names_unless_topics_are_given() -> None:
    launch = _launch_module()

    plain = launch.node_settings({'camera': 'generic'}, '/s')
    given = launch.node_settings({'camera': 'generic', 'depth_topic': '/cam/depth',
                                  'camera_info_topic': '/cam/info'}, '/s')

    assert ('depth/image_raw', 'depth/image_raw') in plain['remappings']
    assert ('depth/camera_info', 'depth/camera_info') in plain['remappings']
    assert ('depth/image_raw', '/cam/depth') in given['remappings']
    assert ('depth/image_raw/compressedDepth', '/cam/depth/compressedDepth') in \
        given['remappings']
    assert ('depth/camera_info', '/cam/info') in given['remappings']


@pytest.mark.parametrize(('values', 'parameters'), [
    ({}, ['mine.yaml', {'use_sim_time': False}]),
    ({'use_tf': 'true'}, ['mine.yaml', {'use_sim_time': False, 'use_tf': True}]),
    ({'publish_ground': 'true'}, ['mine.yaml', {'use_sim_time': False, 'publish_ground': True}]),
    ({'publish_ground': 'false', 'use_tf': 'true'},
     ['mine.yaml', {'use_sim_time': False, 'use_tf': True, 'publish_ground': False}]),
    ({'use_sim_time': 'true'}, ['mine.yaml', {'use_sim_time': True}]),
])
def test_use_sim_time_is_always_passed_use_tf_and_publish_ground_only_when_given(
        values: dict[str, str], parameters: list) -> None:
    settings = _launch_module().node_settings({'params_file': 'mine.yaml', **values}, '/s')

    assert settings['parameters'] == parameters


def test_an_unknown_camera_preset_is_refused_by_name() -> None:
    with pytest.raises(ValueError, match='camera:=realsense is not a preset'):
        _launch_module().node_settings({'camera': 'realsense'}, '/s')


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
# The Nav2 costmap example


def test_nav2_sources_are_the_nodes_clouds() -> None:
    clouds = {name for name, kind in _node_topics('publisher').items() if kind == 'PointCloud2'}
    sources = _sources()

    assert {topic.lstrip('/') for topic in sources} == {'obstacles/points',
                                                        'obstacles/clearing_points'}
    assert {topic.lstrip('/') for topic in sources} <= clouds
    assert all(topic.startswith('/') for topic in sources)  # the node runs without namespace
    assert all(source['data_type'] == 'PointCloud2' for source in sources.values())
    points, clearing = sources['/obstacles/points'], sources['/obstacles/clearing_points']
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
    points = _sources()['/obstacles/points']

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
    points = _sources()['/obstacles/points']

    # the voxel layer measures the marking range in 3-D from the cloud frame's origin
    assert points['obstacle_max_range'] > math.hypot(reach, top)
    assert points['obstacle_max_range'] > math.hypot(reach, _lowest_obstacle_m(params))
    assert points['obstacle_min_range'] <= float(params['min_range_m'])
    assert _sources()['/obstacles/clearing_points']['raytrace_min_range'] == 0.0
    assert min(costmap['width'], costmap['height']) / 2 >= reach
    assert costmap['resolution'] == pytest.approx(float(params['costmap_resolution_m']))
    assert costmap['robot_base_frame'] == params['cloud_frame_id']


@pytest.mark.parametrize('scene', ['corridor', 'step_down'])
def test_every_detector_point_passes_the_voxel_layer_filters(scene: str) -> None:
    values = bag_processor.node_param_values(CORRIDOR)
    config = bag_processor.config_from_values(values, str(CORRIDOR))
    params = config.detector.params
    frame = render_scene(scene, seed=1, height_m=params.camera_height_m,
                         pitch_rad=params.camera_pitch_rad, roll_rad=params.camera_roll_rad)
    result = config.detector.process(frame.depth_mm, frame.intrinsics)
    layer, source = _layer(), _sources()['/obstacles/points']
    points = result.obstacle_points.astype(np.float64)
    clearing = clearing_cloud(result, stride_px=config.clearing_stride_px,
                              range_m=config.clearing_range_m)

    assert points.shape[0] > 100 and clearing.shape[0] > 1000
    z = points[:, 2]
    assert z.min() >= max(layer['min_obstacle_height'], source['min_obstacle_height'])
    assert z.max() <= min(layer['max_obstacle_height'], source['max_obstacle_height'])
    assert np.linalg.norm(points, axis=1).max() < source['obstacle_max_range']
    # clearing rays from the camera (the cloud frame's origin) are no longer than Nav2 traces
    assert np.linalg.norm(clearing, axis=1).max() <= \
        _sources()['/obstacles/clearing_points']['raytrace_max_range']
