"""``evaluate`` and ``sweep`` on a cluster: one task per (parameter point, sequence)."""

from __future__ import annotations

import functools
import time

import numpy as np
from collections.abc import Callable, Iterable, Sequence
from typing import Any

from obstacle_detection.evaluation import runner as evaluation
from obstacle_detection.pipeline.detector import Detector
from obstacle_detection.pipeline.params import DetectorParams, Intrinsics
from .cluster import Fleet, limit_threads, run_tasks

#: (name, frame count, lazy frames), as ``evaluation_args.frame_sources`` gives them.
Source = tuple[str, int, Iterable[evaluation.LabelledFrame]]
#: One process's seconds to render a labelled frame and to score one (one thread, Kinect v2
#: SD), measured on the 2-core machine: docs/fleet.md, One process or a cluster.
RENDER_FRAME_S = 0.04
SCORE_FRAME_S = 0.025
#: ... a frame of a scene sequence (render, detect, fuse) and a real frame (fit the mount,
#: detect; VGA).
SEQUENCE_FRAME_S = 0.1
REAL_FRAME_S = 0.5
#: Real frames: floor pixels lie within FLOOR_BAND_M of the fitted floor; standing pixels
#: STANDING_M above it up to the robot height.
FLOOR_BAND_M = 0.02
STANDING_M = 0.05


def work_seconds(sources: Sequence[Source], points: int = 1) -> float:
    """Estimate one process's seconds to score ``points`` parameter points on ``sources``."""
    frames = sum(count for _, count, _ in sources)
    return frames * (RENDER_FRAME_S + points * SCORE_FRAME_S)


def load_frames(frames: Iterable[evaluation.LabelledFrame]) -> list[evaluation.LabelledFrame]:
    """Render or read one sequence's frames (a task)."""
    limit_threads()
    return list(frames)


def score_sequence(frames: Sequence[evaluation.LabelledFrame], params: DetectorParams,
                   refiner: Any = None) -> list[evaluation.FrameScore]:
    """Per-frame scores of one sequence with one parameter point (a task)."""
    limit_threads()
    params = params.replace(compute_threads=1)
    _warm_up(params)
    return evaluation.evaluate_frames(frames, params, refiner=refiner).frames


@functools.lru_cache(maxsize=64)
def _warm_up(params: DetectorParams) -> None:
    """Compile first, once per process and point: the frames' times are the pipeline's alone."""
    Detector(params).warm_up()


def score_points(fleet: Fleet, sources: Sequence[Source], points: Sequence[DetectorParams],
                 *, refiner: Any = None, label: str = 'scoring', progress: bool = True
                 ) -> list[list[evaluation.FrameScore]]:
    """Per point, the frame scores of every source in source order (one task per pair)."""
    if fleet.distributed:   # each source's frames rendered once, by a task of their own
        frames = [fleet.submit(load_frames, lazy) for _, _, lazy in sources]
    else:
        frames = [load_frames(lazy) for _, _, lazy in sources]
    items = [(frames[s], params, refiner) for params in points for s in range(len(sources))]
    flat = run_tasks(fleet, score_sequence, items, label=label, progress=progress)
    count = len(sources)
    return [[score for part in flat[p * count:(p + 1) * count] for score in part]
            for p in range(len(points))]


def evaluate_on_fleet(fleet: Fleet, sources: Sequence[Source], params: DetectorParams, *,
                      label: str = '', refiner: Any = None, refiner_name: str | None = None,
                      progress: bool = True) -> evaluation.Report:
    """``runner.evaluate_frames`` over every source's frames, one task per source."""
    started = time.perf_counter()
    [scores] = score_points(fleet, sources, [params], refiner=refiner, label='evaluate',
                            progress=progress)
    return evaluation.pool_scores(scores, params, label=label, refiner_name=refiner_name,
                                  seconds=time.perf_counter() - started)



def score_video_sequence(name: str, seed: int, exact_odometry: bool, params: DetectorParams,
                         fusion: Any, stop: int | None, sheet_frames: int,
                         on_frame: Callable[[int, int], None] | None = None) -> Any:
    """Score the fused costmap over one scene sequence (a task): ``video.SequenceReport``."""
    from obstacle_detection.evaluation import video
    from obstacle_detection.sim.sequences import PERFECT_ODOMETRY, OdometryModel, SceneSequence

    limit_threads()
    sequence = SceneSequence(name, seed=seed, odometry=PERFECT_ODOMETRY if exact_odometry
                             else OdometryModel())
    return video.evaluate_sequence(sequence, params, fusion, stop=stop,
                                   sheet_frames=sheet_frames, on_frame=on_frame)


def real_frame_counts(depth_m: np.ndarray, intrinsics: Intrinsics, params: DetectorParams,
                      ) -> tuple[int, int, int, int, str]:
    """Return (floor, floor marked, standing, standing marked, mount text) of one frame.

    The mount is fitted to the floor; only pixels inside the region of interest count.
    """
    from obstacle_detection.labels import LABEL_OBSTACLE
    from obstacle_detection.pipeline import geometry
    from obstacle_detection.pipeline.detector import Detector
    from obstacle_detection.pipeline.mount import estimate_mount

    limit_threads()
    est = estimate_mount(depth_m, intrinsics)
    p = params.replace(camera_height_m=est.height_m, camera_pitch_rad=est.pitch_rad,
                       camera_roll_rad=est.roll_rad)
    result = Detector(p).process(depth_m, intrinsics)
    rays = geometry.ground_rays(depth_m.shape, intrinsics, p)
    d = depth_m.reshape(-1)
    x, y = d * rays[0], d * rays[1]
    z = d * rays[2] + np.float32(p.camera_height_m)
    inside = (d > 0) & (x >= p.min_range_m) & (x <= p.max_range_m) & (
        np.abs(y) <= p.lateral_limit_m)
    marked = result.labels.reshape(-1) == LABEL_OBSTACLE
    on_floor = inside & (np.abs(z) <= FLOOR_BAND_M)
    standing = inside & (z >= STANDING_M) & (z <= p.robot_height_m)
    mount = (f'h {est.height_m:.2f} m, pitch {est.pitch_deg:.1f} deg, '
             f'roll {est.roll_deg:.1f} deg; {result.floor.summary()}')
    return (int(on_floor.sum()), int((on_floor & marked).sum()), int(standing.sum()),
            int((standing & marked).sum()), mount)

