"""tools/sweep.py: the best-of-grid rule, a tiny real sweep, and the command."""

import argparse
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from obstacle_detection.evaluation import runner as evaluation
from obstacle_detection.pipeline.params import table_4_2
from obstacle_detection.evaluation import sweep as grid_search
from obstacle_detection.tools import sweep

NAN = float('nan')


def test_best_of_grid_on_a_hand_made_grid():
    scores = np.array([[0.2, 0.7, NAN],
                       [0.9, 0.1, 0.9]])
    assert grid_search.best_of_grid(scores) == (1, 0)  # first of the tied 0.9s, NaN ignored
    assert grid_search.best_of_grid(scores, higher_is_better=False) == (1, 1)


def test_best_of_an_all_nan_grid_is_none():
    assert grid_search.best_of_grid(np.full((2, 2), NAN)) is None


def test_axis_parsing():
    axis = grid_search.parse_axis('theta_deg=15, 20,30')
    assert axis == grid_search.Axis('theta_deg', ('15', '20', '30'))
    with pytest.raises(argparse.ArgumentTypeError, match="'abc' is not a number"):
        grid_search.parse_axis('N=3,abc')


@pytest.fixture(scope='module')
def small_frames():
    scenario = evaluation.Scenario('corridor', 'corridor', seeds=(0,))
    return list(evaluation.scenario_frames(scenario, size=(128, 106)))


def score_here(frames):
    """Return a scorer that evaluates the points on ``frames`` in this process."""
    return lambda points: [evaluation.evaluate_frames(frames, p).frames for p in points]


def test_tiny_sweep_best_is_the_argmax_of_its_own_scores(small_frames):
    x = grid_search.Axis('theta_deg', ('10', '30', '80'))
    y = grid_search.Axis('N', ('5', '10'))
    result = grid_search.grid_sweep(score_here(small_frames), table_4_2(), x, y, 'cell_f1')
    grid = result.grids['corridor']
    assert grid.shape == (2, 3) and np.isfinite(grid).all()
    row, col = result.best('corridor')
    assert grid[row, col] == np.nanmax(grid)
    assert f'{grid[row, col]:.3f}*' in grid_search.format_grid(result, 'corridor')
    # Each cell is what a plain evaluation with that setting gives.
    params = evaluation.apply_overrides(table_4_2(), result.setting(row, col))
    report = evaluation.evaluate_frames(small_frames, params)
    assert report.scenes['corridor'].cell.f1 == pytest.approx(grid[row, col])


def test_invalid_setting_is_nan_not_an_error(small_frames):
    x = grid_search.Axis('K', ('4', '5'))  # an even median kernel is refused by DetectorParams
    result = grid_search.grid_sweep(score_here(small_frames), table_4_2(), x, None)
    assert np.isnan(result.grids['overall'][0, 0]) and np.isfinite(result.grids['overall'][0, 1])
    assert result.best('overall') == (0, 1)
    with pytest.raises(ValueError, match='no valid setting'):
        grid_search.grid_sweep(score_here(small_frames), table_4_2(),
                               grid_search.Axis('K', ('4', '6')), None)


def test_command_prints_grid_names_best_and_saves_heatmap(tmp_path, capsys):
    out = tmp_path / 'heat.png'
    data = tmp_path / 'grid.json'
    code = sweep.main(['--x', 'theta_deg=20,60', '--y', 'N1=0,12', '--scene', 'ramps',
                       '--out', str(out), '--json', str(data), '--workers', '0'])
    assert code == 0
    text = capsys.readouterr().out
    assert 'best setting per scenario' in text and 'ramps' in text
    saved = json.loads(data.read_text())
    grid = np.array(saved['grids']['ramps'], dtype=float)
    row, col = np.unravel_index(np.nanargmax(grid), grid.shape)
    assert saved['best']['ramps'] == {'theta_deg': ['20', '60'][col], 'N1': ['0', '12'][row]}
    assert cv2.imread(str(out)) is not None


def test_command_says_its_suite_and_frames_and_writes_into_out(tmp_path, capsys, monkeypatch):
    # sweep scores one frame per scenario by default: said, with evaluate's all-frames score
    # beside it not the same number; the heatmap goes to out/ (ignored by git), not the cwd
    monkeypatch.chdir(tmp_path)
    code = sweep.main(['--x', 'theta_deg=20,60', '--scene', 'ramps', '--workers', '0'])
    assert code == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith('suite: seed (scenarios.json, the seed\'s slope-only truth), '
                               '1 frame per scenario (--max-frames 1, the default of sweep; '
                               'evaluate scores every frame); parameters: corridor; 1 frames;')
    assert lines[-1] == f'heatmap: {Path("out") / "sweep.png"}'
    assert (tmp_path / 'out' / 'sweep.png').is_file() and not (tmp_path / 'sweep.png').exists()


def test_heatmap_has_a_title_and_one_colour_scale(tmp_path, monkeypatch):
    # sweep.png had no title and no colour scale, and false-alarm panels coloured 1 - value
    # without a word on the picture
    from obstacle_detection.viz import pictures

    titles: list[str] = []
    titled = pictures.titled

    def recorded(image, title, **kwargs):
        titles.append(title)
        return titled(image, title, **kwargs)
    monkeypatch.setattr(pictures, 'titled', recorded)
    out = tmp_path / 'heat.png'
    assert sweep.main(['--x', 'theta_deg=20,60', '--scene', 'ramps', '--scene',
                       'pitched_floor', '--out', str(out), '--workers', '0']) == 0
    assert titles == ['sweep of theta_deg: cell_f1 per scenario (seed suite, 1 frame per '
                      'scenario, preset corridor); red box: the best setting']
    image = cv2.cvtColor(cv2.imread(str(out)), cv2.COLOR_BGR2RGB)
    for level in (0, 255):   # both ends of the one colour scale are drawn
        colour = cv2.cvtColor(cv2.applyColorMap(np.uint8([[level]]), cv2.COLORMAP_VIRIDIS),
                              cv2.COLOR_BGR2RGB)[0, 0]
        assert (image == colour).all(axis=-1).any(), level


def test_command_refuses_an_unknown_axis(capsys):
    assert sweep.main(['--x', 'Q=1,2', '--scene', 'corridor']) == 2
    assert "unknown parameter 'Q'" in capsys.readouterr().err


def test_scene_without_truth_obstacles_is_ranked_by_false_alarms():
    x = grid_search.Axis('theta_deg', ('10', '60'))
    result = grid_search.SweepResult(
        x, None, 'cell_f1', grids={'floor': np.array([[0.0, NAN]])},
        false_alarms={'floor': np.array([[0.3, 0.0]])}, positives={'floor': 0})
    assert result.ranking('floor')[1] == 'cell_false_alarm'
    assert result.best('floor') == (0, 1)
