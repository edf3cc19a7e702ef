"""The image writer's memory bound and its error reporting."""

import threading
import time

import numpy as np
import pytest

import wandcal.capture.recording.writer as writer_module
from wandcal.capture.recording.session import (
    INBOX_SECONDS,
    LEAD_SECONDS,
    MEMORY_BUDGET_BYTES,
    WRITE_SECONDS,
    buffer_frames,
)
from wandcal.capture.recording.writer import ImageWriter
from wandcal.drivers.errors import DriverError


def test_a_slow_disk_blocks_the_producer_instead_of_growing_the_queue(tmp_path, monkeypatch):
    gate = threading.Event()
    real = writer_module.cv2.imwrite

    def slow_imwrite(path, image, params):
        gate.wait()
        return real(path, image, params)

    monkeypatch.setattr(writer_module.cv2, "imwrite", slow_imwrite)
    w = ImageWriter(max_queued=4, threads=1)
    image = np.zeros((8, 8), np.uint8)
    produced = []

    def produce():
        for i in range(20):
            w.put(tmp_path / f"{i}.png", image)
            produced.append(i)

    t = threading.Thread(target=produce)
    t.start()
    deadline = time.monotonic() + 10
    while len(produced) < 5 and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(0.2)  # time to overrun the bound, were it not held
    # one image in the writer's hands and four waiting: the producer is held at the sixth
    assert len(produced) == 5 and w.high_water <= 4
    gate.set()
    t.join(5)
    w.close()
    assert w.written == 20 and w.high_water <= 4
    assert len(list(tmp_path.glob("*.png"))) == 20


def test_write_errors_surface_with_the_path(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    w = ImageWriter(max_queued=2, threads=1)
    w.put(blocker / "cam1" / "000000.png", np.zeros((4, 4), np.uint8))
    with pytest.raises(DriverError, match="cannot write .*000000.png"):
        w.close()


def test_buffers_hold_two_seconds_and_at_most_the_memory_budget():
    seconds = (INBOX_SECONDS, LEAD_SECONDS, WRITE_SECONDS)
    # small frames: the time bound, two seconds of 8 cameras at 100 fps, whatever the duration
    assert sum(buffer_frames(100, 8, s, 320 * 240) for s in seconds) == pytest.approx(8 * 100 * 2, abs=3)
    # 16-bit 1280x1024 frames (the sizing the session uses): the byte budget binds
    frame = 1280 * 1024 * 2
    frames = sum(buffer_frames(100, 8, s, frame) for s in seconds)
    assert frames * frame <= MEMORY_BUDGET_BYTES and frames >= 8 * 100 * 0.5
