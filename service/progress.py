"""A one-line progress display on stderr for long commands."""

from __future__ import annotations

import sys
import time


class ProgressLine:
    """Rewrites one status line on a terminal; prints one line per stage elsewhere (logs, CI).

    Call it with the pipeline's progress events (dicts with ``stage``, ``message`` and, while
    refining, ``iteration`` and ``cost``).
    """

    def __init__(self, stream=None, quiet: bool = False):
        self.stream = stream or sys.stderr
        self.quiet = quiet
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.start = time.perf_counter()
        self.last_stage = None
        self.last_draw = 0.0

    def __call__(self, event: dict) -> None:
        if self.quiet:
            return
        stage = event.get("stage", "")
        text = f"[{time.perf_counter() - self.start:6.1f} s] {stage:<12} {event.get('message', '')}"
        if "iteration" in event:
            text += f"  iter {event['iteration']}  cost {event.get('cost', float('nan')):.6g}"
        if self.tty:
            now = time.perf_counter()
            if stage == self.last_stage and now - self.last_draw < 0.1:
                return
            self.last_draw = now
            self.stream.write("\r\033[K" + text[:150])
            if stage == "done":
                self.stream.write("\n")
        elif stage != self.last_stage:
            self.stream.write(text + "\n")
        self.stream.flush()
        self.last_stage = stage

    def close(self) -> None:
        if self.tty and not self.quiet:
            self.stream.write("\n")
            self.stream.flush()
