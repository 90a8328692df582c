"""A small progress bar for the command-line tools (standard library only)."""

from __future__ import annotations

import sys
import time
from typing import Any, TextIO


class Progress:
    """Count work items: a bar redrawn on a terminal (at most every 0.1 s), one final line."""

    def __init__(self, total: int | None, label: str, *, stream: TextIO | None = None) -> None:
        """Start counting; ``total`` None: no bar, only the count."""
        self.total = total
        self.label = label
        self.count = 0
        self._stream = sys.stderr if stream is None else stream
        self._start = time.monotonic()
        self._drawn = 0.0

    def update(self, n: int = 1) -> None:
        """Mark ``n`` more items as done."""
        self.count += n
        if self._stream.isatty() and time.monotonic() - self._drawn >= 0.1:
            self._drawn = time.monotonic()
            self._stream.write('\r' + self._line())
            self._stream.flush()

    def _line(self) -> str:
        elapsed = time.monotonic() - self._start
        if self.total:
            filled = '#' * round(30 * min(self.count / self.total, 1.0))
            bar = f' [{filled.ljust(30, "-")}] {self.count}/{self.total}'
        else:
            bar = f' {self.count}'
        return f'{self.label}{bar} {elapsed:5.1f} s ({self.count / max(elapsed, 1e-9):.1f}/s)'

    def __enter__(self) -> Progress:
        """Return the bar itself."""
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *_: Any) -> None:
        """Write the final line, marked ``(stopped)`` when the work stopped on an error."""
        end = ' (stopped)\n' if exc_type is not None else '\n'
        self._stream.write(('\r' if self._stream.isatty() else '') + self._line() + end)
        self._stream.flush()
