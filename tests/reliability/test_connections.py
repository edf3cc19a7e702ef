"""Connections that never finish (issue 20, class 4): sockets that send nothing or half a request
header are closed after the header deadline, the oldest of them make room when the connection
limit is reached, a normal client is served all the while, and repeated log lines are counted
rather than written."""

from __future__ import annotations

import logging
import socket
import time

import httpx
from hypothesis import given, settings
from hypothesis import strategies as st

from wandcal.service.connection_limits import RepeatFilter

HELD = 150  # more than the limit below, so the limit's eviction is what lets the client in
MAX_CONNECTIONS = 40
HEADER_TIMEOUT_S = 2.0
POLL_DEADLINE_S = 120.0  # how long the test waits for the server to close them: generous, a busy CI box
PARTIAL = b"GET /api/v1/health HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: "


def _closed_by_server(sock: socket.socket) -> bool:
    try:
        return sock.recv(1, socket.MSG_DONTWAIT) == b""
    except BlockingIOError:
        return False
    except OSError:  # reset: closed too
        return True


def test_idle_and_partial_sockets_are_closed_while_a_client_is_served(server):
    srv = server(header_timeout_s=HEADER_TIMEOUT_S, max_connections=MAX_CONNECTIONS)
    held = []
    try:
        for k in range(HELD):
            s = socket.create_connection(("127.0.0.1", srv.port))
            if k % 2:
                s.sendall(PARTIAL)  # slowloris: a header begun and never finished
            held.append(s)
        # a normal client is answered while they are held (the limit closes the oldest of them)
        with httpx.Client(base_url=srv.url + "/api/v1", timeout=30.0) as client:
            for _ in range(5):
                assert client.get("/health").status_code == 200
        deadline = time.monotonic() + POLL_DEADLINE_S
        open_ = list(held)
        while open_ and time.monotonic() < deadline:
            open_ = [s for s in open_ if not _closed_by_server(s)]
            time.sleep(0.1)
        assert not open_, f"{len(open_)} of {HELD} idle or partial sockets still open"
        assert httpx.get(srv.url + "/api/v1/health", timeout=30.0).status_code == 200
        # a keep-alive client that goes quiet after its answer is closed as well
        s = socket.create_connection(("127.0.0.1", srv.port))
        s.sendall(b"GET /api/v1/health HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        assert s.recv(4096).startswith(b"HTTP/1.1 200")
        s.sendall(PARTIAL)
        while not _closed_by_server(s) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert _closed_by_server(s)
        held.append(s)
    finally:
        for s in held:
            s.close()
    log = srv.log.read_text(errors="replace")
    assert "Traceback" not in log


class FakeClock:
    def __init__(self):
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


@settings(max_examples=100, deadline=None, derandomize=True)
@given(events=st.lists(st.tuples(st.floats(0, 0.5), st.sampled_from(["Too many open files", "accept failed", "x"])),
                       max_size=200))
def test_repeated_log_lines_pass_once_a_window_and_count_the_rest(events):
    clock = FakeClock()
    f = RepeatFilter(window_s=1.0, clock=clock)
    passed: dict[str, int] = {}
    reported = 0
    for step, message in events:
        clock.now += step
        record = logging.LogRecord("asyncio", logging.ERROR, __file__, 1, message, None, None)
        if f.filter(record):
            passed[message] = passed.get(message, 0) + 1
            if "repeated" in str(record.msg):
                reported += int(str(record.msg).split("repeated ")[1].split()[0])
    span = clock.now
    for message in {m for _, m in events}:
        assert 1 <= passed[message] <= span / 1.0 + 1  # at most one line a window per message
    # every line is written or counted in a later line, except the repeats since each last one
    assert sum(passed.values()) + reported <= len(events)
