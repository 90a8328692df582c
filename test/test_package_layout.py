"""The package installs where ``ros2 run`` looks, and the installed ``detector`` starts.

The build repeats what colcon's ament_python build runs (``setup.py egg_info build install
--single-version-externally-managed``) into a temporary prefix, without colcon.
"""

from __future__ import annotations

import ast
import re
import signal
import subprocess
import sys
import sysconfig
import threading
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
import ros_env


REPO = ros_env.REPO_ROOT
PACKAGE = 'obstacle_detection'
#: The command lines (tools/<name>.py), installed as ``<name>`` beside ``detector``.
TOOLS = ('bag_convert', 'bag_play', 'bag_process', 'benchmark', 'demo', 'estimate_mount',
         'evaluate', 'latency_bench', 'param_table', 'pictures', 'sweep')
EXEC_DEPENDS = {'rclpy', 'sensor_msgs', 'nav_msgs', 'std_msgs', 'geometry_msgs',
                'python3-numpy', 'python3-scipy', 'python3-opencv'}


def _package_xml() -> ET.Element:
    return ET.parse(REPO / 'package.xml').getroot()


def test_package_xml_is_format_3_ament_python() -> None:
    root = _package_xml()
    assert root.tag == 'package' and root.get('format') == '3'
    assert root.findtext('name') == PACKAGE
    assert root.findtext('export/build_type') == 'ament_python'
    assert root.findtext('license') and root.find('maintainer').get('email')


def test_package_xml_declares_dependencies() -> None:
    root = _package_xml()
    exec_depends = {e.text for e in root.findall('exec_depend')}
    assert EXEC_DEPENDS <= exec_depends
    assert 'python3-pytest' in {e.text for e in root.findall('test_depend')}


def test_setup_py_version_matches_package_xml() -> None:
    version = re.search(r"version='([^']+)'", (REPO / 'setup.py').read_text()).group(1)
    assert version == _package_xml().findtext('version')


def _site_packages(prefix: Path) -> Path:
    relative = Path(sysconfig.get_path('purelib')).relative_to(sysconfig.get_path('data'))
    return prefix / relative


@pytest.mark.parametrize('relative', [
    'lib/obstacle_detection/detector',
    'share/obstacle_detection/package.xml',
    'share/obstacle_detection/params/corridor.yaml',
    'share/obstacle_detection/params/corridor_video.yaml',
    'share/obstacle_detection/params/nav2_stvl.yaml',
    'share/obstacle_detection/params/nav2_collision_monitor.yaml',
    'share/obstacle_detection/rviz/obstacle_detection.rviz',
    'share/ament_index/resource_index/packages/obstacle_detection',
])
def test_installed_where_ros2_run_looks(prefix: Path, relative: str) -> None:
    assert (prefix / relative).is_file()


def test_every_tool_is_a_command_where_ros2_run_looks(prefix: Path) -> None:
    assert sorted(p.stem for p in (REPO / 'tools').glob('[!_]*.py')) == sorted(TOOLS)
    for name in TOOLS:
        command = prefix / 'lib' / PACKAGE / name
        assert command.is_file() and command.stat().st_mode & 0o111, command
        assert f"'console_scripts', '{name}'" in command.read_text(), command
        assert (_site_packages(prefix) / PACKAGE / 'tools' / f'{name}.py').is_file(), name
    # the command lines live inside the package: nothing named `tools` at the top level
    assert not (_site_packages(prefix) / 'tools').exists()


def _installed_env(prefix: Path, tmp_path: Path) -> dict[str, str]:
    env = ros_env.loopback_env('test_package_layout', log_dir=tmp_path / 'ros_log')
    env['PYTHONPATH'] = str(_site_packages(prefix))
    return env


def test_installed_param_table_prints_the_parameter_table(prefix: Path, tmp_path: Path) -> None:
    from obstacle_detection.tools.param_table import parameter_table

    done = subprocess.run([str(prefix / 'lib' / PACKAGE / 'param_table')],
                          env=_installed_env(prefix, tmp_path), cwd=tmp_path,
                          capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == parameter_table().strip()


def test_installed_tools_find_the_installed_parameter_files(prefix: Path, tmp_path: Path) -> None:
    probe = ('from obstacle_detection.cli.support import package_file; '
             "print(package_file('params/corridor.yaml'))")
    done = subprocess.run([sys.executable, '-c', probe], env=_installed_env(prefix, tmp_path),
                          cwd=tmp_path, capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == str(prefix / 'share' / PACKAGE / 'params' / 'corridor.yaml')
    from obstacle_detection.cli.support import package_file
    assert package_file('params/corridor.yaml') == REPO / 'params' / 'corridor.yaml'


def test_installed_evaluate_reports_a_bad_scene_as_a_usage_error(prefix: Path,
                                                                 tmp_path: Path) -> None:
    command = str(prefix / 'lib' / PACKAGE / 'evaluate')
    env = _installed_env(prefix, tmp_path)
    helped = subprocess.run([command, '--help'], env=env, cwd=tmp_path, capture_output=True,
                            text=True, timeout=120, check=False)
    assert helped.returncode == 0 and helped.stdout.startswith('usage: evaluate'), helped.stderr
    bad = subprocess.run([command, '--scene', 'no_such_scene'], env=env, cwd=tmp_path,
                         capture_output=True, text=True, timeout=120, check=False)
    assert bad.returncode == 2 and bad.stderr.count('\n') == 1, bad.stderr
    assert 'no_such_scene' in bad.stderr and 'Traceback' not in bad.stderr


def test_tools_neither_edit_sys_path_nor_import_each_other() -> None:
    for path in sorted((REPO / 'tools').glob('*.py')):
        tree = ast.parse(path.read_text(), str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and node.attr == 'path' and \
                    isinstance(node.value, ast.Name) and node.value.id == 'sys':
                raise AssertionError(f'{path.name} uses sys.path')
            modules = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                       [node.module or ''] if isinstance(node, ast.ImportFrom) else [])
            assert not any(m == 'tools' or m.startswith(('tools.', f'{PACKAGE}.tools'))
                           for m in modules), f'{path.name} imports another tool: {modules}'


def test_editable_install_maps_the_tools_into_the_package(tmp_path: Path) -> None:
    """In the venv (``pip install -e .``), obstacle_detection.tools is the checkout's tools/."""
    probe = ('import obstacle_detection, obstacle_detection.tools.evaluate as e; '
             'print(obstacle_detection.__file__); print(e.__file__)')
    env = {k: v for k, v in ros_env.loopback_env('test_package_layout').items()
           if k != 'PYTHONPATH'}
    done = subprocess.run([sys.executable, '-c', probe], env=env, cwd=tmp_path,
                          capture_output=True, text=True, timeout=60, check=False)
    package = done.stdout.splitlines()[0] if done.returncode == 0 else ''
    if not package.startswith(str(REPO)):
        pytest.skip('obstacle_detection is not installed editable from this checkout')
    # through the package's link obstacle_detection/tools -> ../tools
    assert Path(done.stdout.splitlines()[1]).resolve() == REPO / 'tools' / 'evaluate.py'
    command = Path(sys.executable).parent / 'evaluate'
    assert command.is_file(), 'the venv has no evaluate command: bash tools/setup_venv.sh'


def test_installed_python_package(prefix: Path) -> None:
    installed = _site_packages(prefix) / PACKAGE
    assert (installed / 'ros' / 'node.py').is_file()
    assert (installed / 'pipeline' / 'detector.py').is_file()
    # package data: the loopback DDS profile and the committed scenario suites
    assert (installed / 'ros' / 'fastdds_loopback.xml').is_file()
    assert (installed / 'evaluation' / 'scenarios_robot.json').is_file()


def _wait_for_line(process: subprocess.Popen, lines: list[str], pattern: str,
                   timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if any(pattern in line for line in lines):
            return True
        if process.poll() is not None:
            time.sleep(0.2)  # let the reader thread catch the last lines
            return any(pattern in line for line in lines)
        time.sleep(0.05)
    return False


def test_installed_detector_starts_and_stops_on_sigint(prefix: Path, tmp_path: Path) -> None:
    env = ros_env.loopback_env('test_package_layout', log_dir=tmp_path / 'ros_log')
    site = str(_site_packages(prefix))
    env['PYTHONPATH'] = site  # the installed copy first; the venv's own site-packages follow
    probe = 'import obstacle_detection.ros.node as n; print(n.__file__)'
    which = subprocess.run([sys.executable, '-c', probe], env=env, cwd=tmp_path,
                           capture_output=True, text=True, timeout=60, check=False)
    assert which.stdout.strip().startswith(site), which.stdout + which.stderr

    params = prefix / 'share/obstacle_detection/params/corridor.yaml'
    process = subprocess.Popen(
        [str(prefix / 'lib/obstacle_detection/detector'), '--ros-args', '--params-file',
         str(params)], env=env, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
        text=True)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(process.stdout), daemon=True)
    reader.start()
    try:
        assert _wait_for_line(process, lines, 'ready:', timeout=60), ''.join(lines)
        process.send_signal(signal.SIGINT)
        assert process.wait(timeout=30) == 0, ''.join(lines)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait(timeout=10)
        reader.join(timeout=5)
    assert not any('Traceback' in line for line in lines), ''.join(lines)


def test_parameter_table_lists_every_parameter_with_its_range() -> None:
    from obstacle_detection.ros.parameters import ALL_PARAMS
    from obstacle_detection.tools.param_table import parameter_table

    rows = parameter_table().splitlines()[2:]

    assert [row.split('|')[1].strip(' `') for row in rows] == [s.name for s in ALL_PARAMS]
    slope = next(row for row in rows if row.startswith('| `max_slope_deg`'))
    assert '| 30 | 60 | (0, 90) |' in slope


def test_requirements_name_the_jazzy_wheels_only() -> None:
    """The ROS wheels are pinned by their ros-jazzy-* names, which can only ever be Jazzy."""
    lines = [line.split('#')[0].strip() for line in
             (REPO / 'requirements.txt').read_text().splitlines()]
    ros = [line for line in lines if line.startswith('ros-')]
    assert {line.split('==')[0] for line in ros} == {
        'ros-jazzy-rclpy', 'ros-jazzy-common-interfaces', 'ros-jazzy-rmw-fastrtps-cpp'}
    assert all('==' in line for line in ros), ros
