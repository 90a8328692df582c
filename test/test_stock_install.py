"""A stock ROS 2 Jazzy install (Ubuntu 24.04, rosdep, colcon) gets everything the code imports.

rosdep and colcon do not run here; what they do is read from their sources and ported:

- The dependency table below holds every key package.xml relies on, each with the file of
  ros/rosdistro (master, 2026-08-22) it was read from: ``rosdep/python.yaml`` for the Python
  keys and their ``ubuntu`` rule, ``jazzy/distribution.yaml`` for the ROS packages and the
  repository releasing them. Every import of the package, its tools and its launch file maps
  to one of them (an AST walk), or is optional: imported only where its absence is handled,
  which a run with those modules hidden shows.
- numba is optional for a reason rosdep cannot fix: ``python3-numba`` (rosdep/python.yaml) is
  an apt-only rule, and Ubuntu 24.04 has no such package (packages.ubuntu.com lists
  python3-numba for jammy, questing and resolute, not noble; noble has python3-llvmlite
  0.42.0 alone), so declaring it would make ``rosdep install`` fail on noble. README, Install,
  says how to get the compiled path (pip).
- ``colcon build --symlink-install`` is colcon-core's ``PythonBuildTask.build``
  (colcon_core/task/python/build.py): ``_symlinks_in_build`` links setup.py, setup.cfg, the
  first-level packages and the data files into the build folder, then ``setup.py develop
  --editable --build-directory build --no-deps`` runs there, and the ``pythonpath_develop``
  hook puts the build folder first on PYTHONPATH. The test below does the same into a
  temporary prefix (``--prefix`` in place of colcon's sitecustomize prefix override; colcon's
  own ``symlink_data`` command, which links the data files into share/, is left out).
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
import sysconfig
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

import ros_env

REPO = ros_env.REPO_ROOT
PACKAGE = 'obstacle_detection'
ROSDEP_PYTHON = 'ros/rosdistro rosdep/python.yaml'
JAZZY = 'ros/rosdistro jazzy/distribution.yaml'

#: import name -> (package.xml key, where the key was read, what it installs on Ubuntu noble)
EXEC_KEYS = {
    'numpy': ('python3-numpy', ROSDEP_PYTHON, 'apt python3-numpy'),
    'scipy': ('python3-scipy', ROSDEP_PYTHON, 'apt python3-scipy'),
    'cv2': ('python3-opencv', ROSDEP_PYTHON, 'apt python3-opencv'),
    'yaml': ('python3-yaml', ROSDEP_PYTHON, 'apt python3-yaml'),
    'rosbags': ('python3-rosbags-pip', ROSDEP_PYTHON, 'pip rosbags'),
    'rclpy': ('rclpy', JAZZY, 'repository rclpy'),
    'rcl_interfaces': ('rcl_interfaces', JAZZY, 'repository rcl_interfaces'),
    'builtin_interfaces': ('builtin_interfaces', JAZZY, 'repository rcl_interfaces'),
    'sensor_msgs': ('sensor_msgs', JAZZY, 'repository common_interfaces'),
    'nav_msgs': ('nav_msgs', JAZZY, 'repository common_interfaces'),
    'std_msgs': ('std_msgs', JAZZY, 'repository common_interfaces'),
    'geometry_msgs': ('geometry_msgs', JAZZY, 'repository common_interfaces'),
    'diagnostic_msgs': ('diagnostic_msgs', JAZZY, 'repository common_interfaces'),
    'tf2_ros': ('tf2_ros_py', JAZZY, 'repository geometry2'),
    'launch': ('launch', JAZZY, 'repository launch'),
    'launch_ros': ('launch_ros', JAZZY, 'repository launch_ros'),
    'ament_index_python': ('ament_index_python', JAZZY, 'repository ament_index'),
}
#: the tests' own imports beyond EXEC_KEYS
TEST_KEYS = {
    'pytest': ('python3-pytest', ROSDEP_PYTHON, 'apt python3-pytest'),
    'ruff': ('python3-ruff-pip', ROSDEP_PYTHON, 'pip ruff'),
}
#: imports with no rosdep key that installs on noble; the code runs without them
OPTIONAL = {
    'numba': 'python3-numba is apt-only and noble has no python3-numba: pip (README, Install)',
    'dask': 'no rosdep key; pip install .[fleet] (README, Offline work at scale)',
    'distributed': 'no rosdep key; pip install .[fleet] (README, Offline work at scale)',
    'cloudpickle': "dask's own dependency, imported only beside it (fleet/probe.py)",
}
#: rclpy.experimental.EventsExecutor came to Jazzy with rclpy 7.1.4 (ros/rosdistro pull
#: request 44956, "rclpy: 7.1.4-1 in 'jazzy/distribution.yaml'": "Backport of the Events
#: Executor (#1391) (#1435)"); the jazzy branch's 7.1.3 has no rclpy/experimental.
RCLPY_WITH_EVENTS_EXECUTOR = '7.1.4'


def _package_xml() -> ET.Element:
    return ET.parse(REPO / 'package.xml').getroot()


def _depends(kind: str) -> dict[str, ET.Element]:
    return {e.text: e for e in _package_xml().findall(kind)}


def _third_party_imports(*folders: str) -> dict[str, set[str]]:
    """Top-level module -> files importing it, for every non-stdlib absolute import."""
    found: dict[str, set[str]] = {}
    local = {p.stem for p in (REPO / 'test').glob('*.py')}
    for folder in folders:
        for path in sorted((REPO / folder).rglob('*.py')):
            for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'), str(path))):
                if isinstance(node, ast.Import):
                    names = [alias.name for alias in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    names = [node.module]
                else:
                    continue
                for name in names:
                    top = name.split('.')[0]
                    if top not in sys.stdlib_module_names and top != PACKAGE \
                            and not (folder == 'test' and top in local):
                        found.setdefault(top, set()).add(str(path.relative_to(REPO)))
    return found


# --------------------------------------------------------------------------------------------
# rosdep: every import has a declared key that installs on Ubuntu 24.04


def test_every_import_of_the_package_tools_and_launch_file_is_a_declared_exec_depend() -> None:
    imports = _third_party_imports(PACKAGE, 'tools', 'launch')
    declared = _depends('exec_depend')

    unknown = {name: files for name, files in imports.items()
               if name not in EXEC_KEYS and name not in OPTIONAL}
    assert not unknown, f'imports without a rosdep key in this table: {unknown}'
    missing = {name: EXEC_KEYS[name][0] for name in imports
               if name in EXEC_KEYS and EXEC_KEYS[name][0] not in declared}
    assert not missing, f'not declared as exec_depend in package.xml: {missing}'
    # the table is not padded: each key is used, numba, dask and distributed really imported
    assert set(imports) - set(OPTIONAL) <= set(EXEC_KEYS)
    assert set(OPTIONAL) <= set(imports)


def test_every_import_of_the_tests_is_declared_for_colcon_test() -> None:
    imports = _third_party_imports('test')
    declared = set(_depends('exec_depend')) | set(_depends('test_depend'))
    keys = EXEC_KEYS | TEST_KEYS

    unknown = sorted(set(imports) - set(keys) - set(OPTIONAL))
    assert not unknown, f'test imports without a key: {unknown}'
    assert {keys[name][0] for name in imports if name in keys} <= declared


def test_optional_modules_have_no_key_that_installs_on_noble() -> None:
    declared = set(_depends('exec_depend')) | set(_depends('test_depend'))

    assert not {'python3-numba', 'python3-dask', 'python3-distributed'} & declared
    assert all(source in (ROSDEP_PYTHON, JAZZY) for _, source, _ in EXEC_KEYS.values())
    pip_keys = {key for key, _, rule in (EXEC_KEYS | TEST_KEYS).values()
                if rule.startswith('pip ')}
    assert pip_keys == {'python3-rosbags-pip', 'python3-ruff-pip'}
    assert all(key.endswith('-pip') for key in pip_keys)


def test_the_package_and_its_tools_import_without_the_optional_modules(tmp_path: Path) -> None:
    """With numba, dask and distributed hidden, every module imports; the numpy path is on."""
    probe = f"""
import importlib, pkgutil, sys
for name in {sorted(OPTIONAL)!r}:
    sys.modules[name] = None          # `import name` now raises ImportError
import {PACKAGE}
names = [m.name for m in pkgutil.walk_packages({PACKAGE}.__path__, '{PACKAGE}.')]
for name in names:
    importlib.import_module(name)
from {PACKAGE}.pipeline import jit
print(len(names), jit.AVAILABLE, jit.enabled())
"""
    env = ros_env.loopback_env('test_stock_install')
    done = subprocess.run([sys.executable, '-c', probe], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stderr
    count, available, enabled = done.stdout.split()
    assert int(count) > 40 and (available, enabled) == ('False', 'False')


def test_rclpy_is_pinned_to_the_first_jazzy_release_with_the_events_executor() -> None:
    rclpy = _depends('exec_depend')['rclpy']
    node = ast.parse((REPO / PACKAGE / 'ros' / 'node.py').read_text(encoding='utf-8'))
    uses = {(n.module, a.name) for n in ast.walk(node) if isinstance(n, ast.ImportFrom)
            for a in n.names}

    assert ('rclpy.experimental', 'EventsExecutor') in uses
    assert rclpy.get('version_gte') == RCLPY_WITH_EVENTS_EXECUTOR
    assert not set(rclpy.attrib) - {'version_gte'}


def test_use_tf_has_its_tf2_package_declared() -> None:
    node = (REPO / PACKAGE / 'ros' / 'node.py').read_text(encoding='utf-8')

    assert 'import tf2_ros' in node
    assert 'tf2_ros_py' in _depends('exec_depend')


def test_license_file_is_the_apache_license_package_xml_and_setup_py_name() -> None:
    text = (REPO / 'LICENSE').read_text(encoding='utf-8')
    setup = (REPO / 'setup.py').read_text(encoding='utf-8')

    assert 'Apache License' in text and 'Version 2.0, January 2004' in text
    assert 'TERMS AND CONDITIONS FOR USE, REPRODUCTION, AND DISTRIBUTION' in text
    assert _package_xml().findtext('license') == 'Apache-2.0'
    assert "license='Apache-2.0'" in setup


# --------------------------------------------------------------------------------------------
# colcon build --symlink-install


def _setup_data() -> dict:
    """Return setup.py's packages, package_dir, data_files (as colcon's get_setup_data)."""
    probe = ('import json, setuptools, distutils.core as c; '
             "d = c.run_setup('setup.py', stop_after='init'); "
             'print(json.dumps({"packages": d.packages, "package_dir": d.package_dir or {}, '
             '"data_files": d.data_files or [], "scripts": d.scripts or []}))')
    done = subprocess.run([sys.executable, '-c', probe], cwd=REPO, capture_output=True,
                          text=True, timeout=120, check=True)
    return json.loads(done.stdout.splitlines()[-1])


def _symlinks_in_build(build: Path, data: dict) -> None:
    """Port of colcon-core's PythonBuildTask._symlinks_in_build (first-level packages only)."""
    items = ['setup.py', 'setup.cfg']
    package_dir = data['package_dir']
    renamed = []
    for package in data['packages']:
        if '.' in package:
            continue
        if package in package_dir:
            items.append(package_dir[package])
            renamed.append((package_dir[package], package))
        else:
            items.append(package)
    items += [source for _, sources in data['data_files'] for source in sources]
    items += data['scripts']
    for item in items:
        (build / item).parent.mkdir(parents=True, exist_ok=True)
        (build / item).symlink_to(REPO / item)
    for source, target in renamed:
        (build / target).symlink_to(REPO / source)


@pytest.fixture(scope='module')
def develop(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """Install the package as ``colcon build --symlink-install`` does; (build, install)."""
    tmp = tmp_path_factory.mktemp('symlink_install')
    build, install = tmp / 'build', tmp / 'install'
    build.mkdir()
    python_lib = install / Path(sysconfig.get_path('purelib')).relative_to(
        sysconfig.get_path('data'))
    python_lib.mkdir(parents=True)
    _symlinks_in_build(build, _setup_data())
    env = ros_env.loopback_env('test_stock_install')
    env['PYTHONPATH'] = str(python_lib)
    done = subprocess.run(
        [sys.executable, 'setup.py', 'develop', '--editable', '--build-directory',
         str(build / 'build'), '--no-deps', '--prefix', str(install)],
        cwd=build, env=env, capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stdout + done.stderr
    return build, install


def _develop_env(build: Path, install: Path) -> dict[str, str]:
    env = ros_env.loopback_env('test_stock_install')
    python_lib = install / Path(sysconfig.get_path('purelib')).relative_to(
        sysconfig.get_path('data'))
    # colcon's pythonpath_develop hook: the build folder first
    env['PYTHONPATH'] = f'{build}:{python_lib}'
    return env


def test_symlink_install_installs_every_tool_command(develop: tuple[Path, Path]) -> None:
    _, install = develop
    tools = sorted(p.stem for p in (REPO / 'tools').glob('[!_]*.py'))

    assert len(tools) > 5
    for name in ['detector', *tools]:
        command = install / 'lib' / PACKAGE / name
        assert command.is_file() and command.stat().st_mode & 0o111, name


@pytest.mark.parametrize('tool', ['evaluate', 'bag_convert', 'param_table'])
def test_symlink_install_runs_the_tools_from_the_source_folder(
        develop: tuple[Path, Path], tool: str, tmp_path: Path) -> None:
    build, install = develop
    env = _develop_env(build, install)

    helped = subprocess.run([str(install / 'lib' / PACKAGE / tool), '--help'], env=env,
                            cwd=tmp_path, capture_output=True, text=True, timeout=120,
                            check=False)
    where = subprocess.run(
        [sys.executable, '-c', f'import {PACKAGE}.tools.{tool} as t; print(t.__file__)'],
        env=env, cwd=tmp_path, capture_output=True, text=True, timeout=120, check=False)

    assert helped.returncode == 0, helped.stderr
    assert helped.stdout.startswith(f'usage: {tool}'), helped.stdout
    # found through the build folder's link: an edit of tools/<tool>.py is live, no rebuild
    assert where.stdout.strip().startswith(str(build)), where.stdout + where.stderr
    assert Path(where.stdout.strip()).resolve() == REPO / 'tools' / f'{tool}.py'


# --------------------------------------------------------------------------------------------
# The README's path, step by step, against what the steps rely on


def _jazzy_commands() -> list[str]:
    """Return the commands of the README's 'On a ROS 2 Jazzy system' block, no comments."""
    readme = (REPO / 'README.md').read_text(encoding='utf-8')
    section = readme.split('### On a ROS 2 Jazzy system', 1)[1].split('\n### ', 1)[0]
    block = section.split('```bash\n', 1)[1].split('```', 1)[0]
    return [line.split(' #')[0].strip() for line in block.splitlines()
            if line.strip() and not line.lstrip().startswith('#')]


def test_readme_jazzy_path_allows_pip_as_rosdep_asks() -> None:
    """Allow pip beside apt first: rosdep's pip installer refuses it otherwise (PEP 668).

    ros-infrastructure/rosdep, src/rosdep2/platforms/pip.py, externally_managed_installable:
    true for PIP_BREAK_SYSTEM_PACKAGES in rosdep's environment or ``break-system-packages`` in
    ``[install]`` of /etc/pip.conf; the pip command runs under ``sudo -H``
    (installers.py, elevate_priv), which resets the environment on Ubuntu, so the README sets
    the file (doc/pip_and_pep_668.rst, "Configure using pip.conf").
    """
    import configparser

    commands = _jazzy_commands()
    pip_conf = next(c for c in commands if '/etc/pip.conf' in c)
    text = pip_conf.split('"')[1].encode().decode('unicode_escape')
    parser = configparser.ConfigParser()
    parser.read_string(text)

    assert 'sudo tee -a /etc/pip.conf' in pip_conf
    assert parser.getboolean('install', 'break-system-packages')
    install = commands.index(next(c for c in commands if 'rosdep install' in c))
    assert commands.index(pip_conf) < install        # before rosdep needs pip
    assert '--from-paths src --ignore-src -y' in commands[install]


def test_readme_jazzy_path_installs_the_numba_the_node_names() -> None:
    commands = _jazzy_commands()
    numba = next(c for c in commands if 'numba' in c)
    requirement = numba.split('"')[1]
    wanted = next(line.split('#')[0].strip() for line in
                  (REPO / 'requirements.txt').read_text(encoding='utf-8').splitlines()
                  if line.startswith('numba'))
    node = (REPO / PACKAGE / 'ros' / 'node.py').read_text(encoding='utf-8')

    assert numba.startswith('sudo -H pip3 install')
    assert requirement == wanted == 'numba>=0.60'
    assert f'pip install "{requirement}"' in node      # what ~/status says without it
    assert 'python3-numba' not in _depends('exec_depend')


def test_readme_jazzy_path_builds_launches_and_shows_what_the_node_publishes() -> None:
    from test_launch_and_nav2 import _corridor, _launch_module

    from obstacle_detection.ros.node import OUTPUTS

    commands = _jazzy_commands()
    build = next(c for c in commands if c.startswith('colcon build'))
    launch = next(c for c in commands if c.startswith('ros2 launch'))
    rviz = next(c for c in commands if 'rviz2' in c)
    package, launch_file, *arguments = launch.split()[2:]
    values = dict(argument.split(':=') for argument in arguments)
    settings = _launch_module().node_settings(values, '/opt/ros/share/obstacle_detection')
    corridor = _corridor()

    assert '--symlink-install' in build     # the develop install tested above
    assert (package, launch_file) == (PACKAGE, 'detector.launch.py')
    assert settings['parameters'][1]['use_tf'] is False      # the bench: mount from the file
    assert ('depth/image_raw', '/camera/camera/depth/image_rect_raw') in settings['remappings']
    # RViz's fixed frame is the costmap's frame; the README adds the node's output topics
    assert rviz.split()[-2:] == ['-f', corridor['costmap_frame_id']]
    readme = (REPO / 'README.md').read_text(encoding='utf-8')
    assert f'/{OUTPUTS["costmap"][1]} > Map' in readme
    assert f'/{OUTPUTS["obstacles"][1]} > PointCloud2' in readme
