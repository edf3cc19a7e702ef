"""A one-line status display on stderr: rewritten in place on a terminal; elsewhere (logs, CI) and
with ``quiet`` only the final line (:meth:`StatusLine.done`, the command's summary) is printed."""

from __future__ import annotations

import sys
import time
from typing import TextIO

TTY_INTERVAL_S = 0.2  # five updates a second read smoothly without flooding the terminal


class StatusLine:
    def __init__(self, stream: TextIO | None = None, clock=time.monotonic, quiet: bool = False):
        self.stream = stream or sys.stderr
        self.clock = clock
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)()) and not quiet
        self._last = -1e9
        self._width = 0

    def update(self, text: str, force: bool = False) -> None:
        now = self.clock()
        if not force and (not self.tty or now - self._last < TTY_INTERVAL_S):
            return
        self._last = now
        if self.tty:
            self.stream.write("\r" + text.ljust(self._width))
            self._width = len(text)
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def done(self, text: str) -> None:
        self.update(text, force=True)
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()


def bar(done: int, total: int, width: int = 30) -> str:
    """``[#######.......]  45/120``"""
    filled = int(width * done / total) if total else width
    return f"[{'#' * filled}{'.' * (width - filled)}] {done}/{total}"
