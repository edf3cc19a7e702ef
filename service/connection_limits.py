"""Connections that never finish: a header deadline, a connection limit that evicts the idlest,
and log lines that repeat at most once a second (docs/reliability.md, "Connections").

uvicorn closes a connection that stays idle *after* a response (``timeout_keep_alive``), but not
one that sends nothing, or half a request header, and then waits (slowloris): about a thousand of
those used every file descriptor a systemd unit has by default and locked every client out.
:func:`server_options` gives ``uvicorn.run`` a protocol that closes them.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time

import h11
from uvicorn.protocols.http.h11_impl import H11Protocol

# a log line repeated within this many seconds is counted rather than written ("Too many open
# files" from the accept loop filled 57 MB of log in seconds)
REPEAT_WINDOW_S = 1.0
MAX_HEADER_BYTES = 16 * 1024  # h11's default, stated: browsers send 1-8 kB of header; a larger one is a 400


class GuardedH11Protocol(H11Protocol):
    """An ``H11Protocol`` that closes a connection which has not sent a whole request header
    within ``header_timeout_s`` of opening (or of its last response), and that, when more than
    ``max_connections`` are open, closes the one waiting longest for a header to make room.
    :func:`guarded_protocol` sets the two limits."""

    header_timeout_s: float
    max_connections: int
    _waiting_since: float | None = None  # monotonic seconds since it waits for a request header
    _header_task: asyncio.TimerHandle | None = None

    def connection_made(self, transport) -> None:
        super().connection_made(transport)
        self._arm_header_deadline()
        if len(self.connections) > self.max_connections:
            waiting = {c: c._waiting_since for c in self.connections
                       if c is not self and isinstance(c, GuardedH11Protocol) and c._waiting_since}
            if waiting:
                min(waiting, key=waiting.__getitem__)._close_waiting()
            else:  # every other connection is mid-request: refuse this one rather than a request
                self._close_waiting()

    def _arm_header_deadline(self) -> None:
        self._waiting_since = time.monotonic()
        old = self._header_task
        if old is not None:
            old.cancel()
        self._header_task = self.loop.call_later(self.header_timeout_s, self._header_deadline)

    def _header_deadline(self) -> None:
        self._header_task = None
        if self.conn.their_state is h11.IDLE:  # no whole request header since it was armed
            self._close_waiting()

    def _close_waiting(self) -> None:
        self._waiting_since = None
        if not self.transport.is_closing():
            self.transport.close()

    def handle_events(self) -> None:
        super().handle_events()
        if self.conn.their_state is not h11.IDLE:  # a request's header has arrived
            self._waiting_since = None

    def on_response_complete(self) -> None:
        super().on_response_complete()
        if not self.transport.is_closing():
            self._arm_header_deadline()

    def connection_lost(self, exc) -> None:
        task = self._header_task
        if task is not None:
            task.cancel()
        self._waiting_since = None
        super().connection_lost(exc)


def guarded_protocol(header_timeout_s: float, max_connections: int) -> type[H11Protocol]:
    """:class:`GuardedH11Protocol` with these limits: seconds to a whole header, open connections."""
    limits = {"header_timeout_s": header_timeout_s, "max_connections": max_connections}
    return type("GuardedH11Protocol", (GuardedH11Protocol,), limits)


def server_options(settings) -> dict:
    """Keyword arguments of ``uvicorn.run`` for ``settings`` (wandcal.service.settings.Settings)."""
    return {
        "http": guarded_protocol(settings.header_timeout_s, settings.max_connections),
        "timeout_keep_alive": settings.keep_alive_s,
        # h11 buffers a request header up to this size; a larger one is a 400, not memory
        "h11_max_incomplete_event_size": MAX_HEADER_BYTES,
    }


class RepeatFilter(logging.Filter):
    """Lets a message through once per ``window_s``; the repeats in between are counted and the
    next line that passes says how many were left out."""

    def __init__(self, window_s: float = REPEAT_WINDOW_S, clock=time.monotonic):
        super().__init__()
        self.window_s = window_s
        self.clock = clock
        self._last: dict[tuple[str, int, str], tuple[float, int]] = {}
        self._lock = threading.Lock()

    def filter(self, record: logging.LogRecord) -> bool:
        key = (record.name, record.levelno, str(record.msg))
        now = self.clock()
        with self._lock:
            when, skipped = self._last.get(key, (None, 0))
            if when is not None and now - when < self.window_s:
                self._last[key] = (when, skipped + 1)
                return False
            self._last[key] = (now, 0)
            if len(self._last) > 1024:  # keys are message templates: a few dozen in practice
                self._last = {key: (now, 0)}
        if skipped:
            record.msg = f"{record.msg} (repeated {skipped} more times in the last {self.window_s:g} s)"
        return True


REPEATING_LOGGERS = ("asyncio", "uvicorn.error", "wandcal.service")


def install_repeat_filter() -> None:
    """Rate-limit the loggers whose lines can repeat without bound (the accept loop's errors)."""
    for name in REPEATING_LOGGERS:
        logger = logging.getLogger(name)
        if not any(isinstance(f, RepeatFilter) for f in logger.filters):
            logger.addFilter(RepeatFilter())
