"""The ``wandcal-trigger/1`` serial line protocol (docs/trigger-protocol.md), shared by the host
client (:mod:`wandcal.drivers.trigger`), the emulator and, in C, the reference firmware.

Lines are ASCII, terminated by LF (a CR before it is ignored). The host sends commands; the
device answers each with exactly one reply line, and while running it also sends one pulse
line per trigger pulse.
"""

from __future__ import annotations

from dataclasses import dataclass

PROTOCOL = "wandcal-trigger/1"
BAUD = 115200  # USB CDC ignores it; a real UART bridge needs it, and 115200 carries ~7000 pulse lines/s
MIN_RATE_HZ = 0.1
MAX_RATE_HZ = 2000.0  # above this an ATmega32U4's printing of pulse lines cannot keep up
MIN_STROBE_US = 10
MAX_STROBE_US = 100_000
US_WRAP = 1 << 32  # the device clock is a uint32 of microseconds (Arduino micros()): wraps after 71.6 min

# command verbs (host -> device)
HELLO, RATE, STROBE, START, STOP, STATUS = "HELLO", "RATE", "STROBE", "START", "STOP", "STATUS"
COMMANDS = (HELLO, RATE, STROBE, START, STOP, STATUS)
# reply and event prefixes (device -> host)
OK, ERR, PULSE, DONE, COMMENT = "OK", "ERR", "P", "DONE", "#"
# error codes
BADARG, UNKNOWN, BUSY = "BADARG", "UNKNOWN", "BUSY"


@dataclass(frozen=True)
class PulseLine:
    """``P <counter> <t_us>``: pulse number ``counter`` (since power-on, from 0) left the device
    at ``t_us`` on its microsecond clock (uint32, wraps)."""

    counter: int
    t_us: int


def parse_pulse(line: str) -> PulseLine | None:
    """The pulse in ``line``, or None when ``line`` is not a well-formed pulse line."""
    parts = line.split()
    if len(parts) != 3 or parts[0] != PULSE:
        return None
    try:
        counter, t_us = int(parts[1]), int(parts[2])
    except ValueError:
        return None
    if counter < 0 or not 0 <= t_us < US_WRAP:
        return None
    return PulseLine(counter, t_us)


def format_pulse(counter: int, t_us: int) -> str:
    return f"{PULSE} {counter} {t_us % US_WRAP}"


def parse_fields(line: str) -> dict[str, str]:
    """``key=value`` fields of a HELLO or STATUS reply."""
    return dict(p.split("=", 1) for p in line.split() if "=" in p)


class Unwrapper:
    """Turns the device's wrapping uint32 microsecond clock into a monotonic int."""

    def __init__(self) -> None:
        self._last: int | None = None
        self._offset = 0

    def __call__(self, t_us: int) -> int:
        if self._last is not None and t_us < self._last - US_WRAP // 2:
            self._offset += US_WRAP
        self._last = t_us
        return t_us + self._offset
