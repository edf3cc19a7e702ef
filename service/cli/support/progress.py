"""The progress line of every long command (calibrate, check, demo, detect, capture), with one policy:

- On a terminal, one line on stderr, rewritten in place: the time since the command started, then
  what it is doing. A new stage is drawn at once; news within a stage at most ten times a second;
  and while a step runs long without news (the paper method's first LP takes minutes at 8 x 1500),
  a ticker keeps the clock moving so that a working command never looks hung.
- Elsewhere (a log, a pipe, CI) and with ``--quiet``, nothing is drawn: the command's result is all
  that should appear there.
- A command's closing line (:meth:`ProgressLine.done`: what ``detect`` wrote, what ``capture``
  recorded) is part of its result, so it is printed in every case, quiet or not, terminal or not.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from typing import TextIO

REDRAW_S = 0.1  # news of one stage redraws at most ten times a second: readable, not a flood
TICK_S = 0.5  # how often the clock moves while a step sends no news
WIDTH = 150  # characters shown where the terminal's width is unknown: a wrapped line breaks the rewrite


class ProgressLine:
    """Feed it the pipeline's events (call it with dicts of ``stage``, ``message`` and, while refining,
    ``iteration`` and ``cost``) or a command's own text (:meth:`update`); end it with :meth:`close`,
    or with :meth:`done` and the closing line."""

    def __init__(self, stream: TextIO | None = None, quiet: bool = False, clock=time.perf_counter):
        self.stream = stream or sys.stderr
        tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.quiet = quiet or not tty
        self.clock = clock
        self.start = clock()
        self.stage: str | None = None
        self.last_draw = -float("inf")
        self.text = ""
        self.ended = False
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._ticker: threading.Thread | None = None

    def __call__(self, event: dict) -> None:
        """A pipeline event: ``{"stage", "message"}``, with ``"iteration"`` and ``"cost"`` while refining."""
        if self.quiet:
            return
        stage = event.get("stage", "")
        text = f"{stage:<12} {event.get('message', '')}"
        if "iteration" in event:
            text += f"  iter {event['iteration']}  cost {event.get('cost', float('nan')):.6g}"
        self.update(text, stage=stage)

    def update(self, text: str, stage: str | None = None) -> None:
        """Show ``text``: at once when it starts a new ``stage`` (or the stage ``done``), else when
        the line was last drawn at least :data:`REDRAW_S` ago."""
        if self.quiet:
            return
        with self._lock:
            self.text = text
            now = self.clock()
            if self.ended or (stage == self.stage and stage != "done" and now - self.last_draw < REDRAW_S):
                return
            self.stage = stage
            self._draw(now)
            if self._ticker is None:
                self._ticker = threading.Thread(target=self._tick, name="progress-line", daemon=True)
                self._ticker.start()

    def close(self) -> None:
        """End the line (a terminal's next output starts on a fresh one); again does nothing."""
        if self._end() and not self.quiet:
            with self._lock:
                self.stream.write("\n")
                self.stream.flush()

    def done(self, text: str) -> None:
        """End the line with the command's closing ``text``, printed in every case; on a terminal
        it replaces the progress line."""
        self._end()
        with self._lock:
            self.stream.write(("\r\033[K" if not self.quiet else "") + text + "\n")
            self.stream.flush()

    def __enter__(self) -> ProgressLine:
        return self

    def __exit__(self, *exc) -> None:
        self.close()  # after done() nothing; after an error the line ends before the message

    def _end(self) -> bool:
        """Stop the ticker; False when the line had ended already."""
        with self._lock:
            ended, self.ended = self.ended, True
        self._stop.set()
        if self._ticker is not None:
            self._ticker.join()
        return not ended

    def _draw(self, now: float) -> None:
        self.last_draw = now
        try:
            self.stream.write("\r\033[K" + f"[{now - self.start:6.1f} s] {self.text}"[:self._width()])
            self.stream.flush()
        except OSError:  # the terminal hung up (EIO): a progress line is not worth failing the work for
            self.quiet = True

    def _tick(self) -> None:
        while not self._stop.wait(TICK_S):
            with self._lock:
                if self.clock() - self.last_draw >= TICK_S:
                    self._draw(self.clock())

    def _width(self) -> int:
        try:
            columns = os.get_terminal_size(self.stream.fileno()).columns
        except (AttributeError, OSError, ValueError):  # not a real terminal (a test's stand-in)
            return WIDTH
        return columns - 1 if columns > 1 else WIDTH  # a new pseudo-terminal reports 0 columns


def bar(done: int, total: int, width: int = 30) -> str:
    """``[#######.......]  45/120``"""
    filled = int(width * done / total) if total else width
    return f"[{'#' * filled}{'.' * (width - filled)}] {done}/{total}"
