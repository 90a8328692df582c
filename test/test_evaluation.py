"""The scenario suite runner and tools/evaluate.py on small frames."""

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from obstacle_detection.labels import (CELL_FREE, CELL_OCCUPIED, GT_ABOVE_ROBOT, GT_OBSTACLE,
                                       LABEL_OBSTACLE)
from obstacle_detection.evaluation import runner as evaluation, metrics
from obstacle_detection.sim import scenes
from obstacle_detection.evaluation.metrics import Confusion
from obstacle_detection.pipeline.params import table_4_2, table_4_3
from obstacle_detection.tools import evaluate


REPO = Path(__file__).resolve().parents[1]
SUITE = evaluation.SUITES['seed']
SMALL = (256, 212)  # half the Kinect v2 SD size: same field of view, a quarter of the pixels


def _corridor_frame(size=SMALL):
    scenario = evaluation.Scenario('corridor', 'corridor', seeds=(0,))
    return next(evaluation.scenario_frames(scenario, size=size))


def test_committed_suite_names_real_scenes_and_covers_the_issue():
    scenarios = evaluation.load_scenarios(SUITE)
    assert {s.scene for s in scenarios} <= set(scenes.SCENE_NAMES)
    covered = {s.scene for s in scenarios}
    for needed in ('corridor', 'ramps', 'people', 'farm_row', 'step_down', 'dark_materials',
                   'person_walking'):
        assert needed in covered
    assert any(dict(s.mount).get('pitch_deg') for s in scenarios)
    assert any(s.is_sequence and s.frame_count > 1 for s in scenarios)


def test_scenario_frame_range_and_mount_in_degrees():
    s = evaluation.scenario_from_dict({
        'name': 'walk', 'scene': 'person_walking', 'seeds': [1, 2],
        'frames': {'start': 0, 'stop': 10, 'step': 5}, 'mount': {'pitch_deg': 30.0}})
    assert s.frames == (0, 5) and s.frame_count == 4
    assert s.render_kwargs() == {'pitch_rad': pytest.approx(math.radians(30.0))}


def test_overrides_accept_seed_names_degrees_and_voxel_size():
    p = evaluation.apply_overrides(table_4_2(), {'theta_deg': '45', 'N': '5', 'N1': 3,
                                                 'voxel_m': 0.05, 'K': 9})
    assert p.max_slope_rad == pytest.approx(math.pi / 4)
    assert (p.normal_neighbours, p.validation_neighbours, p.median_kernel) == (5, 3, 9)
    assert p.voxel_size_m == (0.05, 0.05, 0.05)


def test_overrides_set_booleans_written_as_words():
    base = table_4_2()
    assert not base.robot_level and not base.refine_floor
    p = evaluation.apply_overrides(base, {'robot_level': 'true', 'refine_floor': 'Yes'})
    assert p.robot_level is True and p.refine_floor is True
    q = evaluation.apply_overrides(p, {'robot_level': '0', 'refine_floor': False})
    assert q.robot_level is False and q.refine_floor is False
    with pytest.raises(ValueError, match="robot_level='maybe' must be true or false"):
        evaluation.apply_overrides(base, {'robot_level': 'maybe'})


def test_overrides_refuse_unknown_names_and_fractional_counts():
    with pytest.raises(ValueError, match="unknown parameter 'Q'"):
        evaluation.apply_overrides(table_4_2(), {'Q': 1})
    with pytest.raises(ValueError, match='N=5.5 must be an integer'):
        evaluation.apply_overrides(table_4_2(), {'N': 5.5})


def test_node_parameter_file(tmp_path):
    path = tmp_path / 'node.yaml'
    path.write_text('/**:\n  ros__parameters:\n    max_slope_deg: 45.0\n'
                    '    normal_neighbours: 5\n    publish_ground: true\n')
    p = evaluation.load_params_file(path)
    assert p.max_slope_rad == pytest.approx(math.pi / 4)
    assert p.normal_neighbours == 5
    assert evaluation.load_params_file(path, table_4_3()).median_kernel == 7   # on the base
    path.write_text('/**:\n  ros__parameters:\n    depth_topic: /camera/depth\n')
    # not the node's either: ignored as the node ignores it (the tools warn, as the node does)
    assert evaluation.load_params_file(path) == table_4_2()


def test_evaluate_warns_about_a_misspelt_parameter_as_the_node(tmp_path, capsys):
    path = tmp_path / 'typo.yaml'
    path.write_text('/**:\n  ros__parameters:\n    max_slope_dg: 20.0\n')
    assert evaluate.main(['--params-file', str(path), '--scene', 'curb_sill', '--max-frames',
                          '1', '--quiet', '--workers', '0']) == 0
    assert (f"warning: {path}: unknown parameter 'max_slope_dg' is ignored (did you mean "
            "'max_slope_deg'?)") in capsys.readouterr().err


def test_truth_grid_uses_the_costmap_binning():
    frame = _corridor_frame()
    params = frame.params(table_4_2())
    grid = evaluation.truth_costmap(frame, params)
    from obstacle_detection.pipeline.costmap import costmap_geometry
    origin, nx, ny = costmap_geometry(params)
    flat = frame.truth_points.reshape(-1, 3)
    finite = np.isfinite(flat).all(axis=1)
    roi = np.zeros(flat.shape[0], bool)
    from obstacle_detection.pipeline import geometry
    roi[finite] = geometry.roi_mask(flat[finite], params)
    obstacle, traversable = metrics.truth_points(frame.truth_points, frame.truth_labels,
                                                 roi.reshape(frame.truth_labels.shape))
    reference = metrics.truth_grid(obstacle, traversable, origin, params.costmap_resolution_m,
                                   (ny, nx))
    np.testing.assert_array_equal(grid, reference)
    assert np.count_nonzero(grid == CELL_OCCUPIED) > 20


class _RecordingRefiner:
    """A stand-in LogisticRefiner: predicts the rule-based mask and logs its inputs."""

    def __init__(self):
        self.previous = []

    def predict_labels(self, result, previous_mask):
        self.previous.append(previous_mask)
        return result.labels == LABEL_OBSTACLE


def test_sequence_frames_pass_the_previous_rule_based_mask():
    scenario = evaluation.Scenario('walk', 'person_walking', seeds=(0,), frames=(0, 6))
    frames = list(evaluation.scenario_frames(scenario, size=(128, 106)))
    still = _corridor_frame((128, 106))
    refiner = _RecordingRefiner()
    report = evaluation.evaluate_frames(frames + [still], table_4_2(), refiner=refiner)
    assert refiner.previous[0] is None and refiner.previous[2] is None
    assert refiner.previous[1] is not None and refiner.previous[1].shape == (106, 128)
    # The stand-in reproduces the rule-based pixel labels, so the pixel scores agree (the
    # refined costmap differs: its voxels go through the N1 validation a second time).
    assert report.overall.refined_pixel == report.overall.pixel
    assert sum(dataclasses.astuple(report.overall.refined_cell)) == \
        sum(dataclasses.astuple(report.overall.cell))


def test_report_pools_counts_and_serialises_nan_as_null():
    summary = evaluation.SceneSummary('x')
    summary.add(evaluation.FrameScore('x', '0', Confusion(0, 0, 0, 5), Confusion(1, 1, 0, 2),
                                      10.0))
    summary.add(evaluation.FrameScore('x', '1', Confusion(0, 1, 0, 5), Confusion(1, 0, 1, 2),
                                      20.0))
    assert summary.cell == Confusion(2, 1, 1, 4) and summary.mean_ms == 15.0
    data = summary.as_dict()
    assert data['pixel']['recall'] is None
    json.dumps(data, allow_nan=False)


def test_evaluate_one_corridor_frame_scores_above_a_floor(tmp_path, capsys):
    out = tmp_path / 'report.json'
    code = evaluate.main(['--suite', 'seed', '--scene', 'corridor', '--max-frames', '1',
                          '--json', str(out), '--quiet', '--preset', 'table_4_2'])
    assert code == 0
    table = capsys.readouterr().out
    assert 'corridor' in table and 'overall' in table and 'cell F1' in table
    report = json.loads(out.read_text())
    corridor = report['scenes']['corridor']
    assert corridor['frames'] == 1
    # Box tops are flat and so 'ground' for the seed's method: the cell recall is limited.
    assert corridor['cell']['f1'] > 0.45
    assert corridor['pixel']['f1'] > 0.85
    assert corridor['cell']['false_alarm_rate'] < 0.2


def test_evaluate_reports_bad_input_with_exit_code_2(capsys):
    assert evaluate.main(['--scene', 'no_such_scene']) == 2
    assert "unknown scenario 'no_such_scene'" in capsys.readouterr().err
    assert evaluate.main(['--scene', 'corridor', '--max-frames', '0']) == 2
    assert 'evaluate: error: --max-frames=0 must be >= 1' in capsys.readouterr().err
    assert evaluate.main(['--scene', 'corridor', '--set', 'Q=1']) == 2
    assert "unknown parameter 'Q'" in capsys.readouterr().err


def test_truth_obstacles_exist_in_every_suite_scene_but_the_empty_floor():
    for scenario in evaluation.load_scenarios(SUITE):
        frame = next(evaluation.scenario_frames(scenario, max_frames=1, size=(64, 53)))
        has_obstacle = bool(np.any(frame.truth_labels == GT_OBSTACLE))
        assert has_obstacle == (scenario.scene != 'pitched_floor'), scenario.name


def _shipped_parameter_files():
    """(file, preset) pairs: the navigation default, the seed tables (issue 9 adds files)."""
    from obstacle_detection.pipeline.params import PRESETS
    folder = REPO / 'params'
    pairs = [('corridor.yaml', 'corridor' if 'corridor' in PRESETS else 'table_4_2'),
             ('corridor_video.yaml', 'table_4_3')]
    pairs += [(f'seed_{name}.yaml', name) for name in ('table_4_2', 'table_4_3')
              if (folder / f'seed_{name}.yaml').is_file()]
    return pairs


@pytest.mark.parametrize('name, preset', _shipped_parameter_files())
def test_shipped_parameter_files_reproduce_the_presets(name, preset):
    from obstacle_detection.pipeline.params import PRESETS
    path = REPO / 'params' / name
    assert evaluation.load_params_file(path) == PRESETS[preset]()


# -- the robot-level suite (issue 9) ----------------------------------------------------------

ROBOT_SUITE = evaluation.SUITES['robot']


def _robot_frame(name, size=SMALL):
    scenario = next(s for s in evaluation.load_scenarios(ROBOT_SUITE) if s.name == name)
    return next(evaluation.scenario_frames(scenario, size=size, max_frames=1))


def test_robot_suite_covers_the_issue_scenes_with_robot_truth_and_tof_noise():
    scenarios = evaluation.load_scenarios(ROBOT_SUITE)
    assert {s.scene for s in scenarios} <= set(scenes.SCENE_NAMES)
    for needed in ('office', 'dark_office', 'ramp_landing', 'dock_edge', 'dock_edge_high',
                   'curb_sill', 'shelf', 'orchard', 'corridor', 'step_down',
                   'open_ramp', 'open_ramp_ahead', 'dark_furniture', 'thin_legs'):
        assert needed in {s.scene for s in scenarios}
    assert all(s.truth == 'robot' for s in scenarios)
    # time-of-flight noise; issue 22's dark furniture with its dropouts in blobs
    assert all(s.noise == ('kinect_v2_tof_blobs' if s.scene == 'dark_furniture'
                           else 'kinect_v2_tof') for s in scenarios)
    assert any(dict(s.mount).get('pitch_deg') and dict(s.mount).get('roll_deg')
               for s in scenarios)
    # the seed suite keeps its truth and sensor model
    assert all(s.truth == 'seed' and s.noise == 'kinect_v2'
               for s in evaluation.load_scenarios(SUITE))


def test_seed_suite_frames_carry_the_slope_only_truth():
    frame = _corridor_frame()
    rendered = scenes.render_scene('corridor', seed=0, size=SMALL, intrinsics=frame.intrinsics)
    np.testing.assert_array_equal(frame.truth_labels, rendered.labels_seed)
    assert frame.truth == 'seed'
    assert not (frame.truth_labels == GT_ABOVE_ROBOT).any()
    robot = next(evaluation.scenario_frames(
        evaluation.Scenario('corridor', 'corridor', truth='robot'), size=SMALL))
    np.testing.assert_array_equal(robot.truth_labels, rendered.labels)


def test_robot_truth_grid_marks_the_drop_edge_and_the_lower_floor():
    frame = _robot_frame('dock_edge_high')
    params = frame.params(table_4_2())
    grid = evaluation.truth_costmap(frame, params)
    from obstacle_detection.pipeline.costmap import costmap_geometry
    origin, nx, ny = costmap_geometry(params)
    x_edge = next(p.x_m for p in scenes.build_scene('dock_edge_high', seed=0).primitives)
    x_centres = origin[0] + (np.arange(nx) + 0.5) * params.costmap_resolution_m
    occupied = grid == CELL_OCCUPIED
    edge_col = int(np.floor((x_edge - 1e-3 - origin[0]) / params.costmap_resolution_m))
    assert occupied[:, edge_col].sum() > 10                         # where the floor ends
    assert occupied[:, x_centres > x_edge + 0.3].sum() > 50         # the lower floor, < TDBG
    assert not occupied[:, x_centres < x_edge - 0.1].any()          # the dock is free
    assert (grid[:, x_centres < x_edge - 0.1] == CELL_FREE).sum() > 50


@pytest.mark.parametrize('name', ['office', 'ramp_landing', 'dock_edge', 'curb_sill'])
def test_robot_checks_of_a_perfect_and_of_a_blind_costmap(name):
    frame = _robot_frame(name)
    params = frame.params(table_4_2())
    roi = evaluation.truth_roi(frame, params)
    truth = evaluation.truth_costmap(frame, params, roi)
    perfect = evaluation.robot_score(frame, truth, params, truth, roi)
    blind = evaluation.robot_score(frame, np.full_like(truth, CELL_FREE), params,
                                   truth, roi)
    entries = perfect.objects + perfect.passable + perfect.drops
    assert entries
    assert all(hits == cells for _, hits, cells in entries)
    assert all(hits == 0 for _, hits, _ in blind.objects + blind.drops)
    assert all(hits == cells for _, hits, cells in blind.passable)
    kinds = {'office': 'objects', 'ramp_landing': 'passable', 'dock_edge': 'drops',
             'curb_sill': 'passable'}
    assert getattr(perfect, kinds[name])
    if name == 'office':
        assert {n for n, _, _ in perfect.objects} == {'box_small', 'box_large', 'table', 'chair'}
    if name == 'ramp_landing':
        assert {n for n, _, _ in perfect.passable} == {'ramp', 'landing'}
        assert {n for n, _, _ in perfect.objects} == {'steep_ramp'}


def test_robot_summary_pools_found_objects_passable_cells_and_drops():
    summary = evaluation.SceneSummary('x')
    for frame_id, robot in (('0', evaluation.RobotScore([('box', 3, 4), ('table', 1, 4)],
                                                        [('ramp', 9, 10)], [('drop', 2, 4)])),
                            ('1', evaluation.RobotScore([('box', 2, 4)], [('ramp', 10, 10)],
                                                        [('drop', 1, 4)]))):
        summary.add(evaluation.FrameScore('x', frame_id, Confusion(), Confusion(), 1.0,
                                          robot=robot))
    assert summary.objects_found() == (2, 3, ['table (x 0)'])
    assert summary.passable_free() == pytest.approx(19 / 20)
    assert summary.drops_marked() == (1, 2, ['drop (x 1)'])
    data = summary.as_dict()['robot']
    assert data['objects_found'] == 2 and data['unmarked'] == ['drop (x 1)']


def test_evaluate_without_suite_scores_the_readmes_robot_suite(capsys):
    # the README's accuracy table is the robot suite with corridor.yaml: the defaults
    code = evaluate.main(['--scene', 'curb_sill', '--max-frames', '1', '--quiet',
                          '--workers', '0'])
    assert code == 0
    table = capsys.readouterr().out
    assert table.startswith('suite: robot (scenarios_robot.json, robot-level truth); '
                            'parameters: corridor; 1 frames in ')
    assert 'robot table (objects found' in table


def test_evaluate_robot_suite_prints_the_robot_table(tmp_path, capsys):
    out = tmp_path / 'report.json'
    code = evaluate.main(['--suite', 'robot', '--scene', 'dock_edge', '--scene', 'curb_sill',
                          '--json', str(out), '--quiet', '--workers', '0'])
    assert code == 0
    table = capsys.readouterr().out
    assert 'robot table (objects found, drops, passable free, 1-cell F1):' in table
    assert 'objects' in table and 'F1 1-cell' in table
    assert 'issue 9' not in table
    report = json.loads(out.read_text())
    assert report['scenes']['dock_edge']['robot']['drops'] == 1
    assert report['scenes']['curb_sill']['robot']['objects'] == 1     # the curb
    assert report['overall']['robot']['passable_free'] is not None      # the sill
    assert report['overall']['robot']['f1_one_cell'] >= report['overall']['cell']['f1']


def test_evaluate_real_frames_names_a_missing_frame(tmp_path, capsys):
    assert evaluate.main(['--real', str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and str(tmp_path / 'tum_office' / 'depth.png') in err


def test_robot_truth_leaves_the_gaps_of_a_grazing_underside_unscored():
    # a table top 0.72 m up seen from 0.6 m: its underside is sampled in rows ~0.1 m apart
    frame = _robot_frame('office', size=scenes.KINECT_V2_SD_SIZE)
    params = frame.params(table_4_2())
    grid = evaluation.truth_costmap(frame, params)
    from obstacle_detection.pipeline.costmap import costmap_geometry
    origin, nx, ny = costmap_geometry(params)
    top = next(p for p in scenes.build_scene('office', seed=0).primitives
               if p.name == 'table')
    (x0, y0, _), (x1, y1, _) = top.bounds()
    res = params.costmap_resolution_m
    x1 = min(x1, params.max_range_m - 0.1)    # inside the range, where the truth has points
    cols = slice(int((x0 - origin[0]) / res) + 1, int((x1 - origin[0]) / res) - 1)
    rows = slice(int((y0 - origin[1]) / res) + 1, int((y1 - origin[1]) / res) - 1)
    under = grid[rows, cols]
    cols_sum = (under == CELL_OCCUPIED).any(axis=0)
    assert 0 < cols_sum.sum() < cols_sum.size        # sampled rows only
    assert not (under == CELL_FREE).all(axis=0).any()   # no column known free


def test_the_tools_default_to_the_navigation_default(tmp_path, capsys):
    # README: `evaluate --suite robot` scores params/corridor.yaml, not the seed's Table 4.2
    code = evaluate.main(['--suite', 'robot', '--scene', 'curb_sill', '--max-frames', '1',
                          '--quiet', '--workers', '0', '--json', str(tmp_path / 'r.json')])
    assert code == 0
    assert 'parameters: corridor' in capsys.readouterr().out


def test_robot_truth_marks_the_cells_of_an_obstacle_that_returned_no_depth():
    # a dark table top 0.8 m up (under the robot's 1 m), seen from below by a camera 0.6 m up:
    # all its pixels drop out, the floor under it is seen between the legs
    from dataclasses import replace

    from obstacle_detection.evaluation.camera import scaled_intrinsics
    from obstacle_detection.pipeline.costmap import costmap_geometry
    from obstacle_detection.pipeline.params import KINECT_V2_SD
    from obstacle_detection.sim.noise import EXACT
    from obstacle_detection.sim.primitives import Box, Floor
    from obstacle_detection.sim.render import Scene, render

    top = Box((1.2, -0.4, 0.77), (1.7, 0.4, 0.8), dark=True, name='top')
    legs = [Box((x, y, 0.0), (x + 0.04, y + 0.04, 0.77), name='leg')
            for x in (1.2, 1.66) for y in (-0.4, 0.36)]
    shot = render(Scene('t', (Floor(), top, *legs)), size=SMALL,
                  intrinsics=scaled_intrinsics(KINECT_V2_SD, 0.5),
                  noise=replace(EXACT, dark_dropout_rate=1.0))
    dropped = shot.hit_index == 1
    assert dropped.sum() > 50 and np.all(shot.depth_mm[dropped] == 0)
    assert np.all(shot.labels[dropped] == evaluation.GT_NO_RETURN)
    frame = evaluation.LabelledFrame(
        't', '0', shot.depth_mm, shot.intrinsics, shot.labels, shot.points_ground,
        shot.height_m, shot.pitch_rad, shot.roll_rad, truth='robot',
        object_ids=shot.hit_index, object_names=shot.object_names,
        drop_edge=shot.drop_edge, hit_labels=shot.hit_labels)
    params = frame.params(table_4_2())
    roi = evaluation.truth_roi(frame, params)
    fixed = evaluation.truth_costmap(frame, params, roi)
    flawed = evaluation.truth_costmap(replace(frame, hit_labels=None), params, roi)
    origin, nx, ny = costmap_geometry(params)
    under_top = metrics.point_cells(shot.points_ground[dropped & roi], origin,
                                    params.costmap_resolution_m, (ny, nx))
    # without the hits, the cells under the top whose floor was seen are called free
    assert (flawed[under_top] == CELL_FREE).sum() > 100           # of 160 under the top
    assert np.all(fixed[under_top & (flawed != evaluation.CELL_UNKNOWN)] == CELL_OCCUPIED)
    np.testing.assert_array_equal(fixed[~under_top], flawed[~under_top])   # nothing else moves
    assert (fixed == CELL_FREE).sum() > 100                                # the floor around
