"""DetectorParams validation and the seed presets."""

import dataclasses
import math

import pytest

from obstacle_detection.pipeline.params import (SEED_TABLE_4_1, DetectorParams, Intrinsics,
                                                corridor, table_4_2, table_4_3)


def test_defaults_are_seed_table_4_2_but_the_median():
    p = DetectorParams(robot_level=False, refine_floor=False, median_kernel=17)
    assert p == table_4_2()
    assert p.max_slope_rad == pytest.approx(math.pi / 6)
    assert (p.validation_neighbours, p.normal_neighbours) == (12, 10)
    assert (p.tdbg_m, p.smar_m, p.max_range_m) == (-0.1, 0.8, 2.0)
    assert p.voxel_size_m == (0.025, 0.025, 0.025)


def test_table_4_3():
    p = table_4_3()
    assert p.max_slope_rad == pytest.approx(math.pi / 3)
    assert (p.validation_neighbours, p.normal_neighbours) == (7, 5)
    assert (p.tdbg_m, p.smar_m, p.max_range_m, p.median_kernel) == (-0.1, 0.8, 1.0, 7)


def test_table_4_1_fallback_intrinsics():
    assert (SEED_TABLE_4_1.fx, SEED_TABLE_4_1.cx, SEED_TABLE_4_1.cy) == (580.0, 200.0, 130.0)


@pytest.mark.parametrize('change, pattern', [
    ({'median_kernel': 4}, r'median_kernel=4 must be odd'),
    ({'median_kernel': 0}, r'median_kernel=0 out of range'),
    ({'max_slope_rad': 0.0}, r'max_slope_rad=0.0 out of range'),
    ({'max_slope_rad': math.pi / 2}, r'max_slope_rad=.* out of range'),
    ({'voxel_x_m': 0.0}, r'voxel_x_m=0.0 out of range'),
    ({'voxel_z_m': -0.025}, r'voxel_z_m=-0.025 out of range'),
    ({'normal_neighbours': 2}, r'normal_neighbours=2 out of range'),
    ({'validation_neighbours': -1}, r'validation_neighbours=-1 out of range'),
    ({'max_range_m': float('nan')}, r'max_range_m=nan must be finite'),
    ({'normal_neighbours': 10.0}, r'normal_neighbours=10.0 must be an integer'),
    ({'crop_top_px': True}, r'crop_top_px=True must be an integer'),
    ({'min_range_m': 3.0}, r'min_range_m=3.0 must be below max_range_m'),
    ({'tdbg_m': 0.5}, r'tdbg_m=0.5 out of range'),
    ({'max_step_height_m': 1.0}, r'max_step_height_m=1.0 must be below robot_height_m=1.0'),
    ({'max_step_height_m': 0.3, 'robot_height_m': 0.2},
     r'max_step_height_m=0.3 must be below robot_height_m=0.2'),
    ({'max_step_height_m': -0.01}, r'max_step_height_m=-0.01 out of range: must be >= 0'),
    ({'max_step_down_m': -0.05}, r'max_step_down_m=-0.05 out of range: must be >= 0'),
    ({'robot_height_m': 0.0}, r'robot_height_m=0.0 out of range: must be > 0'),
    ({'robot_height_m': -1.0}, r'robot_height_m=-1.0 out of range'),
    ({'drop_view_m': -0.5}, r'drop_view_m=-0.5 out of range'),
    ({'floor_max_offset_m': -0.1}, r'floor_max_offset_m=-0.1 out of range'),
    ({'floor_max_tilt_rad': -0.1}, r'floor_max_tilt_rad=-0.1 out of range'),
    ({'robot_level': 1}, r'robot_level=1 must be true or false'),
    ({'refine_floor': 'yes'}, r"refine_floor='yes' must be true or false"),
])
def test_bad_values_raise_naming_the_value(change, pattern):
    with pytest.raises(ValueError, match=pattern):
        DetectorParams(**change)


def test_params_are_frozen_and_replace_validates():
    p = DetectorParams()
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.median_kernel = 5  # type: ignore[misc]
    assert p.replace(median_kernel=5).median_kernel == 5
    with pytest.raises(ValueError, match='median_kernel=6'):
        p.replace(median_kernel=6)
    with pytest.raises(ValueError, match='unknown parameter'):
        p.replace(no_such_thing=1)


def test_every_field_has_description_and_range():
    for f in dataclasses.fields(DetectorParams):
        assert f.metadata['description'], f.name
        if f.type not in ('bool', bool):   # a switch has no range
            assert 'min' in f.metadata and 'max' in f.metadata, f.name


def test_navigation_default_is_table_4_2_with_the_robot_level_rules():
    p = DetectorParams()
    assert p == corridor()
    assert p.robot_level and p.refine_floor
    assert (p.max_step_height_m, p.max_step_down_m, p.robot_height_m) == (0.05, 0.05, 1.0)
    assert (p.median_kernel, table_4_2().median_kernel) == (5, 17)
    seed_fields = {f.name for f in dataclasses.fields(DetectorParams)} - {
        'robot_level', 'refine_floor', 'median_kernel'}
    assert all(getattr(p, name) == getattr(table_4_2(), name) for name in seed_fields)
    assert not table_4_2().robot_level and not table_4_3().robot_level
    assert not table_4_2().refine_floor and not table_4_3().refine_floor


@pytest.mark.parametrize('bad', [dict(fx=0.0), dict(fy=-1.0), dict(cx=float('nan'))])
def test_intrinsics_reject_bad_values(bad):
    values = dict(fx=365.0, fy=365.0, cx=256.0, cy=212.0)
    values.update(bad)
    with pytest.raises(ValueError, match='intrinsics'):
        Intrinsics(**values)


def test_with_frame_mount_equals_a_validated_replace() -> None:
    params = DetectorParams()
    changes = dict(camera_height_m=0.63, camera_pitch_rad=0.02, camera_roll_rad=-0.01,
                   tdbg_m=-1.0)
    fast = params.with_frame_mount(**changes)
    assert fast == params.replace(**changes) and hash(fast) == hash(params.replace(**changes))
    assert params.camera_height_m == 0.6     # the original is untouched
