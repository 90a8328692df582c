"""rviz/obstacle_detection.rviz shows what the node publishes, as RViz (Jazzy) reads it.

The display classes and property names are rviz_default_plugins' on ros2/rviz ``jazzy``
(``rviz_default_plugins/plugins_description.xml``; the properties each display creates in
its constructor: ``displays/map/map_display.cpp``, ``displays/pointcloud/
point_cloud_common.cpp`` and ``transformers/flat_color_pc_transformer.cpp``,
``displays/image/image_display.cpp``, ``displays/grid/grid_display.cpp``,
``displays/tf/tf_display.cpp``; a topic's QoS properties: ``rviz_common/properties/
qos_profile_property.cpp``). RViz ignores a property name it does not know, so each is checked
here. The node's publishers are the running node's own (all outputs switched on), their QoS
read from the graph; a subscription that asks reliable meets only a reliable publisher, one
that asks transient local only a transient-local one.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest
import ros_env
import yaml
from rclpy.qos import DurabilityPolicy, ReliabilityPolicy

REPO = ros_env.REPO_ROOT
RVIZ = REPO / 'rviz' / 'obstacle_detection.rviz'
CORRIDOR = REPO / 'params' / 'corridor.yaml'

TOPIC_KEYS = {'Value', 'Depth', 'History Policy', 'Reliability Policy', 'Durability Policy'}
COMMON_KEYS = {'Class', 'Name', 'Enabled', 'Value', 'Topic'}
#: display class -> (message type it subscribes, the properties it declares)
DISPLAYS: dict[str, tuple[str | None, set[str]]] = {
    'rviz_default_plugins/Grid': (None, {
        'Reference Frame', 'Plane Cell Count', 'Normal Cell Count', 'Cell Size', 'Line Style',
        'Color', 'Alpha', 'Plane', 'Offset'}),
    'rviz_default_plugins/TF': (None, {
        'Show Names', 'Show Axes', 'Show Arrows', 'Marker Scale', 'Update Interval',
        'Frame Timeout', 'Filter (whitelist)', 'Filter (blacklist)', 'Frames', 'Tree'}),
    'rviz_default_plugins/Map': ('nav_msgs/msg/OccupancyGrid', {
        'Update Topic', 'Alpha', 'Color Scheme', 'Draw Behind', 'Use Timestamp'}),
    'rviz_default_plugins/PointCloud2': ('sensor_msgs/msg/PointCloud2', {
        'Selectable', 'Style', 'Size (m)', 'Size (Pixels)', 'Alpha', 'Decay Time',
        'Position Transformer', 'Color Transformer', 'Color'}),
    'rviz_default_plugins/Image': ('sensor_msgs/msg/Image', {
        'Normalize Range', 'Min Value', 'Max Value', 'Median window'}),
}
#: qos_profile_property.cpp: the names of the policies
RELIABILITY = {'Reliable': ReliabilityPolicy.RELIABLE,
               'Best Effort': ReliabilityPolicy.BEST_EFFORT}
DURABILITY = {'Transient Local': DurabilityPolicy.TRANSIENT_LOCAL,
              'Volatile': DurabilityPolicy.VOLATILE}
#: Nav2's costmap (nav2_costmap_2d/src/costmap_2d_publisher.cpp, Costmap2DPublisher:
#: QoS(KeepLast(1)).transient_local().reliable()), shown beside the node's
NAV2_TOPICS = {'/local_costmap/costmap': ('nav_msgs/msg/OccupancyGrid',
                                          ReliabilityPolicy.RELIABLE,
                                          DurabilityPolicy.TRANSIENT_LOCAL)}


def _displays() -> list[dict[str, Any]]:
    config = yaml.safe_load(RVIZ.read_text(encoding='utf-8'))
    return config['Visualization Manager']['Displays']


def _topic_displays() -> list[dict[str, Any]]:
    return [d for d in _displays() if 'Topic' in d]


@pytest.fixture(scope='module')
def publishers() -> Iterator[dict[str, tuple[str, Any, Any]]]:
    """Topic -> (type, reliability, durability) of the node with every output on."""
    from obstacle_detection.ros.node import DetectorNode

    with ros_env.rclpy_context(f'{__name__}:publishers') as context:
        node = DetectorNode(context=context, cli_args=[
            '--ros-args', '--params-file', str(CORRIDOR), '-p', 'publish_clearing:=true',
            '-p', 'publish_overlay:=true', '-p', 'fuse:=true', '-p', 'publish_ground:=true'])
        try:
            found = {}
            for name, types in node.get_topic_names_and_types():
                for info in node.get_publishers_info_by_topic(name):
                    if info.node_name == node.get_name():
                        found[name] = (types[0], info.qos_profile.reliability,
                                       info.qos_profile.durability)
            yield found
        finally:
            node.close()
            node.destroy_node()


def test_every_display_and_property_is_one_rviz_jazzy_reads() -> None:
    for display in _displays():
        assert display['Class'] in DISPLAYS, display['Class']
        known = DISPLAYS[display['Class']][1] | COMMON_KEYS
        assert set(display) <= known, (display['Name'], set(display) - known)
        for key in ('Topic', 'Update Topic'):
            if key in display:
                assert set(display[key]) == TOPIC_KEYS, (display['Name'], key)
                assert display[key]['Reliability Policy'] in RELIABILITY
                assert display[key]['Durability Policy'] in DURABILITY


def test_the_outputs_a_user_looks_at_are_all_shown() -> None:
    shown = {d['Topic']['Value'] for d in _topic_displays()}
    classes = {d['Class'] for d in _displays()}

    assert {'/obstacles/points', '/obstacles/clearing_points', '/obstacles/costmap',
            '/obstacles/fused_costmap', '/obstacles/overlay'} <= shown
    assert 'rviz_default_plugins/TF' in classes


@pytest.mark.parametrize('display', _topic_displays(), ids=lambda d: d['Name'])
def test_each_topic_is_published_with_a_qos_the_display_accepts(
        publishers: dict, display: dict) -> None:
    topic = display['Topic']['Value']
    wanted_type = DISPLAYS[display['Class']][0]
    kind, reliability, durability = NAV2_TOPICS.get(topic) or publishers[topic]

    assert kind == wanted_type
    if display['Topic']['Reliability Policy'] == 'Reliable':
        assert reliability == ReliabilityPolicy.RELIABLE
    if display['Topic']['Durability Policy'] == 'Transient Local':
        assert durability == DurabilityPolicy.TRANSIENT_LOCAL


def test_the_grids_are_latched_and_the_display_asks_for_it(publishers: dict) -> None:
    grids = [d for d in _topic_displays() if d['Class'] == 'rviz_default_plugins/Map']

    for display in grids:
        assert display['Topic']['Durability Policy'] == 'Transient Local', display['Name']
        if display['Topic']['Value'] in publishers:
            assert publishers[display['Topic']['Value']][2] == DurabilityPolicy.TRANSIENT_LOCAL


def test_the_frames_are_the_node_s_frames() -> None:
    from obstacle_detection.cli import bag_processor

    values = bag_processor.node_param_values(CORRIDOR)
    config = yaml.safe_load(RVIZ.read_text(encoding='utf-8'))['Visualization Manager']
    grid = next(d for d in config['Displays'] if d['Class'] == 'rviz_default_plugins/Grid')

    assert config['Global Options']['Fixed Frame'] == values['odom_frame']
    assert grid['Reference Frame'] == values['cloud_frame_id']
