"""The node's health on ``/diagnostics``: counters per period and the level they mean.

Named and identified as diagnostic_updater (ros/diagnostics, ros2-jazzy,
diagnostic_updater/_diagnostic_updater.py) publishes a task: ``Updater.publish`` names each
status ``<node name>: <task>``, the node's name (``Node.get_name()``), or its fully qualified name
when the node's parameter ``diagnostic_updater.use_fqn`` is true (``Updater.__init__``, as the
C++ updater); ``hardware_id`` is one string set once (``Updater.setHardwareID``), here the
resolved depth topic.
"""

from __future__ import annotations

import threading
import time
from collections import Counter
from dataclasses import dataclass, field

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

NO_FRAME_ERROR_S = 2.0
SKIPPED_ERROR_SHARE = 0.5
DROPPED_WARN_SHARE = 0.2
#: The node's compute_path() when the compiled kernels run.
COMPILED = 'compiled numba kernels'
#: What the status is about, after the node's name (diagnostic_updater's "node: task" form).
STATUS_TASK = 'depth obstacle detection'
#: diagnostic_updater's own parameter (``Updater.__init__`` declares it, default false): true
#: names the status after the node's fully qualified name, so that detectors in two namespaces
#: report under two names.
USE_FQN_PARAMETER = 'diagnostic_updater.use_fqn'

OK, WARN, ERROR = DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR


@dataclass
class Period:
    """What happened between two reports."""

    seconds: float = 0.0
    received: int = 0
    processed: int = 0
    dropped: int = 0
    errors: int = 0
    skipped: Counter = field(default_factory=Counter)
    sum_ms: float = 0.0
    max_ms: float = 0.0        #: the slowest frame of the period
    fallback: int = 0          #: frames processed with the fallback intrinsics
    since_last_frame_s: float | None = None   #: None: no frame since the node started


class HealthWindow:
    """Thread-safe frame counters: one period per reader (the diagnostics, the log)."""

    def __init__(self, now: float | None = None, readers: tuple[str, ...] = ('diagnostics',)
                 ) -> None:
        self._lock = threading.Lock()
        self._start = dict.fromkeys(readers, time.monotonic() if now is None else now)
        self._periods = {reader: Period() for reader in readers}
        self._last_frame: float | None = None

    def count(self, name: str, count: int = 1, now: float | None = None) -> None:
        """Count frames ``received``, ``dropped`` or lost to ``errors``."""
        with self._lock:
            for period in self._periods.values():
                setattr(period, name, getattr(period, name) + count)
            if name == 'received':
                self._last_frame = time.monotonic() if now is None else now

    def processed(self, elapsed_ms: float, fallback: bool = False) -> None:
        """Count one frame processed and published in ``elapsed_ms``; ``fallback`` intrinsics."""
        with self._lock:
            for period in self._periods.values():
                period.processed += 1
                period.sum_ms += elapsed_ms
                period.max_ms = max(period.max_ms, elapsed_ms)
                period.fallback += bool(fallback)

    def skipped(self, reason: str) -> None:
        """Count one frame skipped for bad input, by reason (a short key)."""
        with self._lock:
            for period in self._periods.values():
                period.skipped[reason] += 1

    def take(self, now: float | None = None, reader: str = 'diagnostics') -> Period:
        """Return the reader's period since its last call and start a new one."""
        now = time.monotonic() if now is None else now
        with self._lock:
            period, self._periods[reader] = self._periods[reader], Period()
            period.seconds = max(now - self._start[reader], 1e-9)
            self._start[reader] = now
            if self._last_frame is not None:
                period.since_last_frame_s = now - self._last_frame
        return period


@dataclass(frozen=True)
class Context:
    """What the node knows besides the counters."""

    uptime_s: float
    depth_topic: str
    code_path: str             #: the node's compute_path()
    mount: str                 #: where the camera mount comes from, and its values
    camera_info_topic: str = 'depth/camera_info'
    fallback_intrinsics: str = ''   #: the fallback_fx/fy/cx/cy values, 'fx=.. fy=.. ...'
    #: the mount against the floor in view (ros.mount_check): key/values, and a warning or ''
    mount_check: dict[str, str] = field(default_factory=dict)
    mount_warning: str = ''


def intrinsics_text(period: Period, ctx: Context) -> str:
    """Say which intrinsics the period's frames used: CameraInfo, or the fallback values."""
    if not period.processed:
        return '-'
    fallback = (f'fallback {ctx.fallback_intrinsics} (no CameraInfo on '
                f'{ctx.camera_info_topic})')
    if period.fallback == period.processed:
        return fallback
    camera_info = f'CameraInfo on {ctx.camera_info_topic}'
    if period.fallback:
        return f'{camera_info}; {period.fallback} frame(s): {fallback}'
    return camera_info


def _level_and_message(period: Period, ctx: Context) -> tuple[int, str]:
    frames = period.received
    skipped = sum(period.skipped.values())
    reasons = ', '.join(f'{k} {v}' for k, v in period.skipped.most_common())
    skipped_text = f'{skipped} of {frames} frames skipped for bad input ({reasons})'
    if period.since_last_frame_s is None:
        if ctx.uptime_s >= NO_FRAME_ERROR_S:
            return ERROR, f'no depth frame received on {ctx.depth_topic} yet'
    elif period.since_last_frame_s >= NO_FRAME_ERROR_S:
        return ERROR, (f'no depth frame for {period.since_last_frame_s:.1f} s on '
                       f'{ctx.depth_topic}')
    if frames and skipped > SKIPPED_ERROR_SHARE * frames:
        return ERROR, skipped_text
    if period.errors:
        return ERROR, f'the pipeline failed on {period.errors} frame(s) (see the log)'
    if skipped:
        return WARN, skipped_text
    if ctx.mount_warning:
        return WARN, ctx.mount_warning
    if period.fallback:
        return WARN, (f'{period.fallback} of {period.processed} frames used the fallback '
                      f'intrinsics {ctx.fallback_intrinsics}: no CameraInfo on '
                      f'{ctx.camera_info_topic}')
    if frames and period.dropped > DROPPED_WARN_SHARE * frames:
        return WARN, (f'{period.dropped} of {frames} frames replaced before processing: the '
                      'node does not keep up with the camera')
    if ctx.code_path != COMPILED:
        return WARN, ctx.code_path
    return OK, f'{period.processed / period.seconds:.1f} frames/s processed'


def status_name(node_name: str) -> str:
    """Return the status name: ``node_name`` (name, or fully qualified with use_fqn), task."""
    return f'{node_name}: {STATUS_TASK}'


def health_status(period: Period, ctx: Context, *, name: str,
                  hardware_id: str) -> DiagnosticStatus:
    """Return the DiagnosticStatus of one period: level, one-line message, key/values."""
    level, message = _level_and_message(period, ctx)
    values = {
        'input rate [Hz]': f'{period.received / period.seconds:.1f}',
        'processed rate [Hz]': f'{period.processed / period.seconds:.1f}',
        'processing mean [ms]': (f'{period.sum_ms / period.processed:.1f}'
                                 if period.processed else '-'),
        'processing max [ms]': f'{period.max_ms:.1f}' if period.processed else '-',
        'intrinsics': intrinsics_text(period, ctx),
        'dropped (newer frame came first)': str(period.dropped),
        'skipped (bad input)': str(sum(period.skipped.values())),
        'errors': str(period.errors),
        'mount': ctx.mount,
        **ctx.mount_check,
        'code path': ctx.code_path,
    }
    return DiagnosticStatus(level=level, name=name, message=message,
                            hardware_id=hardware_id,
                            values=[KeyValue(key=k, value=v) for k, v in values.items()])

