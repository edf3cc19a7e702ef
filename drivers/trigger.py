"""Host side of the strobe trigger: a microcontroller that pulses the cameras' trigger inputs and
the IR strobes and reports every pulse over a serial line (``wandcal-trigger/1``,
docs/trigger-protocol.md).

URLs: ``serial:///dev/ttyACM0``, a bare device path (``/dev/pts/5``), or any pyserial URL
(``loop://``, ``socket://host:port``), opened with ``serial.serial_for_url``. ``none`` means no
trigger (free-running cameras matched by their sequence numbers).
"""

from __future__ import annotations

import contextlib
import queue
import threading
from dataclasses import dataclass

import serial

from wandcal.drivers import trigger_protocol as tp
from wandcal.drivers.errors import DriverError

REPLY_TIMEOUT_S = 2.0  # a board answers within milliseconds; USB re-enumeration can take a second
READ_POLL_S = 0.05  # the reader thread's read timeout: how soon it notices close()


class TriggerLost(DriverError):
    """The serial port vanished (unplugged, emulator killed) or stopped answering."""


@dataclass(frozen=True)
class Pulse:
    """One trigger pulse: its counter since the device powered on and its time on the device
    clock, in microseconds, unwrapped to a monotonic integer."""

    counter: int
    t_us: int


class SerialTrigger:
    """A ``wandcal-trigger/1`` device. Opening is a reentrant context manager.

    Args:
        url: ``serial:///dev/ttyACM0``, a device path or a pyserial URL.
        port: an already-open pyserial-like object (tests); ``url`` then only names it.
    """

    def __init__(self, url: str, port=None):
        self.url = url
        self.identity: dict[str, str] = {}
        self._port = port
        self._given_port = port is not None
        self._depth = 0
        self._replies: queue.Queue[str | None] = queue.Queue()  # None: the reader stopped
        self._pulses: queue.Queue[Pulse | None] = queue.Queue()
        self._cmd_lock = threading.Lock()
        self._reader: threading.Thread | None = None
        self._closing = threading.Event()
        self.done = threading.Event()  # the device sent DONE: the last pulse of a counted run
        self.lost: TriggerLost | None = None
        self._unwrap = tp.Unwrapper()

    # -- lifetime
    def open(self) -> SerialTrigger:
        if self._depth == 0:
            self._connect()
        self._depth += 1
        return self

    def close(self) -> None:
        if self._depth == 0:
            return
        self._depth -= 1
        if self._depth == 0:
            if self.lost is None:
                with contextlib.suppress(DriverError):  # closing anyway; a port that went away is reported by .lost
                    self.stop()
            self._closing.set()
            if self._reader is not None:
                self._reader.join(timeout=1.0)
            if not self._given_port:
                self._port.close()

    def __enter__(self) -> SerialTrigger:
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    def _connect(self) -> None:
        if not self._given_port:
            target = self.url[len("serial://"):] if self.url.startswith("serial://") else self.url
            try:
                self._port = serial.serial_for_url(target, baudrate=tp.BAUD, timeout=READ_POLL_S)
            except (serial.SerialException, OSError, ValueError) as exc:
                raise DriverError(f"trigger {self.url}: cannot open the serial port ({exc}); check the path "
                                  "(ls /dev/ttyACM* /dev/ttyUSB*), that you are in group 'dialout', and that no "
                                  "other program holds it") from None
        self._closing.clear()
        self._reader = threading.Thread(target=self._read_loop, name="trigger-reader", daemon=True)
        self._reader.start()
        self.command(tp.STOP)  # a board left running by an earlier session stops first
        self._drain_pulses()
        hello = self.command(tp.HELLO)
        parts = hello.split()
        if len(parts) < 2 or parts[1] != tp.PROTOCOL:
            raise DriverError(f"trigger {self.url}: the device speaks {parts[1] if len(parts) > 1 else '?'!r}, not "
                              f"{tp.PROTOCOL!r}; flash drivers/firmware/wandcal_trigger or update wandcal")
        self.identity = tp.parse_fields(hello)

    # -- commands
    def command(self, verb: str, *args) -> str:
        """Send one command and return its reply line; an ERR reply raises :class:`DriverError`."""
        line = " ".join([verb, *map(str, args)])
        with self._cmd_lock:
            self._check_lost()
            try:
                self._port.write((line + "\n").encode("ascii"))
                self._port.flush()
            except (serial.SerialException, OSError) as exc:
                self._set_lost(f"writing '{line}' failed ({exc})")
                self._check_lost()
            try:
                reply = self._replies.get(timeout=REPLY_TIMEOUT_S)
            except queue.Empty:
                self._check_lost()
                raise DriverError(f"trigger {self.url}: no reply to '{line}' within {REPLY_TIMEOUT_S:g} s; is it a "
                                  f"{tp.PROTOCOL} device (docs/trigger-protocol.md)?") from None
        if reply is None:  # the reader stopped; _set_lost recorded why before it queued the None
            raise self.lost or DriverError(f"trigger {self.url}: the connection was lost")
        if reply.startswith(tp.ERR):
            raise DriverError(f"trigger {self.url} refused '{line}': {reply}")
        return reply

    def set_rate(self, hz: float) -> None:
        self.command(tp.RATE, f"{hz:g}")

    def start(self, count: int = 0) -> None:
        """Start pulsing: ``count`` pulses then DONE, or until :meth:`stop` when 0."""
        self.done.clear()
        self.command(tp.START, int(count))

    def stop(self) -> int:
        """Stop pulsing; returns the device's pulse counter."""
        return int(self.command(tp.STOP).split()[-1])

    def status(self) -> dict[str, str]:
        return tp.parse_fields(self.command(tp.STATUS))

    def next_pulse(self, timeout: float | None = None) -> Pulse | None:
        """The next pulse, or None after ``timeout`` s; raises :class:`TriggerLost` once the port
        is gone and every pulse received before that has been handed out."""
        try:
            pulse = self._pulses.get(timeout=timeout)
        except queue.Empty:
            return None
        if pulse is None:
            self._pulses.put(None)  # keep the end marker for later calls
            self._check_lost()
        return pulse

    # -- reader thread
    def _read_loop(self) -> None:
        while not self._closing.is_set():
            try:
                raw = self._port.readline()
            except (serial.SerialException, OSError) as exc:
                if not self._closing.is_set():
                    self._set_lost(f"the port vanished ({exc})")
                return
            if not raw:
                continue
            line = raw.decode("ascii", "replace").strip()
            if not line or line.startswith(tp.COMMENT):
                continue
            pulse = tp.parse_pulse(line)
            if pulse is not None:
                self._pulses.put(Pulse(pulse.counter, self._unwrap(pulse.t_us)))
            elif line.startswith(tp.DONE):
                self.done.set()
            elif line.startswith(tp.PULSE + " "):
                continue  # a garbled pulse line: its counter gap shows up above as a missing pulse time
            else:
                self._replies.put(line)

    def _set_lost(self, why: str) -> None:
        if self.lost is None:
            self.lost = TriggerLost(f"trigger {self.url}: {why}. Capture stopped; everything received until then "
                                    "is kept. Reconnect the trigger (check the USB cable) and record again.")
        self._pulses.put(None)
        self._replies.put(None)

    def _check_lost(self) -> None:
        if self.lost is not None:
            raise self.lost

    def _drain_pulses(self) -> None:
        while True:
            try:
                self._pulses.get_nowait()
            except queue.Empty:
                return


def open_trigger(url: str | None) -> SerialTrigger | None:
    """The trigger named by ``url``; None for ``none`` (or an empty URL)."""
    if url is None or url.strip().lower() in ("", "none"):
        return None
    return SerialTrigger(url)
