"""A software twin of the strobe-trigger microcontroller, speaking ``wandcal-trigger/1``.

:class:`EmulatedTrigger` is the device's state machine with an injected clock; :func:`serve_pty`
puts it behind a real pseudo-terminal so the host's pyserial code runs unchanged against it.
"""

from __future__ import annotations

import array
import fcntl
import os
import select
import sys
import termios
import time
import tty
from collections.abc import Callable

from wandcal.drivers import trigger_protocol as tp

FIRMWARE = "emulator"
VERSION = "1.0"
LINES = 8  # camera trigger outputs of the reference board
DEFAULT_RATE_HZ = 100.0
DEFAULT_STROBE_US = 500
DRAIN_SECONDS = 5.0  # how long a vanishing emulator waits for the host to read what it sent


class EmulatedTrigger:
    """Device logic: commands in, reply lines and pulse lines out.

    Args:
        clock: seconds, monotonic. Pulse ``k`` of a run started at ``t0`` is due at
            ``t0 + k / rate`` and stamped with that time, as a hardware timer would.
        start_us: the device clock at power-on (set near 2**32 to exercise the wrap).
    """

    def __init__(self, clock: Callable[[], float] = time.monotonic, start_us: int = 0):
        self.clock = clock
        self.t0 = clock()
        self.start_us = start_us
        self.rate = DEFAULT_RATE_HZ
        self.strobe_us = DEFAULT_STROBE_US
        self.counter = 0
        self.running = False
        self.remaining = 0  # pulses left in this run; 0 with running means until STOP
        self.limited = False
        self._run_start = 0.0
        self._run_index = 0

    def now_us(self, t: float | None = None) -> int:
        t = self.clock() if t is None else t
        return (self.start_us + int(round((t - self.t0) * 1e6))) % tp.US_WRAP

    def handle(self, line: str) -> str:
        """The one reply line to a command line."""
        parts = line.strip().split()
        if not parts:
            return f"{tp.ERR} {tp.UNKNOWN} empty command; send HELLO, RATE, STROBE, START, STOP or STATUS"
        verb, args = parts[0].upper(), parts[1:]
        if verb == tp.HELLO:
            return f"{tp.HELLO} {tp.PROTOCOL} firmware={FIRMWARE} version={VERSION} lines={LINES}"
        if verb == tp.STATUS:
            return (f"{tp.STATUS} running={int(self.running)} rate={self.rate:g} strobe={self.strobe_us} "
                    f"counter={self.counter} remaining={self.remaining} t_us={self.now_us()}")
        if verb == tp.STOP:
            self.running = False
            return f"{tp.OK} {tp.STOP} {self.counter}"
        if verb in (tp.RATE, tp.STROBE, tp.START):
            return self._set(verb, args)
        return f"{tp.ERR} {tp.UNKNOWN} {parts[0]!r} is not a command; send HELLO, RATE, STROBE, START, STOP or STATUS"

    def _set(self, verb: str, args: list[str]) -> str:
        if self.running and verb != tp.START:
            return f"{tp.ERR} {tp.BUSY} {verb} while running; send STOP first"
        if self.running:
            return f"{tp.ERR} {tp.BUSY} already running; send STOP first"
        try:
            value = float(args[0]) if args else (0.0 if verb == tp.START else float("nan"))
        except ValueError:
            value = float("nan")
        if verb == tp.RATE:
            if not tp.MIN_RATE_HZ <= value <= tp.MAX_RATE_HZ:
                return f"{tp.ERR} {tp.BADARG} RATE needs a frequency in Hz from {tp.MIN_RATE_HZ:g} to {tp.MAX_RATE_HZ:g}"
            self.rate = value
            return f"{tp.OK} {tp.RATE} {value:g}"
        if verb == tp.STROBE:
            if not tp.MIN_STROBE_US <= value <= tp.MAX_STROBE_US or value >= 1e6 / self.rate:
                return (f"{tp.ERR} {tp.BADARG} STROBE needs a width in us from {tp.MIN_STROBE_US} to "
                        f"{tp.MAX_STROBE_US}, shorter than the pulse period")
            self.strobe_us = int(value)
            return f"{tp.OK} {tp.STROBE} {self.strobe_us}"
        if not (value >= 0 and value.is_integer()):
            return f"{tp.ERR} {tp.BADARG} START takes a whole number of pulses (0: until STOP)"
        self.running, self.remaining, self.limited = True, int(value), value > 0
        self._run_start, self._run_index = self.clock(), 0
        return f"{tp.OK} {tp.START} {int(value)}"

    def next_due(self) -> float | None:
        """Clock time of the next pulse, or None when stopped."""
        return self._run_start + self._run_index / self.rate if self.running else None

    def due_lines(self) -> list[str]:
        """Pulse lines (and a final DONE) for every pulse due by now."""
        out = []
        now = self.clock()
        while (due := self.next_due()) is not None and due <= now:  # None: stopped
            out.append(tp.format_pulse(self.counter, self.now_us(due)))
            self.counter += 1
            self._run_index += 1
            if self.limited:
                self.remaining -= 1
                if self.remaining == 0:
                    self.running = False
                    out.append(f"{tp.DONE} {self.counter}")
        return out


def serve_pty(vanish_after: int | None = None, start_us: int = 0, announce=print) -> int:
    """Serve the emulator on a new pseudo-terminal until killed.

    Prints the terminal's path (connect with ``serial:///dev/pts/N`` or the bare path).
    ``vanish_after``: after that many pulses close the terminal and return, as if the
    board were unplugged mid-capture. It first waits (up to ``DRAIN_SECONDS``) for the host to
    read the pulses already sent, so a test knows exactly which pulses the host received: a real
    unplug would also lose whatever still sat unread in the kernel's buffer.
    """
    master, slave = os.openpty()
    # Raw mode: no echo of commands back to the host and no CR/LF translation. The emulator keeps
    # its own slave descriptor open so the terminal survives the host closing and reopening it.
    tty.setraw(slave)
    announce(os.ttyname(slave))
    sys.stdout.flush()
    device = EmulatedTrigger(start_us=start_us)
    pending = b""
    try:
        while True:
            due = device.next_due()
            wait = 0.2 if due is None else max(0.0, due - device.clock())
            readable, _, _ = select.select([master], [], [], wait)
            if readable:
                pending += os.read(master, 4096)
                *lines, pending = pending.split(b"\n")
                for raw in lines:
                    line = raw.decode("ascii", "replace").strip()
                    if line:
                        _write(master, [device.handle(line)])
            out = device.due_lines()
            if vanish_after is not None and device.counter >= vanish_after:
                _write(master, [x for x in out if (p := tp.parse_pulse(x)) and p.counter < vanish_after])
                _wait_until_read(slave, DRAIN_SECONDS)
                return 0
            _write(master, out)
    finally:
        os.close(master)
        os.close(slave)


def _wait_until_read(slave: int, timeout: float) -> None:
    """Wait until the host has read everything written to the terminal, or ``timeout`` passes.

    The kernel moves written bytes to the reading side a little later (a work queue), so the
    queue must be seen empty on several checks in a row, not once.
    """
    deadline = time.monotonic() + timeout
    pending = array.array("i", [0])
    empty_checks = 0
    while empty_checks < 5 and time.monotonic() < deadline:
        time.sleep(0.01)
        fcntl.ioctl(slave, termios.FIONREAD, pending, True)
        empty_checks = empty_checks + 1 if pending[0] == 0 else 0


def _write(fd: int, lines: list[str]) -> None:
    if lines:
        os.write(fd, "".join(line + "\n" for line in lines).encode("ascii"))


class EmulatorProcess:
    """The emulator in a child process (for tests and demos): ``python -m
    wandcal.drivers.trigger_emulator``, the options of ``wandcal trigger-emulator``.

    Use as a context manager; ``path`` is the pseudo-terminal it serves. ``extra`` are more
    command-line options (``--vanish-after 60``).
    """

    def __init__(self, *extra: str):
        import subprocess
        from pathlib import Path

        root = Path(__file__).resolve().parents[1]
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(root), os.environ.get("PYTHONPATH")])))
        self.process = subprocess.Popen([sys.executable, "-m", "wandcal.drivers.trigger_emulator", *extra],
                                        stdout=subprocess.PIPE, text=True, env=env)
        stdout = self.process.stdout
        assert stdout is not None  # stdout=PIPE
        self.path = stdout.readline().strip()
        if not self.path.startswith("/dev/"):
            self.close()
            raise RuntimeError(f"the trigger emulator did not print its terminal path (got {self.path!r})")

    @property
    def url(self) -> str:
        return f"serial://{self.path}"

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
        self.process.wait()
        if self.process.stdout is not None:  # always (stdout=PIPE)
            self.process.stdout.close()

    def __enter__(self) -> EmulatorProcess:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def main(argv: list[str] | None = None) -> int:
    """``python -m wandcal.drivers.trigger_emulator [--vanish-after N] [--start-us US]``: the child of
    :class:`EmulatorProcess`. Here, not in the command line, because drivers import nothing of the
    layers above them; ``wandcal trigger-emulator`` is the same emulator with its options checked
    for a person (service/cli/recording/trigger.py)."""
    import argparse

    parser = argparse.ArgumentParser(prog="python -m wandcal.drivers.trigger_emulator")
    parser.add_argument("--vanish-after", type=int, default=None, metavar="N")
    parser.add_argument("--start-us", type=int, default=0, metavar="US")
    args = parser.parse_args(argv)
    return serve_pty(vanish_after=args.vanish_after, start_us=args.start_us)


if __name__ == "__main__":
    sys.exit(main())
