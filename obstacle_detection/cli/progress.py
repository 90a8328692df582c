"""A small progress bar for the command-line tools (standard library only)."""

from __future__ import annotations

import sys
import time
from types import TracebackType
from typing import TextIO

_BAR_WIDTH = 30
_MIN_REDRAW_S = 0.1


class Progress:
    """Count work items and show how far along the work is."""

    def __init__(self, total: int | None, label: str, *, stream: TextIO | None = None) -> None:
        """Start counting."""
        self.total = total
        self.label = label
        self.count = 0
        self._stream = stream if stream is not None else sys.stderr
        self._interactive = bool(getattr(self._stream, 'isatty', lambda: False)())
        self._start = time.monotonic()
        self._last_draw = 0.0
        self._closed = False

    def update(self, n: int = 1) -> None:
        """Mark ``n`` more items as done, redrawing the bar at most every 0.1 s."""
        self.count += n
        if not self._interactive:
            return
        now = time.monotonic()
        if now - self._last_draw >= _MIN_REDRAW_S or self.count == self.total:
            self._last_draw = now
            self._stream.write('\r' + self._line())
            self._stream.flush()

    def close(self, message: str = '') -> None:
        """Finish: write the final line (with an optional message after it)."""
        if self._closed:
            return
        self._closed = True
        line = self._line()
        if message:
            line = f'{line} {message}'
        self._stream.write(('\r' if self._interactive else '') + line + '\n')
        self._stream.flush()

    def _line(self) -> str:
        elapsed = time.monotonic() - self._start
        rate = self.count / elapsed if elapsed > 0 else 0.0
        if self.total:
            done = min(self.count / self.total, 1.0)
            filled = int(round(done * _BAR_WIDTH))
            bar = '#' * filled + '-' * (_BAR_WIDTH - filled)
            return (f'{self.label} [{bar}] {self.count}/{self.total} '
                    f'{elapsed:5.1f} s ({rate:.1f}/s)')
        return f'{self.label} {self.count} {elapsed:5.1f} s ({rate:.1f}/s)'

    def __enter__(self) -> Progress:
        """Return the bar itself."""
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 traceback: TracebackType | None) -> None:
        """Write the final line, marking it when the work stopped on an error."""
        self.close('(stopped)' if exc_type is not None else '')
