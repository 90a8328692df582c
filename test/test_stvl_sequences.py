"""Nav2's SpatioTemporalVoxelLayer on the node's clouds, over rendered sequences with truth.

Every frame of each sequence goes through the node's own frame path (``bag_processor.
process_frame``: the frame gate, the pipeline and the messages the node publishes;
test_bag_process checks they equal the node's) with params/corridor.yaml, in two worker
processes that also render the frames and take their truth. The node's ``obstacles/points``
(the obstacles as seen; not the VoxelLayer's ``obstacles/marking_points``, which leave out the
marks within a cell of the view's side: STVL's frustum would decay a box passing there before
it left the view, kept 0.27-0.38 at 30 Hz on drive_by_table, docs/stvl.md) go into the port
of STVL 2.5.5 (test/stvl_layer.py) configured by params/nav2_stvl.yaml, with TF from the
sequence's true poses (exact odometry) and the URDF's mount (corridor.yaml's, or one 1.5 deg /
3 cm off for the URDF-off run); the frustum is posed by the clearing cloud's frame (the
optical frame, placed by the URDF), never by the floor fit. The runs (``RUNS``): every
sequence of ``SEQUENCE_NAMES``, the held-out drive with the body pitching +-2 deg (the four
phases test_nav2_held_out plays) and with the URDF off. Per run three costmaps run side by
side: updated at every frame (30 Hz), at the file's ``update_frequency`` (15 Hz, every 2nd
frame) and at nav2_bringup's 5 Hz (every 6th frame). Clouds are buffered as they come (30 Hz);
an update reads the newest (``observation_persistence: 0``). test/nav2_replay.py defines the
figures; ``pytest -s`` prints them (README, Use with Nav2). The worker processes make the
module ``integration`` (test/conftest.py).
"""

from __future__ import annotations

import dataclasses
import multiprocessing
import time
from concurrent.futures import ProcessPoolExecutor
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
from obstacle_detection.sim.sequences import (PERFECT_ODOMETRY, SEQUENCE_NAMES,
                                              BodyPitch, SceneSequence)

REPO = ros_env.REPO_ROOT
CORRIDOR = REPO / 'params' / 'corridor.yaml'
STVL_YAML = REPO / 'params' / 'nav2_stvl.yaml'
FRAME_ID = 'camera_depth_optical_frame'


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
        self.max_voxels = 0     # the most voxels the grids held after an update
        for source in self.sources.values():
            if source.topic.lstrip('/') not in ('obstacles/points', 'obstacles/clearing_points'):
                raise ValueError(f'{source.name}: topic {source.topic!r} is not a cloud of '
                                 'the node')
            if source.sensor_frame not in ('', FRAME_ID):
                raise ValueError(f'{source.name}: sensor_frame {source.sensor_frame!r}: the '
                                 f'replay knows {FRAME_ID!r} only')

    def receive(self, inp: replay.UpdateInput) -> None:
        """Buffer a frame's clouds as they arrive, through 'TF' (true pose, URDF mount).

        STVL reads no clearing points: a clearing cloud comes with each obstacles/points and
        only its frame (the optical frame) counts.
        """
        now_s = inp.index / replay.RATE_HZ
        base_rot = replay.rotation_z(inp.pose[2])
        base_t = np.array([inp.pose[0], inp.pose[1], 0.0])
        camera = (base_rot @ self.mount[0], base_t + base_rot @ self.mount[1])
        for name, source in self.sources.items():
            on_points = source.topic.lstrip('/') == 'obstacles/points'
            self.costmap.buffer(name, inp.obstacle_points if on_points else inp.clearing_points,
                                (base_rot, base_t) if on_points else camera, now_s, now_s,
                                camera if source.sensor_frame else None)

    def _observations(self, inp: replay.UpdateInput) -> float:
        """Return the time of the update [s] (:meth:`receive` buffered the clouds)."""
        return inp.index / replay.RATE_HZ

    def step(self, inp: replay.UpdateInput) -> np.ndarray:
        """Replay.step, noting how many voxels the grids hold (what an update walks over)."""
        master = super().step(inp)
        self.max_voxels = max(self.max_voxels,
                              sum(layer.grid.keys.size for layer in self.costmap.layers))
        return master

    def report(self) -> replay.SequenceFigures:
        """Replay.report, with ``extra['max_voxels']``."""
        figures = super().report()
        figures.extra['max_voxels'] = self.max_voxels
        return figures


#: Every sequence; the held-out drive also with the body pitching +-2 deg and with a URDF
#: 1.5 deg / 3 cm off, as test_nav2_held_out plays it.
RUNS: tuple[replay.Run, ...] = (
    *(replay.Run(name, name) for name in SEQUENCE_NAMES),
    *replay.HELD_OUT_DRIVES,
)
#: The runs the F1 target is for: the drives (issue 29), not the person sequences.
DRIVES = [run.name for run in RUNS if run.sequence.startswith('drive')]


@dataclasses.dataclass(frozen=True)
class Played:
    """One frame as a worker hands it back: the node's marks and the frame's truth.

    obstacles: the node's obstacles/points, None when the frame published nothing (no valid
    pixel); the truth keeps one point per cell of the scoring lattice (the cells it gives
    are the frame's, point for point).
    """

    index: int
    pose: tuple[float, float, float]
    obstacles: np.ndarray | None
    reason: str
    truth_obstacle: np.ndarray
    truth_free: np.ndarray
    truth_person: np.ndarray
    person_in_view: bool | None
    person_disc: tuple[float, float, float] | None


_WORKER: dict[Any, Any] = {}


def _one_per_cell(points: np.ndarray, pose: tuple[float, float, float],
                  origin: tuple[float, float], res: float) -> np.ndarray:
    """Return the first point of each lattice cell, placed as Replay places them."""
    if points.shape[0] == 0:
        return points
    rot, t = replay.rotation_z(pose[2]), np.array([pose[0], pose[1], 0.0])
    odom = np.asarray(points, np.float64) @ rot.T + t
    ix = np.floor((odom[:, 0] - origin[0]) / res)
    iy = np.floor((odom[:, 1] - origin[1]) / res)
    _, first = np.unique(np.column_stack((ix, iy)), axis=0, return_index=True)
    return points[np.sort(first)]


def play_frame(sequence: str, body_pitch: BodyPitch | None, index: int,
               origin: tuple[float, float], res: float) -> Played:
    """Render one frame, run the node's frame path on it; its marks and truth (a worker)."""
    if 'node' not in _WORKER:
        values = bag_processor.node_param_values(CORRIDOR)
        _WORKER['node'] = bag_processor.config_from_values(values, str(CORRIDOR))
    node = _WORKER['node']
    key = (sequence, body_pitch)
    if key not in _WORKER:
        _WORKER[key] = SceneSequence(sequence, odometry=PERFECT_ODOMETRY, body_pitch=body_pitch)
    sf = _WORKER[key].frame(index)
    stamp = Time(sec=1000 + index // 30, nanosec=int((index % 30) * 1e9 / 30))
    height, width = sf.frame.depth_mm.shape
    cameras = [CameraState.from_camera_info(intrinsics_to_camera_info(
        sf.frame.intrinsics, width, height, stamp=stamp, frame_id=FRAME_ID))]
    image = array_to_image(sf.frame.depth_mm, stamp=stamp, frame_id=FRAME_ID)
    messages, _, reason, _ = bag_processor.process_frame(
        image, cameras, node, with_ground=False, with_overlay=False)
    obstacles = None
    if messages is not None:
        assert messages['obstacles'].header.frame_id == node.cloud_frame_id
        obstacles = pointcloud2_to_points(messages['obstacles'])
    truth_obstacle, truth_floor, truth_person = replay.frame_truth(
        sf, scene_params(sf.frame, node.detector.params))
    return Played(index, sf.pose_true, obstacles, reason,
                  *(_one_per_cell(p, sf.pose_true, origin, res)
                    for p in (truth_obstacle, truth_floor, truth_person)),
                  replay.person_in_view(sf.frame), replay.person_disc(sf))


def play_runs(runs: list[replay.Run], config: nav2.CostmapConfig, values: dict[str, Any],
              periods: dict[str, int], pool: ProcessPoolExecutor) -> list[replay.SequenceFigures]:
    """Play the runs that share their frames: one STVL costmap per run and update period.

    The frames are rendered and put through the node by the pool's workers, in order.
    """
    first = runs[0]
    sequence = SceneSequence(first.sequence, odometry=PERFECT_ODOMETRY,
                             body_pitch=first.body_pitch)
    poses = [sequence.pose_true(i) for i in range(len(sequence))]
    replays = []
    for run in runs:
        urdf = values if run.urdf_error is None else replay.urdf_off(values, run.urdf_error)
        replays += [(period, STVLReplay(run.name, config, replay.camera_mount(urdf), poses,
                                        f'STVL {label}')) for label, period in periods.items()]
    lattice = replays[0][1]
    origin = (lattice.lattice_cell[0] * lattice.res, lattice.lattice_cell[1] * lattice.res)
    n = len(sequence)
    frames = pool.map(play_frame, [first.sequence] * n, [first.body_pitch] * n, range(n),
                      [origin] * n, [lattice.res] * n, chunksize=8)
    obstacles = np.zeros((0, 3))
    for p in frames:
        # a frame with no valid pixel (the 0.5 m blind zone) publishes nothing: the buffers
        # keep the newest cloud they have
        if p.obstacles is not None:
            obstacles = p.obstacles
        elif not p.reason.startswith('no valid depth pixel'):
            raise AssertionError(f'{first.sequence} frame {p.index}: {p.reason}')
        update = replay.UpdateInput(
            index=p.index, pose=p.pose, obstacle_points=obstacles,
            clearing_points=np.zeros((0, 3), np.float32), truth_obstacle=p.truth_obstacle,
            truth_free=p.truth_free, person_in_view=p.person_in_view,
            truth_person=p.truth_person, person_disc=p.person_disc)
        for period, r in replays:
            if p.obstacles is not None:
                r.receive(update)
            if p.index % period == 0:
                r.step(update)
            else:
                r.see(update)      # the truth between updates, for the seen-free history
    return [r.report() for _, r in replays]


#: nav2_bringup's local costmap update_frequency, the rate issue 29 names.
BRINGUP_RATE_HZ = 5.0


def update_periods(config: nav2.CostmapConfig) -> dict[str, int]:
    """Update periods [frames]: every frame, the file's update_frequency and nav2_bringup's."""
    rates = (replay.RATE_HZ, config.update_frequency_hz, BRINGUP_RATE_HZ)
    return {f'{hz:g} Hz': round(replay.RATE_HZ / hz) for hz in sorted(set(rates), reverse=True)}


@pytest.fixture(scope='module')
def figures() -> dict[tuple[str, str], replay.SequenceFigures]:
    config = stvl.read_stvl_costmap(STVL_YAML)
    values = bag_processor.node_param_values(CORRIDOR)
    groups: dict[tuple, list[replay.Run]] = {}
    for run in RUNS:        # runs that share their frames are played together
        groups.setdefault(run.frames_key, []).append(run)
    start = time.perf_counter()
    with ProcessPoolExecutor(max_workers=2, mp_context=multiprocessing.get_context('spawn')) \
            as pool:
        reports = [f for runs in groups.values()
                   for f in play_runs(runs, config, values, update_periods(config), pool)]
    print(f'\n{replay.format_table(reports)}\n({time.perf_counter() - start:.0f} s)')
    return {(f.name, f.layer): f for f in reports}


RATES = list(update_periods(stvl.read_stvl_costmap(STVL_YAML)))
#: Measured misses, expected to fail (strict: a pass is reported too).
#: At 5 Hz, from STVL's order (updateBounds: ClearFrustums builds the column counts, Mark comes
#: after, UpdateROSCostmap reads the counts): a mark reaches the costmap one update later
#: (upstream issue #284), 0.2 s at 5 Hz. New cells appear late while driving past the boxes
#: (F1 0.963; 0.981 with the marks shown in their own update, docs/stvl.md).
LATE_AT_5_HZ = pytest.mark.xfail(strict=True, reason='STVL marks after it fills the costmap: '
                                 'one update late (spatio_temporal_voxel_layer issue #284)')
KNOWN_MISSES = {('f1', 'drive_past_boxes', '5 Hz'): LATE_AT_5_HZ}


def cases(figure: str, names: list[str] | None = None) -> list[Any]:
    """(run, rate) pairs (of ``names``, else every run); KNOWN_MISSES expected to fail."""
    return [pytest.param(name, rate, marks=[KNOWN_MISSES[(figure, name, rate)]]
                         if (figure, name, rate) in KNOWN_MISSES else [])
            for name in names or [run.name for run in RUNS] for rate in RATES]


CASES = cases('')


@pytest.mark.parametrize(('name', 'rate'), CASES)
def test_no_ghost_10_frames_after_the_person_left(figures: dict, name: str, rate: str) -> None:
    got = figures[(name, f'STVL {rate}')]
    if got.leave_frame is None:
        pytest.skip(f'{name} has no person that leaves the view')

    assert got.ghost_after_10 == 0
    assert got.frames_to_clear <= replay.CLEAR_BUDGET_FRAMES


@pytest.mark.parametrize(('name', 'rate'), cases('f1', DRIVES))
def test_costmap_f1_with_one_cell_tolerance_while_driving(figures: dict, name: str,
                                                           rate: str) -> None:
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
