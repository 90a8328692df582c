"""DetectorParams validation and the seed presets."""

import dataclasses
import math

import pytest

from obstacle_detection.params import (SEED_TABLE_4_1, DetectorParams, Intrinsics, table_4_2,
                                       table_4_3)


def test_defaults_are_seed_table_4_2():
    p = DetectorParams()
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
        assert 'min' in f.metadata and 'max' in f.metadata, f.name


@pytest.mark.parametrize('bad', [dict(fx=0.0), dict(fy=-1.0), dict(cx=float('nan'))])
def test_intrinsics_reject_bad_values(bad):
    values = dict(fx=365.0, fy=365.0, cx=256.0, cy=212.0)
    values.update(bad)
    with pytest.raises(ValueError, match='intrinsics'):
        Intrinsics(**values)
