"""``bag_process`` over many bags: one task per bag (or chunk), a summary table and a JSON line."""

from __future__ import annotations

import contextlib
import dataclasses
import glob
import io
import json
import math
import shutil
import uuid
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from obstacle_detection.cli import support as tool_support
from obstacle_detection.cli.bag_processor import (DEFAULT_NAMESPACE, FrameReport,
                                                  config_from_values, copy_connections,
                                                  process_bag)
from obstacle_detection.cli.bag_writer import (BAG_VERSION, DEFAULT_DEPTH_TOPIC, STORAGES,
                                               staged_output)
from .cluster import Fleet, TaskError, limit_threads, run_tasks

#: Suffixes of a list file of bags (anything else that is a file is refused).
LIST_SUFFIXES = ('.txt', '.list')
_GLOB_CHARS = frozenset('*?[')


def is_bag(path: Path) -> bool:
    """Tell whether ``path`` is a rosbag2 folder (it holds ``metadata.yaml``)."""
    return (path / 'metadata.yaml').is_file()


def is_many(spec: str | Path) -> bool:
    """Tell whether ``spec`` names several bags (a folder of bags, a glob, a list file)."""
    text = str(spec)
    if _GLOB_CHARS & set(text):
        return True
    path = Path(text)
    if path.is_file():
        return path.suffix in LIST_SUFFIXES
    return path.is_dir() and not is_bag(path) and any(path.rglob('metadata.yaml'))


def find_bags(spec: str | Path) -> list[tuple[Path, Path]]:
    """Return ``(bag, output name)`` of every bag ``spec`` names, in a stable order.

    Raises tool_support.ToolError naming the spec or the entry that is not a bag.
    """
    text = str(spec)
    path = Path(text)
    if path.is_dir() and not (_GLOB_CHARS & set(text)):
        bags = sorted(p.parent for p in path.rglob('metadata.yaml'))
        if not bags:
            raise tool_support.ToolError(path, 'no bag in the folder (no metadata.yaml below '
                                               'it)')
        # a bag inside another bag's folder is not a bag of its own
        bags = [b for b in bags if not any(o in b.parents for o in bags)]
        return [(bag, bag.relative_to(path)) for bag in bags]
    if _GLOB_CHARS & set(text):
        matches = [Path(m) for m in sorted(glob.glob(text))]
        if not matches:
            raise tool_support.ToolError(text, 'the pattern matches nothing')
        entries = matches
    elif path.is_file() and path.suffix in LIST_SUFFIXES:
        try:
            lines = path.read_text(encoding='utf-8').splitlines()
        except (OSError, UnicodeDecodeError) as err:
            raise tool_support.ToolError(path, f'cannot read the list ({err})') from err
        entries = [path.parent / line.strip() for line in lines
                   if line.strip() and not line.lstrip().startswith('#')]
        if not entries:
            raise tool_support.ToolError(path, 'the list names no bag')
    else:
        raise tool_support.ToolError(path, 'not a folder of bags, a glob pattern or a list '
                                           f'file ({", ".join(LIST_SUFFIXES)})')
    for entry in entries:
        tool_support.check_bag_path(entry, ros1=False)
    names = [Path(entry.name) for entry in entries]
    clash = sorted({str(n) for n in names if names.count(n) > 1})
    if clash:
        raise tool_support.ToolError(text, f'several bags are named {", ".join(clash)}; their '
                                           'outputs would collide (give a folder of bags)')
    return list(zip(entries, names))


@dataclasses.dataclass(frozen=True)
class BagJob:
    """One bag to process: where from, where to, and the node's parameters (picklable)."""

    bag: Path
    output: Path
    values: Mapping[str, Any]
    origin: str
    mount_origin: str
    depth_topic: str = DEFAULT_DEPTH_TOPIC
    info_topic: str | None = None
    namespace: str = DEFAULT_NAMESPACE
    with_ground: bool = False
    with_overlay: bool = False
    storage: str = 'sqlite3'
    chunk_frames: int | None = None


@dataclasses.dataclass
class BagOutcome:
    """What one bag's task did; ``error`` set when it failed (nothing written then)."""

    bag: Path
    output: Path
    frames: int = 0
    processed: int = 0
    skipped: dict[str, int] = dataclasses.field(default_factory=dict)
    obstacle_points: int = 0
    pipeline_ms: float = 0.0      # sum of the processed frames' pipeline times
    wall_s: float = 0.0
    warning: str | None = None
    error: str | None = None

    @property
    def ms_per_frame(self) -> float:
        """Mean pipeline time of the processed frames [ms] (NaN: none)."""
        return self.pipeline_ms / self.processed if self.processed else math.nan

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready (NaN becomes None)."""
        ms = self.ms_per_frame
        return {'bag': str(self.bag), 'output': str(self.output), 'frames': self.frames,
                'processed': self.processed, 'skipped': dict(self.skipped),
                'obstacle_points': self.obstacle_points,
                'ms_per_frame': None if math.isnan(ms) else round(ms, 2),
                'wall_s': round(self.wall_s, 3), 'warning': self.warning, 'error': self.error}


def process_one(job: BagJob, window: tuple[int | None, int | None] = (None, None),
                output: Path | None = None) -> BagOutcome:
    """Process one bag, or the chunk ``window`` of it into ``output`` (a task). Never raises."""
    limit_threads()
    output = job.output if output is None else output
    outcome = BagOutcome(job.bag, output)
    totals = {'points': 0}

    def count(report: FrameReport) -> None:
        totals['points'] += report.obstacle_points

    try:
        config = config_from_values(job.values, job.origin)
        with contextlib.redirect_stderr(io.StringIO()):
            summary = process_bag(
                job.bag, output, config, depth_topic=job.depth_topic,
                info_topic=job.info_topic, namespace=job.namespace,
                with_ground=job.with_ground or config.publish_ground,
                with_overlay=job.with_overlay or config.publish_overlay, storage=job.storage,
                progress=False, on_frame=count, mount_origin=job.mount_origin,
                start_ns=window[0], stop_ns=window[1])
    except Exception as err:   # noqa: BLE001 - a bag's failure is its task's result
        outcome.error = _reason(err, job.bag, output)
        return outcome
    outcome.frames = summary.frames
    outcome.processed = summary.processed
    outcome.skipped = dict(summary.skipped)
    outcome.obstacle_points = totals['points']
    outcome.pipeline_ms = float(sum(summary.total_ms))
    outcome.wall_s = summary.wall_s
    outcome.warning = summary.mount_warning
    return outcome


def _reason(err: BaseException, *paths: Path) -> str:
    """Return the error line of a failed bag: the message, naming the bag if it does not."""
    text = str(err)
    if text and text.startswith(tuple(str(p) for p in paths)):
        return text
    return f'{paths[0]}: {type(err).__name__}' + (f': {text}' if text else '')


def plan_chunks(job: BagJob) -> list[tuple[int, int]]:
    """Return the [start, stop) bag-time windows [ns] of ``job``'s chunks; [] for one task."""
    from rosbags.rosbag2 import Reader

    if not job.chunk_frames:
        return []
    try:
        with Reader(job.bag) as reader:
            frames = sum(c.msgcount for c in reader.connections if c.topic == job.depth_topic)
            start, stop = reader.start_time, reader.end_time
    except Exception:   # noqa: BLE001 - the bag's own task reports it
        return []
    count = math.ceil(frames / job.chunk_frames)
    if count < 2:
        return []
    edges = [start + (stop - start) * k // count for k in range(count + 1)]
    return list(zip(edges[:-1], edges[1:]))


def chunks_path(output: Path) -> Path:
    """Return the folder of an output bag's chunk bags while they are made and merged."""
    return output.parent / f'.{output.name}.chunks'


def process_chunk(job: BagJob, index: int, window: tuple[int, int], run: str) -> BagOutcome:
    """Process chunk ``index`` of a bag into its part bag (a task). Never raises."""
    return process_one(job, window, chunks_path(job.output) / run / f'part{index:04d}')


def finish_bag(job: BagJob, *parts: BagOutcome) -> BagOutcome:
    """Return the bag's outcome: process it (no parts) or merge its chunks' parts (a task)."""
    if not parts:
        return process_one(job)
    from rosbags.rosbag2 import Reader, Writer
    from rosbags.typesys import Stores, get_typestore

    outcome = BagOutcome(job.bag, job.output)
    try:
        failed = next((p for p in parts if p.error is not None), None)
        if failed is not None:
            outcome.error = failed.error
            return outcome
        typestore = get_typestore(Stores.ROS2_JAZZY)
        with staged_output(job.output) as staging, \
                Writer(staging, version=BAG_VERSION, storage_plugin=STORAGES[job.storage]) \
                as writer:
            connections: dict[tuple[str, str], Any] = {}
            for part in parts:
                with Reader(part.output) as reader:
                    ids = {}
                    for conn in reader.connections:
                        key = (conn.topic, conn.msgtype)
                        if key not in connections:
                            connections[key] = copy_connections([conn], writer,
                                                                typestore)[conn.id]
                        ids[conn.id] = connections[key]
                    for conn, timestamp, raw in reader.messages():
                        writer.write(ids[conn.id], timestamp, raw)
    except Exception as err:   # noqa: BLE001 - a bag's failure is its task's result
        outcome.error = _reason(err, job.bag, job.output)
        return outcome
    finally:
        for part in parts:
            shutil.rmtree(part.output, ignore_errors=True)
    for part in parts:
        outcome.frames += part.frames
        outcome.processed += part.processed
        for reason, count in part.skipped.items():
            outcome.skipped[reason] = outcome.skipped.get(reason, 0) + count
        outcome.obstacle_points += part.obstacle_points
        outcome.pipeline_ms += part.pipeline_ms
        outcome.wall_s += part.wall_s
        outcome.warning = outcome.warning or part.warning
    return outcome


def staging_path(output: Path) -> Path:
    """Return the temporary folder an output bag is written in (``bag_writer.staged_output``)."""
    return output.parent / f'.{output.name}.partial'


def process_bags(jobs: Sequence[BagJob], fleet: Fleet, *, progress: bool = True
                 ) -> list[BagOutcome]:
    """Run every job where ``fleet`` says; outcomes in ``jobs`` order.

    On KeyboardInterrupt the tasks are cancelled and it propagates (then
    :func:`remove_stale_staging`).
    """
    items: list[tuple[Any, ...]] = [(job,) for job in jobs]
    if fleet.distributed:
        run = uuid.uuid4().hex[:8]
        items = [(job, *(fleet.client.submit(process_chunk, job, k, window, run,
                                             key=f'process_chunk-{run}-{i}-{k}',
                                             retries=fleet.retries, pure=False)
                         for k, window in enumerate(plan_chunks(job))))
                 for i, job in enumerate(jobs)]
    results = run_tasks(fleet, finish_bag, items, label='bags', progress=progress,
                        errors='return')
    for job in jobs:
        shutil.rmtree(chunks_path(job.output), ignore_errors=True)
    return [BagOutcome(job.bag, job.output, error=f'{job.bag}: {result.reason}')
            if isinstance(result, TaskError) else result
            for job, result in zip(jobs, results)]


def remove_stale_staging(jobs: Sequence[BagJob]) -> None:
    """Remove the temporary folders a stopped run left (after its cluster is closed)."""
    for job in jobs:
        shutil.rmtree(staging_path(job.output), ignore_errors=True)
        shutil.rmtree(chunks_path(job.output), ignore_errors=True)


def format_table(outcomes: Sequence[BagOutcome]) -> str:
    """Return the per-bag table, then skip reasons, warnings and failures per bag."""
    names = [str(o.bag) for o in outcomes]
    width = max([len('bag'), len('total')] + [len(n) for n in names]) + 1
    head = (f'{"bag":<{width}} {"frames":>7} {"processed":>9} {"skipped":>7} '
            f'{"obstacle pts":>12} {"ms/frame":>8} {"s":>7}  status')
    lines = [head, '-' * len(head)]
    notes: list[str] = []
    for name, outcome in zip(names, outcomes):
        if outcome.error is not None:
            lines.append(f'{name:<{width}} {"-":>7} {"-":>9} {"-":>7} {"-":>12} {"-":>8} '
                         f'{"-":>7}  FAILED')
            notes.append(f'  {name}: failed: {outcome.error}')
            continue
        ms = outcome.ms_per_frame
        lines.append(f'{name:<{width}} {outcome.frames:>7} {outcome.processed:>9} '
                     f'{sum(outcome.skipped.values()):>7} {outcome.obstacle_points:>12} '
                     f'{"-" if math.isnan(ms) else f"{ms:.1f}":>8} {outcome.wall_s:>7.1f}  ok')
        notes.extend(f'  {name}: skipped {count}: {reason}'
                     for reason, count in outcome.skipped.items())
        if outcome.warning:
            notes.append(f'  {name}: warning: {outcome.warning}')
    done = [o for o in outcomes if o.error is None]
    processed = sum(o.processed for o in done)
    ms_total = sum(o.pipeline_ms for o in done)
    lines.append('-' * len(head))
    lines.append(f'{"total":<{width}} {sum(o.frames for o in done):>7} {processed:>9} '
                 f'{sum(sum(o.skipped.values()) for o in done):>7} '
                 f'{sum(o.obstacle_points for o in done):>12} '
                 f'{(f"{ms_total / processed:.1f}" if processed else "-"):>8} '
                 f'{sum(o.wall_s for o in done):>7.1f}  '
                 f'{len(done)} ok, {len(outcomes) - len(done)} failed')
    return '\n'.join(lines + notes)


def summary_json(outcomes: Sequence[BagOutcome], *, wall_s: float, where: str) -> str:
    """Return the one JSON line of a many-bag run: per bag, totals, the run's wall time."""
    done = [o for o in outcomes if o.error is None]
    processed = sum(o.processed for o in done)
    return json.dumps({
        'bags': [o.as_dict() for o in outcomes], 'ok': len(done),
        'failed': len(outcomes) - len(done), 'frames': sum(o.frames for o in done),
        'processed': processed, 'wall_s': round(wall_s, 3),
        'frames_per_s': round(processed / wall_s, 2) if wall_s > 0 else None,
        'where': where}, sort_keys=True)
