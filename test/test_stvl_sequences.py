"""Nav2's SpatioTemporalVoxelLayer on the node's clouds, over rendered sequences with truth.

Every frame of each sequence goes through the node's own frame path in-process
(``bag_processor.process_frame``: the frame gate, the pipeline and the messages the node
publishes; test_bag_process checks they equal the node's) with params/corridor.yaml. Its
``obstacles/points`` go into the port of STVL 2.5.5 (test/stvl_layer.py) configured by
params/nav2_stvl.yaml, with TF from the sequence's true poses (exact odometry) and the URDF's
mount (corridor.yaml's, or one 1.5 deg / 3 cm off for the URDF-off run); the frustum is posed
by the clearing cloud's frame (the optical frame), never by the floor fit. The runs (``RUNS``):
every sequence of ``SEQUENCE_NAMES``, and the held-out drive with the body pitching +-2 deg and
with the URDF off. Per run two costmaps run side by side: one updated at every frame (30 Hz)
and one at the file's ``update_frequency`` (5 Hz, every 6th frame). Clouds are buffered as they
come (30 Hz); an update reads the newest (``observation_persistence: 0``).
test/nav2_replay.py defines the figures; ``pytest -s`` prints them (README, Use with Nav2).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import nav2_layers as nav2
import nav2_replay as replay
import numpy as np
import pytest
import ros_env
import stvl_layer as stvl
from builtin_interfaces.msg import Time
from message_helpers import pointcloud2_to_points

from obstacle_detection.cli import bag_processor
from obstacle_detection.ros.conversions import array_to_image, intrinsics_to_camera_info
from obstacle_detection.ros.frame_gate import CameraState
from obstacle_detection.sim.scenes import scene_params
from obstacle_detection.sim.sequences import (PERFECT_ODOMETRY, PITCH_PHASES_DEG, SEQUENCE_NAMES,
                                              BodyPitch, SceneSequence)

REPO = ros_env.REPO_ROOT
CORRIDOR = REPO / 'params' / 'corridor.yaml'
STVL_YAML = REPO / 'params' / 'nav2_stvl.yaml'
FRAME_ID = 'camera_depth_optical_frame'
OBSTACLES, FRUSTUM = 'detector_obstacles', 'detector_frustum'


class STVLReplay(replay.Replay):
    """Replay's scoring around the STVL port: clouds buffered as they come, updates scored.

    The scoring (truth lattice, figures) is Replay's; the costmap is
    :class:`stvl_layer.STVLCostmap`.
    """

    def __init__(self, name: str, config: nav2.CostmapConfig,
                 mount: tuple[np.ndarray, np.ndarray], poses: list[Any], layer: str) -> None:
        super().__init__(name, config, mount, poses, layer_name=layer)
        self.costmap = stvl.STVLCostmap(config)
        self.layers = self.costmap.layers
        self.topics = {s.name: s.topic.lstrip('/') for s in stvl.source_settings(config).values()}

    def receive(self, inp: replay.UpdateInput) -> None:
        """Buffer a frame's clouds as they arrive, through 'TF' (true pose, mount)."""
        now_s = inp.index / replay.RATE_HZ
        base_rot = replay.rotation_z(inp.pose[2])
        base_t = np.array([inp.pose[0], inp.pose[1], 0.0])
        frames = {'obstacles/points': (inp.obstacle_points, (base_rot, base_t)),
                  'obstacles/clearing_points': (inp.clearing_points,
                                                (base_rot @ self.mount[0],
                                                 base_t + base_rot @ self.mount[1]))}
        for source, topic in self.topics.items():
            if topic not in frames:
                raise ValueError(f'{source}: topic {topic!r} is not a cloud of the node')
            points, pose = frames[topic]
            self.costmap.buffer(source, points, pose, now_s, now_s)

    def _observations(self, inp: replay.UpdateInput) -> float:
        """Return the time of the update [s] (:meth:`receive` buffered the clouds)."""
        return inp.index / replay.RATE_HZ


def _rendered(sequence: SceneSequence) -> Iterator[Any]:
    """Yield every frame of a sequence, rendering two ahead (the machine's two cores)."""
    with ThreadPoolExecutor(max_workers=2) as pool:
        pending = [pool.submit(sequence.frame, i) for i in range(min(2, len(sequence)))]
        for index in range(len(sequence)):
            frame = pending.pop(0).result()
            if index + 2 < len(sequence):
                pending.append(pool.submit(sequence.frame, index + 2))
            yield frame


@dataclasses.dataclass(frozen=True)
class Run:
    """One scored run: a rendered sequence and the URDF the emulated TF uses.

    body_pitch: the body rocking under the camera (rendered pitched; the URDF, odometry and
    truth do not see it); urdf_error: mount errors of the URDF (nav2_replay.urdf_off) while
    the rendering and the node's parameters keep the true mount.
    """

    name: str
    sequence: str
    body_pitch: BodyPitch | None = None
    urdf_error: dict | None = None


#: Every sequence; the held-out drive also with the body pitching +-2 deg (one phase of
#: PITCH_PHASES_DEG: test_nav2_held_out runs all four for the VoxelLayer) and with a URDF
#: 1.5 deg / 3 cm off (the same frames).
RUNS: tuple[Run, ...] = (
    *(Run(name, name) for name in SEQUENCE_NAMES),
    Run('drive_by_table, pitching', 'drive_by_table',
        body_pitch=BodyPitch(amplitude_deg=2.0, period_s=1.2, phase_deg=PITCH_PHASES_DEG[0])),
    Run('drive_by_table, URDF off', 'drive_by_table', urdf_error=replay.URDF_ERROR),
)


def play_runs(runs: list[Run], config: nav2.CostmapConfig, values: dict[str, Any],
              periods: dict[str, int]) -> list[replay.SequenceFigures]:
    """Render the frames the runs share once; one STVL costmap per run and update period."""
    node = bag_processor.config_from_values(values, str(CORRIDOR))
    first = runs[0]
    sequence = SceneSequence(first.sequence, odometry=PERFECT_ODOMETRY,
                             body_pitch=first.body_pitch)
    poses = [sequence.pose_true(i) for i in range(len(sequence))]
    replays = []
    for run in runs:
        urdf = values if run.urdf_error is None else replay.urdf_off(values, run.urdf_error)
        replays += [(period, STVLReplay(run.name, config, replay.camera_mount(urdf), poses,
                                        f'STVL {label}')) for label, period in periods.items()]
    cameras: list[CameraState] = []
    obstacles = np.zeros((0, 3))
    for sf in _rendered(sequence):
        index = sf.index
        stamp = Time(sec=1000 + index // 30, nanosec=int((index % 30) * 1e9 / 30))
        if not cameras:
            height, width = sf.frame.depth_mm.shape
            cameras.append(CameraState.from_camera_info(intrinsics_to_camera_info(
                sf.frame.intrinsics, width, height, stamp=stamp, frame_id=FRAME_ID)))
        image = array_to_image(sf.frame.depth_mm, stamp=stamp, frame_id=FRAME_ID)
        messages, _, reason, _ = bag_processor.process_frame(
            image, cameras, node, with_ground=False, with_overlay=False)
        # a frame with no valid pixel (the 0.5 m blind zone) publishes nothing: the buffers
        # keep the newest cloud they have
        if messages is not None:
            assert messages['obstacles'].header.frame_id == node.cloud_frame_id
            obstacles = pointcloud2_to_points(messages['obstacles'])
        elif not reason.startswith('no valid depth pixel'):
            raise AssertionError(f'{first.sequence} frame {index}: {reason}')
        update = replay.UpdateInput(
            index=index, pose=sf.pose_true, obstacle_points=obstacles,
            clearing_points=np.zeros((0, 3), np.float32), truth_obstacle=np.zeros((0, 3)),
            truth_free=np.zeros((0, 3)))
        for _, r in replays:
            r.receive(update)
        if all(index % period for period, _ in replays):
            continue
        truth_obstacle, truth_floor, truth_person = replay.frame_truth(
            sf, scene_params(sf.frame, node.detector.params))
        update = dataclasses.replace(
            update, truth_obstacle=truth_obstacle, truth_free=truth_floor,
            person_in_view=replay.person_in_view(sf.frame), truth_person=truth_person,
            person_disc=replay.person_disc(sf))
        for period, r in replays:
            if index % period == 0:
                r.step(update)
    return [r.report() for _, r in replays]


def update_periods(config: nav2.CostmapConfig) -> dict[str, int]:
    """Update periods [frames]: every frame, and the file's update_frequency."""
    step = round(replay.RATE_HZ / config.update_frequency_hz)
    return {'30 Hz': 1, f'{config.update_frequency_hz:g} Hz': step}


@pytest.fixture(scope='module')
def figures() -> dict[tuple[str, str], replay.SequenceFigures]:
    config = stvl.read_stvl_costmap(STVL_YAML)
    # with STVL the node sends the clouds as seen: no marks matched to a raytracing layer's
    # cells and voxels (clearing_voxel_m 0, params/nav2_stvl.yaml says so)
    values = bag_processor.node_param_values(CORRIDOR) | {'clearing_voxel_m': 0.0}
    groups: dict[tuple, list[Run]] = {}
    for run in RUNS:        # runs that share their frames are played together
        groups.setdefault((run.sequence, run.body_pitch), []).append(run)
    reports = [f for runs in groups.values()
               for f in play_runs(runs, config, values, update_periods(config))]
    print(f'\n{replay.format_table(reports)}')
    return {(f.name, f.layer): f for f in reports}


RATES = list(update_periods(stvl.read_stvl_costmap(STVL_YAML)))
#: Measured misses, expected to fail (strict: a pass is reported too).
#: At 5 Hz, from STVL's order (updateBounds: ClearFrustums builds the column counts, Mark comes
#: after, UpdateROSCostmap reads the counts): a mark reaches the costmap one update later
#: (upstream issue #284), 0.2 s at 5 Hz. New cells appear late while driving (F1 0.963) and a
#: walking person is drawn where it stood 0.2 s before (F1 0.939 and 0.903; a noisy mark at its
#: edge lands on floor seen free since the start: 1 stale cell).
LATE_AT_5_HZ = pytest.mark.xfail(strict=True, reason='STVL marks after it fills the costmap: '
                                 'one update late (spatio_temporal_voxel_layer issue #284)')
KNOWN_MISSES = {('f1', 'drive_past_boxes', '5 Hz'): LATE_AT_5_HZ,
                ('f1', 'person_crossing', '5 Hz'): LATE_AT_5_HZ,
                ('stale', 'person_crossing', '5 Hz'): LATE_AT_5_HZ,
                ('f1', 'person_leaving_edge', '5 Hz'): LATE_AT_5_HZ}


def cases(figure: str) -> list[Any]:
    """(run, rate) pairs; those in KNOWN_MISSES marked as expected to fail."""
    return [pytest.param(name, rate, marks=[KNOWN_MISSES[(figure, name, rate)]]
                         if (figure, name, rate) in KNOWN_MISSES else [])
            for name in (run.name for run in RUNS) for rate in RATES]


CASES = cases('')


@pytest.mark.parametrize(('name', 'rate'), CASES)
def test_no_ghost_10_frames_after_the_person_left(figures: dict, name: str, rate: str) -> None:
    got = figures[(name, f'STVL {rate}')]
    if got.leave_frame is None:
        pytest.skip(f'{name} has no person that leaves the view')

    assert got.ghost_after_10 == 0
    assert got.frames_to_clear <= replay.CLEAR_BUDGET_FRAMES


@pytest.mark.parametrize(('name', 'rate'), cases('f1'))
def test_costmap_f1_with_one_cell_tolerance(figures: dict, name: str, rate: str) -> None:
    assert figures[(name, f'STVL {rate}')].f1 >= 0.97


@pytest.mark.parametrize(('name', 'rate'), cases('stale'))
def test_no_seen_free_floor_left_lethal_after_10_frames(figures: dict, name: str,
                                                        rate: str) -> None:
    assert figures[(name, f'STVL {rate}')].stale_lethal_max == 0


@pytest.mark.parametrize(('name', 'rate'), CASES)
def test_no_unknown_cell_in_the_seen_area(figures: dict, name: str, rate: str) -> None:
    assert figures[(name, f'STVL {rate}')].unknown_seen_max == 0


@pytest.mark.parametrize(('name', 'rate'), CASES)
def test_obstacles_stay_marked_after_leaving_the_view(figures: dict, name: str,
                                                      rate: str) -> None:
    got = figures[(name, f'STVL {rate}')]
    if got.kept_cells < 100:
        pytest.skip(f'{name}: too few obstacle cells left the view ({got.kept_cells})')

    assert got.kept >= 0.95
