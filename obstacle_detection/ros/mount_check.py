"""The camera mount (TF's or the parameters') against the floor the camera sees.

Each frame's floor fit says how far the floor puts the camera from its mount (pitch, roll,
height). A body that pitches while driving moves that back and forth around zero; a wrong URDF
or wrong mount parameters shift it for good. The mean over the last :data:`WINDOW_S` seconds
tells the two apart, and is reported on /diagnostics (docs/node.md, Diagnostics).
"""

from __future__ import annotations

import collections
import math
import threading
import time
from dataclasses import dataclass
from typing import Any

#: The disagreement is the mean over the frames of this many seconds: long enough for a body
#: pitching with the robot's motion to average out, short enough to show a wrong URDF at once.
WINDOW_S = 10.0
#: Fewest frames with a floor fit in the window for a verdict.
MIN_FRAMES = 10
#: A mean pitch or roll disagreement above this is a WARN [deg]: the floor fit corrects up to
#: 5 deg, so the costmaps stay right, but the URDF Nav2 uses is off.
ANGLE_WARN_DEG = 1.0
#: A mean height disagreement above this is a WARN [m].
HEIGHT_WARN_M = 0.02
#: The share of the window's frames whose floor lay beyond the fit's bounds that is a WARN.
BEYOND_WARN_SHARE = 0.5
#: How to measure the mount (named in the warning).
MEASURE = 'measure the mount with tools/estimate_mount.py (a depth frame of open floor)'


@dataclass(frozen=True)
class Agreement:
    """The mount against the floor over the window: means of the fitted minus the mount."""

    frames: int                    #: frames processed in the window
    fitted: int                    #: of which the floor fit corrected the mount
    pitch_deg: float = math.nan    #: + : the floor says the camera looks further down
    roll_deg: float = math.nan
    height_m: float = math.nan     #: + : the floor says the camera sits higher
    beyond: int = 0                #: frames whose floor lay beyond the fit's bounds
    beyond_reason: str = ''        #: the last such frame's reason
    warning: str = ''              #: '' when they agree (or too few frames to say)

    def values(self) -> dict[str, str]:
        """Key/values for the DiagnosticStatus."""
        if self.fitted < MIN_FRAMES:
            seen = f'too few floor fits ({self.fitted} of {self.frames} frames in {WINDOW_S:g} s)'
            return {'mount vs floor': seen}
        return {
            'mount vs floor': f'mean of {self.fitted} floor fits over {WINDOW_S:g} s',
            'floor minus mount: pitch [deg]': f'{self.pitch_deg:+.2f}',
            'floor minus mount: roll [deg]': f'{self.roll_deg:+.2f}',
            'floor minus mount: height [cm]': f'{100.0 * self.height_m:+.1f}',
        }


class MountCheck:
    """Thread-safe window of the floor fits of the processed frames."""

    def __init__(self, window_s: float = WINDOW_S) -> None:
        self.window_s = window_s
        self._lock = threading.Lock()
        # (time, fitted, d_pitch_deg, d_roll_deg, d_height_m, beyond_bounds, reason)
        self._frames: collections.deque[tuple] = collections.deque()

    def clear(self) -> None:
        """Forget the window (the mount changed)."""
        with self._lock:
            self._frames.clear()

    def add(self, fit: Any, now: float | None = None) -> None:
        """Record one processed frame's ``FloorFit`` (None: no fit ran)."""
        now = time.monotonic() if now is None else now
        if fit is None:
            entry = (now, False, 0.0, 0.0, 0.0, False, '')
        else:
            entry = (now, bool(fit.refined), fit.d_pitch_deg, fit.d_roll_deg, fit.d_height_m,
                     fit.beyond_bounds, fit.reason)
        with self._lock:
            self._frames.append(entry)
            self._drop_old(now)

    def _drop_old(self, now: float) -> None:
        while self._frames and self._frames[0][0] < now - self.window_s:
            self._frames.popleft()

    def agreement(self, cause: str, fix: str, now: float | None = None) -> Agreement:
        """Return the window's agreement; the warning names ``cause`` and ``fix``.

        cause: where the mount comes from (the URDF, the parameters); fix: how to correct it.
        """
        now = time.monotonic() if now is None else now
        with self._lock:
            self._drop_old(now)
            frames = list(self._frames)
        fitted = [f for f in frames if f[1]]
        beyond = [f for f in frames if f[5]]
        out = dict(frames=len(frames), fitted=len(fitted), beyond=len(beyond),
                   beyond_reason=beyond[-1][6] if beyond else '')
        if len(fitted) >= MIN_FRAMES:
            out.update(pitch_deg=sum(f[2] for f in fitted) / len(fitted),
                       roll_deg=sum(f[3] for f in fitted) / len(fitted),
                       height_m=sum(f[4] for f in fitted) / len(fitted))
        agreement = Agreement(**out)
        return Agreement(**out, warning=_warning(agreement, cause, fix))


def _warning(a: Agreement, cause: str, fix: str) -> str:
    """Return the WARN message of an agreement, or ''."""
    if a.frames >= MIN_FRAMES and a.beyond > BEYOND_WARN_SHARE * a.frames:
        return (f'the floor in view lies beyond what the floor fit may correct in {a.beyond} of '
                f'{a.frames} frames ({a.beyond_reason}): {cause} is far off; {MEASURE} and '
                f'{fix}')
    if a.fitted < MIN_FRAMES:
        return ''
    if (abs(a.pitch_deg) <= ANGLE_WARN_DEG and abs(a.roll_deg) <= ANGLE_WARN_DEG
            and abs(a.height_m) <= HEIGHT_WARN_M):
        return ''
    return (f'the camera mount disagrees with the floor in view: the floor puts the camera '
            f'at pitch {a.pitch_deg:+.1f} deg, roll {a.roll_deg:+.1f} deg, height '
            f'{100.0 * a.height_m:+.1f} cm from the mount (mean of {a.fitted} frames over '
            f'{WINDOW_S:g} s; limits {ANGLE_WARN_DEG:g} deg, {100.0 * HEIGHT_WARN_M:g} cm): '
            f'{cause} is likely wrong; {MEASURE} and {fix}')
