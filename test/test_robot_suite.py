"""The robot-level suite (scenarios_robot.json) with params/corridor.yaml: figures held.

Measured (README, Accuracy): overall cell F1 0.941, false alarms 0.87 % of free cells, 44 of 44
named objects found, passable ramps and landing 99.9 % free, 3 of 3 drops marked; the seed's
Table 4.2 scores cell F1 0.40 on the same truth. The floors are issue 9's own targets (cell F1
>= 0.9, false alarms <= 1 %, every object found, every drop marked, >= 97 % passable free):
the measurement clears them by 0.04 and 0.13 points, enough for last-digit differences
between machines (float summation order in BLAS, OpenCV builds), not for a real regression.
"""

from pathlib import Path

import pytest

from obstacle_detection.evaluation import runner as evaluation
from obstacle_detection.pipeline.params import table_4_2
from obstacle_detection.ros.parameters import detector_params_from_ros, read_params_file

REPO = Path(__file__).resolve().parents[1]
SUITE = evaluation.SUITES['robot']


def run_suite(params):
    """Evaluate every scenario of the robot-level suite; return the overall summary."""
    frames = (frame for scenario in evaluation.load_scenarios(SUITE)
              for frame in evaluation.scenario_frames(scenario))
    return evaluation.evaluate_frames(frames, params).overall


@pytest.fixture(scope='module')
def corridor_overall():
    params = detector_params_from_ros(read_params_file(REPO / 'params' / 'corridor.yaml'))
    assert params.robot_level and params.refine_floor
    return run_suite(params)


def test_corridor_yaml_holds_the_robot_level_figures(corridor_overall):
    cell = corridor_overall.cell
    assert cell.f1 >= 0.9
    assert cell.false_alarm_rate <= 0.01
    found, counted, missed = corridor_overall.objects_found()
    assert counted >= 40 and found == counted, missed
    marked, drops, unmarked = corridor_overall.drops_marked()
    assert drops >= 3 and marked == drops, unmarked
    assert corridor_overall.passable_free() >= 0.97


def test_the_seed_method_does_not(corridor_overall):
    seed = run_suite(table_4_2())
    assert seed.cell.f1 < corridor_overall.cell.f1 - 0.3      # flat tops, curbs, drops
    marked, drops, _ = seed.drops_marked()
    assert marked < drops
