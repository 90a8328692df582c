"""The camera YAML (one reader, one writer) and intrinsics scaling (evaluation/camera.py)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from obstacle_detection.evaluation import EvaluationError, camera
from obstacle_detection.pipeline.params import Intrinsics

INTR = Intrinsics(365.5, 366.25, 255.5, 211.5)


def test_scaling_keeps_the_pixel_centres() -> None:
    # Halving a 512 px wide image: the centre of the image (x = 255.5) stays the centre of
    # the 256 px one (x = 127.5), focal lengths halve.
    half = camera.scaled_intrinsics(INTR, 0.5)
    assert half == Intrinsics(182.75, 183.125, 127.5, 105.5)
    stretched = camera.scaled_intrinsics(INTR, 2.0, 0.5)
    assert (stretched.fx, stretched.cx, stretched.fy, stretched.cy) == (731.0, 511.5, 183.125,
                                                                        105.5)


def test_written_camera_yaml_reads_back(tmp_path: Path) -> None:
    path = tmp_path / 'camera.yaml'
    path.write_text(camera.camera_yaml_text(INTR, comment='test camera', size=(512, 424),
                                            depth_scale=5000.0, height_m=0.75,
                                            pitch_deg=20.0, roll_deg=-4.0))
    back = camera.read_camera_yaml(path)
    assert back.intrinsics == INTR and back.size == (512, 424) and back.depth_scale == 5000.0
    assert back.mount == pytest.approx((0.75, math.radians(20.0), math.radians(-4.0)))
    assert path.read_text().startswith('# test camera\nfx: 365.5\n')


def test_ros_calibration_file_and_its_size(tmp_path: Path) -> None:
    path = tmp_path / 'ros.yaml'
    path.write_text('image_width: 640\nimage_height: 480\ncamera_matrix:\n  rows: 3\n  cols: 3\n'
                    '  data: [500.0, 0.0, 320.0, 0.0, 501.0, 240.0, 0.0, 0.0, 1.0]\n')
    back = camera.read_camera_yaml(path)
    assert back.intrinsics == Intrinsics(500.0, 501.0, 320.0, 240.0)
    assert back.size == (640, 480) and back.mount is None


@pytest.mark.parametrize('text, problem', [
    ('fx: 1\nfy: 1\n', 'missing cx, cy'),
    ('- 1\n- 2\n', 'not a YAML mapping'),
    ('fx: 1\nfy: 1\ncx: 1\ncy: 1\ndepth_scale: -5\n', 'depth_scale=-5.0 must be > 0'),
    ('fx: 1\nfy: 1\ncx: 1\ncy: 1\nwidth: 640\n', 'give both width and height'),
    ('fx: [1\n', 'not valid YAML'),
])
def test_a_bad_camera_yaml_names_the_file_and_the_problem(tmp_path: Path, text: str,
                                                          problem: str) -> None:
    path = tmp_path / 'bad.yaml'
    path.write_text(text)
    with pytest.raises(EvaluationError, match=problem) as caught:
        camera.read_camera_yaml(path)
    assert caught.value.path == path and str(caught.value).startswith(f'{path}: ')
