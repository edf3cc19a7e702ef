"""The wandcal-trigger/1 client against the emulator on a real pseudo-terminal (real pyserial)."""

import time

import pytest

from wandcal.drivers import trigger_protocol as tp
from wandcal.drivers.errors import DriverError
from wandcal.drivers.trigger import SerialTrigger, TriggerLost, open_trigger
from wandcal.drivers.trigger_emulator import EmulatedTrigger, EmulatorProcess


def collect(trigger, n, timeout=5.0):
    pulses, end = [], time.monotonic() + timeout
    while len(pulses) < n and time.monotonic() < end:
        p = trigger.next_pulse(timeout=0.5)
        if p is not None:
            pulses.append(p)
    return pulses


def test_hello_rate_start_pulses_over_pty():
    with EmulatorProcess() as emu, SerialTrigger(emu.url) as trig:
        assert trig.identity["firmware"] == "emulator"
        trig.set_rate(500)
        trig.start(40)
        pulses = collect(trig, 40)
        assert trig.done.wait(2.0)
        status = trig.status()
    counters = [p.counter for p in pulses]
    assert counters == list(range(counters[0], counters[0] + 40))
    gaps = {b.t_us - a.t_us for a, b in zip(pulses, pulses[1:])}
    assert gaps <= {2000}  # stamped by the (emulated) hardware timer: exactly 1/500 s apart
    assert status["running"] == "0" and int(status["counter"]) == counters[-1] + 1


def test_error_replies_raise_with_the_device_message():
    with EmulatorProcess() as emu, SerialTrigger(emu.url) as trig:
        with pytest.raises(DriverError, match="BADARG RATE needs a frequency"):
            trig.set_rate(0)
        with pytest.raises(DriverError, match="UNKNOWN"):
            trig.command("FIRE")
        trig.start(0)
        with pytest.raises(DriverError, match="BUSY"):
            trig.set_rate(10)
        assert trig.stop() >= 0


def test_clock_wrap_is_unwrapped():
    # The device clock wraps 3 s after power-on: far more than the client needs to say HELLO, RATE and
    # START on a loaded machine (CI once took over 30 ms), so the wrap falls inside the run.
    start = tp.US_WRAP - 3_000_000
    with EmulatorProcess("--start-us", str(start)) as emu, SerialTrigger(emu.url) as trig:
        trig.set_rate(1000)
        trig.start(0)
        pulses, end = [], time.monotonic() + 30.0
        while (not pulses or pulses[-1].t_us < tp.US_WRAP + 50_000) and time.monotonic() < end:
            if (p := trig.next_pulse(timeout=0.5)) is not None:
                pulses.append(p)
        trig.stop()
    times = [p.t_us for p in pulses]
    assert times[0] < tp.US_WRAP, "the run began after the wrap: the client took over 3 s to start it"
    assert all(b - a == 1000 for a, b in zip(times, times[1:]))
    assert times[-1] > tp.US_WRAP  # past the wrap and still monotonic


def test_port_vanishing_keeps_received_pulses_and_says_so():
    with EmulatorProcess("--vanish-after", "30") as emu:
        trig = SerialTrigger(emu.url)
        with trig:
            trig.set_rate(1000)
            trig.start(0)
            got = []
            with pytest.raises(TriggerLost, match="vanished.*everything received until then is kept"):
                while True:
                    p = trig.next_pulse(timeout=3.0)
                    assert p is not None, "the emulator should have vanished"
                    got.append(p)
    # the emulator vanishes once the host has read what it sent: all 30 pulses arrived, in order
    assert [p.counter for p in got] == list(range(30))


def test_unopenable_port_names_it():
    with pytest.raises(DriverError, match="/dev/nonexistent-tty.*cannot open"):
        SerialTrigger("serial:///dev/nonexistent-tty").open()
    assert open_trigger("none") is None


def test_emulated_device_logic_with_a_fake_clock():
    now = [0.0]
    dev = EmulatedTrigger(clock=lambda: now[0])
    assert dev.handle("hello").startswith(f"HELLO {tp.PROTOCOL}")
    assert dev.handle("RATE 100") == "OK RATE 100"
    assert dev.handle("STROBE 20000").startswith("ERR BADARG")  # longer than the 10 ms period
    assert dev.handle("START 3") == "OK START 3"
    assert dev.next_due() == 0.0
    now[0] = 0.015
    assert dev.due_lines() == ["P 0 0", "P 1 10000"]
    now[0] = 1.0
    assert dev.due_lines() == ["P 2 20000", "DONE 3"]
    assert dev.next_due() is None
