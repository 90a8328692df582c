"""``bag_process`` over many bags: one task per bag, and a summary table."""

from __future__ import annotations

import contextlib
import dataclasses
import glob
import io
import math
import shutil
import uuid
from collections import Counter
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from rclpy.serialization import deserialize_message
from rosbags.rosbag2 import Reader
from sensor_msgs.msg import Image

from obstacle_detection.cli import support as tool_support
from obstacle_detection.cli.bag_processor import (DEFAULT_NAMESPACE, config_from_values,
                                                  process_bag)
from obstacle_detection.cli.bag_writer import DEFAULT_DEPTH_TOPIC
from . import probe
from .cluster import Fleet, TaskError, limit_threads, run_tasks

_GLOB_CHARS = frozenset('*?[')


def is_many(spec: str | Path) -> bool:
    """Tell whether ``spec`` names several bags (a folder of bags or a glob)."""
    path = Path(spec)
    return bool(_GLOB_CHARS & set(str(spec))) or (
        path.is_dir() and not (path / 'metadata.yaml').is_file()
        and any(path.rglob('metadata.yaml')))


def find_bags(spec: str | Path) -> list[tuple[Path, Path]]:
    """Return ``(bag, output name)`` of every bag ``spec`` (see is_many) names, in order.

    Raises tool_support.ToolError naming the spec or the entry that is not a bag.
    """
    text = str(spec)
    path = Path(text)
    if path.is_dir() and not (_GLOB_CHARS & set(text)):
        bags = sorted(p.parent for p in path.rglob('metadata.yaml'))
        # a bag inside another bag's folder is not a bag of its own
        bags = [b for b in bags if not any(o in b.parents for o in bags)]
        return [(bag, bag.relative_to(path)) for bag in bags]
    entries = [Path(m) for m in sorted(glob.glob(text))]
    if not entries:
        raise tool_support.ToolError(text, 'the pattern matches nothing')
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
    where: str = 'this process'   # the worker that ran it
    info_topic: str | None = None   # the CameraInfo topic it used (None: none recorded)
    info_how: str = ''              # how that topic was chosen


def process_one(job: BagJob) -> BagOutcome:
    """Process one bag (a task)."""
    limit_threads()
    try:
        from distributed import get_worker

        where = get_worker().address
    except (ImportError, ValueError):   # not on a Dask worker
        where = 'this process'
    config = config_from_values(job.values, job.origin)
    with contextlib.redirect_stderr(io.StringIO()):
        summary = process_bag(
            job.bag, job.output, config, depth_topic=job.depth_topic, info_topic=job.info_topic,
            namespace=job.namespace, with_ground=job.with_ground or config.publish_ground,
            with_overlay=job.with_overlay or config.publish_overlay, storage=job.storage,
            progress=False, mount_origin=job.mount_origin)
    return BagOutcome(job.bag, job.output, summary.frames, summary.processed,
                      dict(summary.skipped), summary.obstacle_points, float(sum(summary.total_ms)),
                      summary.wall_s, summary.mount_warning, where=where,
                      info_topic=summary.info_topic, info_how=summary.info_how)


def process_bags(jobs: Sequence[BagJob], fleet: Fleet, *, progress: bool = True
                 ) -> list[BagOutcome]:
    """Run every job where ``fleet`` says; outcomes in ``jobs`` order (a failed one's error set).

    The paths of ``jobs`` must be absolute: a worker resolves a relative one in its own folder.
    An output a worker reports written but this process does not see is a failure (the
    workers do not share this filesystem). Ctrl-C cancels the tasks and propagates (then call
    :func:`remove_stale_staging`).
    """
    if relative := [str(p) for job in jobs for p in (job.bag, job.output) if not p.is_absolute()]:
        raise ValueError(f'process_bags needs absolute paths, not {", ".join(relative)}')
    if fleet.distributed:
        check_shared_files(fleet, jobs)
    results = run_tasks(fleet, process_one, [(job,) for job in jobs], label='bags',
                        progress=progress, return_errors=True)
    outcomes = [BagOutcome(job.bag, job.output, error=str(result.error))   # the table names it
                if isinstance(result, TaskError) else result
                for job, result in zip(jobs, results)]
    for outcome in outcomes:
        if outcome.error is None and not (outcome.output / 'metadata.yaml').is_file():
            outcome.error = (f'{outcome.where} wrote {outcome.output}, but this machine does '
                             'not see it there: the workers must write to a filesystem this '
                             'machine shares, at the same paths')
    return outcomes


def check_shared_files(fleet: Fleet, jobs: Sequence[BagJob]) -> None:
    """Check that every worker sees the bags and the output folders at this machine's paths.

    Writes a marker file in each output folder (created if need be) and asks the workers
    whether they see it and the bags' metadata files; ToolError names the worker and the paths
    it does not see. The markers and the folders made for them are removed.
    """
    folders = sorted({job.output.parent for job in jobs})
    made = [folder for folder in folders if not folder.exists()]
    markers = [folder / f'.fleet-check-{uuid.uuid4().hex}' for folder in folders]
    try:
        for marker in markers:
            marker.parent.mkdir(parents=True, exist_ok=True)
            marker.write_bytes(b'')
        wanted = [str(m) for m in markers] + [str(job.bag / 'metadata.yaml') for job in jobs
                                              if (job.bag / 'metadata.yaml').is_file()]
        unseen = {address: missing for address, missing in
                  fleet.client.run(probe.missing_paths, wanted).items() if missing}
    finally:
        for marker in markers:
            marker.unlink(missing_ok=True)
        for folder in sorted(made, key=lambda f: len(f.parts), reverse=True):
            with contextlib.suppress(OSError):   # only if still empty
                folder.rmdir()
    if unseen:
        address, missing = sorted(unseen.items())[0]
        names = [str(Path(m).parent) if m.endswith('metadata.yaml') else
                 f'the output folder {Path(m).parent}' for m in missing]
        more = f' (and {len(unseen) - 1} other workers)' if len(unseen) > 1 else ''
        raise tool_support.ToolError(
            f'the worker {address}{more} does not see {", ".join(names[:3])}'
            f'{f" and {len(names) - 3} more" if len(names) > 3 else ""}: the workers must see '
            'the bags and the output folder at the same paths as this machine (a shared '
            'filesystem)')


#: One process's cost of a bag (opening the bags, the detector, the first frame's mount check)
#: and of a depth frame (decoding, messages, writing; plus the pipeline per pixel), one thread,
#: measured on the 2-core machine (docs/fleet.md, One process or a cluster).
BAG_S = 0.25
FRAME_S = 0.004
PIXEL_S = 1.1e-7
#: The pixels of a frame whose size is not read (a compressed one): Kinect v2 SD.
DEFAULT_PIXELS = 512 * 424


def work_seconds(jobs: Sequence[BagJob], enough: float = math.inf) -> float:
    """Estimate one process's seconds for ``jobs`` from the bags' frame counts and sizes.

    Stops reading bags once the estimate passes ``enough``; a bag it cannot read counts as
    one frame (its task will say why).
    """
    total, pixels = 0.0, None
    for job in jobs:
        frames = 1
        with contextlib.suppress(Exception):   # what is wrong with a bag is its task's to say
            with Reader(job.bag) as reader:
                depth = [c for c in reader.connections if c.topic == job.depth_topic]
                frames = sum(c.msgcount for c in depth)
                if pixels is None and depth and depth[0].msgtype == 'sensor_msgs/msg/Image':
                    for _, _, raw in reader.messages(connections=depth[:1]):
                        image = deserialize_message(bytes(raw), Image)
                        pixels = image.width * image.height
                        break
        total += BAG_S + frames * (FRAME_S + PIXEL_S * (pixels or DEFAULT_PIXELS))
        if total > enough:
            break
    return total


def remove_stale_staging(jobs: Sequence[BagJob]) -> None:
    """Remove the temporary folders a stopped run left (after its cluster is closed)."""
    for job in jobs:   # the name of bag_writer.staged_output
        shutil.rmtree(job.output.parent / f'.{job.output.name}.partial', ignore_errors=True)


def format_table(outcomes: Sequence[BagOutcome]) -> str:
    """Return the per-bag table, then skip reasons, warnings and failures per bag."""
    done = [o for o in outcomes if o.error is None]
    total = BagOutcome(
        Path('total'), Path(), sum(o.frames for o in done), sum(o.processed for o in done),
        dict(sum((Counter(o.skipped) for o in done), Counter())),
        sum(o.obstacle_points for o in done), sum(o.pipeline_ms for o in done),
        sum(o.wall_s for o in done))
    width = max(len(str(o.bag)) for o in [*outcomes, total]) + 1
    heads = ('frames', 'processed', 'skipped', 'obstacle pts', 'ms/frame', 's')

    def row(o: BagOutcome, status: str) -> str:
        ms = f'{o.pipeline_ms / o.processed:.1f}' if o.processed else '-'
        cells = (['-'] * 6 if o.error is not None else
                 [o.frames, o.processed, sum(o.skipped.values()), o.obstacle_points, ms,
                  f'{o.wall_s:.1f}'])
        return f'{str(o.bag):<{width}} ' + ' '.join(
            f'{c:>{max(len(h), 7)}}' for c, h in zip(cells, heads)) + f'  {status}'
    head = f'{"bag":<{width}} ' + ' '.join(f'{h:>7}' for h in heads) + '  status'
    lines = [head, '-' * len(head)]
    notes: list[str] = []
    for o in outcomes:
        lines.append(row(o, 'ok' if o.error is None else 'FAILED'))
        notes += [f'  {o.bag}: failed: {o.error}'] if o.error is not None else []
        notes += [f'  {o.bag}: skipped {count}: {reason}' for reason, count in o.skipped.items()]
        notes += [f'  {o.bag}: warning: {o.warning}'] if o.warning else []
    lines += ['-' * len(head), row(total, f'{len(done)} ok, {len(outcomes) - len(done)} failed')]
    return '\n'.join(lines + notes)
