"""Guidance for stored captures (uploaded, replayed, streamed or finished live ones).

Computed on request and kept per capture with the solution that starts the next update. A
capture that changes (frame sets streaming in) is recomputed at most once per
``update_interval_s``; within that time a request gets the last document at once, so polling
never queues solves behind each other. One solve per capture runs at a time; other captures and
the rest of the API go on meanwhile (the route runs in the thread pool).
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict
from dataclasses import dataclass, replace

from wandcal.calib.run.guidance import GuidanceSettings, Solution, wanding_guidance
from wandcal.service.settings import GuidanceConfig
from wandcal.service.storage import CaptureStore

KEPT_CAPTURES = 64  # the captures whose guidance is cached; a lab looks at a handful at a time


def guidance_settings(config: GuidanceConfig) -> GuidanceSettings:
    return GuidanceSettings(target_std_mm=config.target_std_mm, min_coverage=config.min_coverage,
                            frames_per_camera=config.frames_per_camera)


@dataclass(eq=False)
class _Entry:
    lock: threading.Lock
    key: tuple | None = None
    document: dict | None = None
    solution: Solution | None = None
    when: float = 0.0


class GuidanceBoard:
    """The guidance of stored captures, cached per capture."""

    def __init__(self, store: CaptureStore, config: GuidanceConfig, clock=time.monotonic):
        self.store = store
        self.config = config
        self.settings = guidance_settings(config)
        self.clock = clock
        self._entries: OrderedDict[tuple[str, str], _Entry] = OrderedDict()  # by (capture, sync mode)
        self._lock = threading.Lock()

    def _entry(self, key: tuple[str, str]) -> _Entry:
        with self._lock:
            entry = self._entries.pop(key, None) or _Entry(threading.Lock())
            self._entries[key] = entry
            while len(self._entries) > KEPT_CAPTURES:
                self._entries.popitem(last=False)
            return entry

    def get(self, capture_id: str, sync: str = "none") -> dict:
        """The capture's guidance document (``sync`` as calibrate's: "auto" for cameras without a
        trigger). Raises CaptureNotFound, or CalibrationError for a capture the guidance cannot
        judge (no wand, and no points on a rig without one)."""
        row = self.store.get(capture_id)
        key = (row.frames, row.framesets, row.has_static, tuple(sorted((c, v["pairs"]) for c, v in row.counts.items())))
        entry = self._entry((capture_id, sync))
        with entry.lock:
            if entry.document is not None and (entry.key == key or
                                               self.clock() - entry.when < self.config.update_interval_s):
                return entry.document
            capture = self.store.load(capture_id)
            points = capture.points if capture.rig.wand_length is None else None  # a points-only rig's guidance
            guidance = wanding_guidance(capture.rig, capture.wand, capture.static, replace(self.settings, sync=sync),
                                        entry.solution, points=points)
            entry.key, entry.when = key, self.clock()
            entry.document = guidance.document | {"updated": time.time(), "live": False}
            entry.solution = guidance.solution or entry.solution
            return entry.document
