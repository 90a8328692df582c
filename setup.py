"""Install the obstacle_detection ament_python package (colcon runs this file)."""

from glob import glob
from pathlib import Path

from setuptools import find_packages, setup

PACKAGE = 'obstacle_detection'
#: The command lines: tools/<name>.py is installed as the module obstacle_detection.tools.<name>
#: and as the command <name> (lib/obstacle_detection/<name> for ``ros2 run``, .venv/bin/<name>).
#: Read through the package's link, which a symlink install's build folder also has.
TOOLS = sorted(Path(path).stem for path in glob(f'{PACKAGE}/tools/*.py')
               if not Path(path).name.startswith('_'))

setup(
    name=PACKAGE,
    version='0.1.0',
    # obstacle_detection/tools is a symbolic link to the top-level tools/ (the command lines stay
    # there): every install, plain, `colcon build --symlink-install` (setup.py develop) or
    # `pip install -e`, finds obstacle_detection.tools through it; no top-level module `tools`
    packages=find_packages(include=[PACKAGE, f'{PACKAGE}.*']),
    # the loopback Fast DDS profile and the committed scenario suites
    package_data={f'{PACKAGE}.ros': ['fastdds_loopback.xml'],
                  f'{PACKAGE}.evaluation': ['scenarios.json', 'scenarios_robot.json']},
    data_files=[
        # ament index marker: lets `ros2 run` / `ros2 pkg` find the package.
        ('share/ament_index/resource_index/packages', [f'resource/{PACKAGE}']),
        (f'share/{PACKAGE}', ['package.xml']),
        # node parameter files, the trained refiners and the Nav2 examples
        (f'share/{PACKAGE}/params', sorted(glob('params/*.yaml') + glob('params/*.json'))),
        # `ros2 launch obstacle_detection detector.launch.py`
        (f'share/{PACKAGE}/launch', sorted(glob('launch/*.launch.py'))),
        # `rviz2 -d $(ros2 pkg prefix obstacle_detection)/share/obstacle_detection/rviz/...`
        (f'share/{PACKAGE}/rviz', sorted(glob('rviz/*.rviz'))),
    ],
    # ROS convention: runtime dependencies come from package.xml (rosdep), not from pip, so a
    # colcon build against system numpy/scipy/OpenCV keeps working.
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='Seed 4227b6c9 maintainers',
    maintainer_email='maintainers@users.noreply.h-seed-4227b6c9.example',
    description='Depth image to obstacle cloud and ground-plane costmap (ROS 2 node).',
    license='Apache-2.0',
    # pip install .[fleet]: offline work on a Dask cluster (README, Offline work at scale)
    extras_require={'test': ['pytest'], 'fleet': ['dask>=2024.8', 'distributed>=2024.8']},
    entry_points={
        'console_scripts': [
            'detector = obstacle_detection.ros.node:main',
            *(f'{name} = {PACKAGE}.tools.{name}:main' for name in TOOLS),
        ],
    },
)
