"""``evaluate`` and ``sweep`` on a cluster: one task per (parameter point, sequence)."""

from __future__ import annotations

import functools
import time
from collections.abc import Iterable, Sequence
from typing import Any

from obstacle_detection.evaluation import runner as evaluation
from obstacle_detection.pipeline.detector import Detector
from obstacle_detection.pipeline.params import DetectorParams
from .cluster import Fleet, limit_threads, run_tasks

#: (name, frame count, lazy frames), as ``evaluation_args.frame_sources`` gives them.
Source = tuple[str, int, Iterable[evaluation.LabelledFrame]]


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

