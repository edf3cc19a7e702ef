"""Bounded-memory image writing: a queue of at most ``max_queued`` images and writer threads.

``cv2.imwrite`` releases the GIL while it compresses, so threads spread PNG encoding over the
cores. When the disk cannot keep up, :meth:`ImageWriter.put` blocks; the capture loop then
stops taking frames from the cameras, and the cameras' own buffers absorb (or drop) the
excess instead of this process's memory growing.
"""

from __future__ import annotations

import os
import queue
import threading
from pathlib import Path

import cv2
import numpy as np

from wandcal.drivers.errors import DriverError

# Sensor noise makes the dark background incompressible by prediction, so PNG row filters only
# cost time: zlib level 1, Huffman coding only and no filter gave the smallest and fastest files
# on simulated 1280x1024 IR frames (read noise 2 grey levels): ~16 ms and ~0.5 MB per frame
# against ~30 ms and 0.67 MB with OpenCV's defaults (bench/bench_capture.py).
PNG_PARAMS = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY,
              cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_NONE]


class ImageWriter:
    """Writes ``(path, image)`` pairs on ``threads`` threads from a bounded queue.

    Attributes:
        high_water: the most images that were ever waiting at once (never above ``max_queued``).
        written: images written so far.
    """

    def __init__(self, max_queued: int, threads: int | None = None):
        if max_queued < 1:
            raise ValueError("max_queued must be at least 1")
        self.max_queued = max_queued
        self._queue: queue.Queue = queue.Queue(maxsize=max_queued)
        self.high_water = 0
        self.written = 0
        self._lock = threading.Lock()
        self._error: DriverError | None = None
        self._threads = [threading.Thread(target=self._run, name=f"png-writer-{i}", daemon=True)
                         for i in range(threads or os.cpu_count() or 1)]
        for t in self._threads:
            t.start()

    def put(self, path: Path, image: np.ndarray) -> None:
        """Queue one image; blocks while ``max_queued`` images wait. Raises a pending write error."""
        if self._error is not None:
            raise self._error
        self._queue.put((Path(path), image))
        with self._lock:
            self.high_water = max(self.high_water, self._queue.qsize())

    def close(self) -> None:
        """Write everything queued, stop the threads; raises the first write error."""
        for _ in self._threads:
            self._queue.put(None)
        for t in self._threads:
            t.join()
        if self._error is not None:
            raise self._error

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            path, image = item
            try:
                path.parent.mkdir(parents=True, exist_ok=True)
                if not cv2.imwrite(str(path), image, PNG_PARAMS):
                    raise OSError("cv2.imwrite returned False")
            except OSError as exc:
                with self._lock:
                    if self._error is None:
                        self._error = DriverError(f"cannot write {path} ({exc}); check free disk space and "
                                                  "permissions of the output folder")
                continue
            with self._lock:
                self.written += 1
