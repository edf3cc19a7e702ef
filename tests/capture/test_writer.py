"""The image writer's memory bound and its error reporting."""

import threading
import time

import numpy as np
import pytest

import capture.writer as writer_module
from capture.session import INBOX_SECONDS, LEAD_SECONDS, WRITE_SECONDS, buffer_frames
from capture.writer import ImageWriter
from drivers.errors import DriverError


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
    time.sleep(0.3)
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


def test_documented_bound_for_ten_minutes_of_8_cameras_at_100_fps():
    # the bound does not grow with the capture's length: only rate x cameras x seconds
    total = sum(buffer_frames(100, 8, s) for s in (INBOX_SECONDS, LEAD_SECONDS, WRITE_SECONDS))
    assert total == 8 * 100 * 2  # two seconds of frames, whatever the duration
