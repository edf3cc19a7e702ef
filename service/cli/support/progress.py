"""The progress line of long commands (calibrate, check, demo): one line on stderr, rewritten in
place on a terminal, and nothing at all with ``--quiet`` or when stderr is not a terminal (a log,
a pipe, CI), where the command's result is all that should appear."""

from __future__ import annotations

import sys
import threading
import time

REDRAW_S = 0.1  # events of one stage redraw at most ten times a second: readable, not a flood
# While one step runs long without an event (the paper method's first LP takes minutes at
# 8 x 1500), the line's clock still moves this often, so a working command never looks hung.
TICK_S = 0.5
WIDTH = 150  # characters of the line shown: wider lines wrap and break the in-place rewrite


class ProgressLine:
    """Call it with the pipeline's progress events (dicts with ``stage``, ``message`` and, while
    refining, ``iteration`` and ``cost``); :meth:`close` when the command is done."""

    def __init__(self, stream=None, quiet: bool = False):
        self.stream = stream or sys.stderr
        tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.quiet = quiet or not tty
        self.start = time.perf_counter()
        self.last_stage = None
        self.last_draw = 0.0
        self.text = ""
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._ticker: threading.Thread | None = None

    def __call__(self, event: dict) -> None:
        if self.quiet:
            return
        stage = event.get("stage", "")
        text = f"{stage:<12} {event.get('message', '')}"
        if "iteration" in event:
            text += f"  iter {event['iteration']}  cost {event.get('cost', float('nan')):.6g}"
        now = time.perf_counter()
        with self._lock:
            self.text = text
            if stage == self.last_stage and now - self.last_draw < REDRAW_S and stage != "done":
                return
            self.last_stage = stage
            self._draw(now)
        if self._ticker is None:
            self._ticker = threading.Thread(target=self._tick, name="progress-line", daemon=True)
            self._ticker.start()

    def _draw(self, now: float) -> None:
        self.last_draw = now
        self.stream.write("\r\033[K" + f"[{now - self.start:6.1f} s] {self.text}"[:WIDTH])
        self.stream.flush()

    def _tick(self) -> None:
        while not self._stop.wait(TICK_S):
            with self._lock:
                if time.perf_counter() - self.last_draw >= TICK_S:
                    self._draw(time.perf_counter())

    def close(self) -> None:
        """End the line (a terminal's next output starts on a fresh one)."""
        self._stop.set()
        if self._ticker is not None:
            self._ticker.join()
        if not self.quiet:
            with self._lock:
                self.stream.write("\n")
                self.stream.flush()
