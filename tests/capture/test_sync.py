"""Frame-set assembly: missing frames, lost pulse lines, realignment by timestamps, stalls."""

import numpy as np

from wandcal.capture.recording.framesets import STALL_S, Assembler
from wandcal.drivers.camera import Frame

PERIOD = 10_000  # us, 100 Hz
IMG = np.zeros((2, 2), np.uint8)


def frame(seq, ts, cam="c"):
    return Frame(image=IMG, sequence=seq, timestamp_us=ts, camera_id=cam)


class FakeClock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def run(asm, pulses, frames_by_cam):
    for counter in pulses:
        asm.add_pulse(counter, 1_000_000 + counter * PERIOD)
    for cam, frames in frames_by_cam.items():
        for seq, ts in frames:
            asm.add_frame(cam, frame(seq, ts))


def test_missed_frame_leaves_an_empty_slot_and_keeps_the_set():
    asm = Assembler(["a", "b"], triggered=True)
    # camera clocks have their own origins; b misses pulse 102 (a gap in its sequence numbers)
    run(asm, range(100, 106), {0: [(s, 5_000 + s * PERIOD) for s in range(6)],
                               1: [(s, 9_000 + s * PERIOD) for s in range(6) if s != 2]})
    sets = asm.ready()
    assert [s.counter for s in sets] == [100, 101, 102, 103, 104, 105]
    assert sets[2].missing() == [1] and not sets[2].complete
    assert all(s.complete for i, s in enumerate(sets) if i != 2)
    assert asm.cameras[1].missed == 1 and not asm.messages


def test_lost_pulse_line_still_makes_a_set_without_a_time():
    asm = Assembler(["a"], triggered=True)
    run(asm, [0, 1, 3, 4], {0: [(s, s * PERIOD) for s in range(5)]})
    asm.end_camera(0)
    sets = asm.ready()
    assert [s.counter for s in sets] == [0, 1, 2, 3, 4]
    assert sets[2].trigger_us is None and sets[2].complete


def test_frame_lost_without_sequence_gap_is_realigned_by_timestamps():
    asm = Assembler(["a", "b"], triggered=True)
    # b (an OpenCV camera counting received frames) loses pulse 3: its later frames carry
    # sequence numbers one too low, but their timestamps are a whole period late
    b = [(s, 7_000 + s * PERIOD) for s in range(3)] + [(s, 7_000 + (s + 1) * PERIOD) for s in range(3, 7)]
    run(asm, range(8), {0: [(s, s * PERIOD) for s in range(8)], 1: b})
    asm.end_camera(0)
    asm.end_camera(1)
    sets = asm.ready()
    assert [s.missing() for s in sets] == [[], [], [], [1], [], [], [], []]
    for s in sets:
        if s.frames[1] is not None:  # every kept frame of b now sits on its own pulse
            assert s.frames[1].timestamp_us - 7_000 == (s.counter) * PERIOD
    assert asm.cameras[1].realigned == 1
    assert "realigned by its timestamps" in asm.messages[0]


def test_unrecoverable_misalignment_is_reported_and_the_frame_left_out():
    asm = Assembler(["a"], triggered=True)
    ts = [s * PERIOD for s in range(4)] + [4 * PERIOD + PERIOD // 2] + [s * PERIOD for s in range(5, 7)]
    run(asm, range(7), {0: list(enumerate(ts))})
    asm.end_camera(0)
    sets = asm.ready()
    assert sets[4].missing() == [0]
    assert asm.cameras[0].misaligned == 1
    assert "not a whole number of frame periods" in asm.messages[0] and "external-trigger mode" in asm.messages[0]


def test_a_silent_camera_stops_holding_sets_back_after_the_stall_time():
    clock = FakeClock()
    asm = Assembler(["a", "b"], triggered=True, clock=clock)
    run(asm, range(3), {0: [(s, s * PERIOD) for s in range(3)]})
    assert asm.ready() == []
    clock.t = STALL_S + 0.1
    sets = asm.ready()
    assert len(sets) == 3 and all(s.missing() == [1] for s in sets)


def test_clock_drift_is_measured():
    asm = Assembler(["a"], triggered=True)
    ppm = 40.0
    run(asm, range(200), {0: [(s, int(s * PERIOD * (1 + ppm * 1e-6))) for s in range(200)]})
    asm.end_camera(0)
    assert len(asm.ready()) == 200
    assert abs(asm.cameras[0].drift_ppm() - ppm) < 5  # the smoothed offset lags the ramp a little


def test_without_trigger_sets_follow_sequence_numbers():
    asm = Assembler(["a", "b"], triggered=False)
    run(asm, [], {0: [(s, s) for s in range(4)], 1: [(s, s) for s in (0, 1, 3)]})
    asm.end_camera(0)
    asm.end_camera(1)
    sets = asm.ready()
    assert [s.counter for s in sets] == [0, 1, 2, 3] and sets[2].missing() == [1]
    assert all(s.trigger_us is None for s in sets)
