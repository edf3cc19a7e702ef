"""Live wanding guidance: the wand pairs a capture records, and the guidance recomputed from them
in a background thread every :data:`UPDATE_INTERVAL_S`, each solve starting from the last.

The capture loop only appends (a lock held for microseconds), so detection never waits for a
solve; readers (the HTTP API, the command line's status line) take the latest document.
"""

from __future__ import annotations

import multiprocessing
import signal
import threading
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from wandcal.calib.rig import Rig, StaticObservations, WandObservations
from wandcal.calib.run.guidance import GuidanceSettings, Solution, wanding_guidance

# The issue asks for an update every second or two. One update costs 0.05-0.35 s (docs/benchmarks.md,
# "Guidance"), so once a second leaves the capture loop most of the time.
UPDATE_INTERVAL_S = 1.0
_INITIAL_ROWS = 4096  # the buffer's first size, in blob rows; it doubles as needed
# Ctrl-C and a closed terminal signal the whole foreground process group, the solver process too:
# it ignores them, so only the capture decides how to stop (a killed solver would end the capture's
# guidance with BrokenProcessPool)
_CAPTURE_SIGNALS = frozenset({signal.SIGINT, signal.SIGHUP})


def _ignore_capture_signals() -> None:
    """The solver process's initializer: Ctrl-C and hang-up are the capture's to handle."""
    for signum in _CAPTURE_SIGNALS:
        signal.signal(signum, signal.SIG_IGN)



class LiveGuidance:
    """Collects wand pairs and keeps the guidance up to date.

    Args:
        rig: the capture's rig (with the wand length).
        settings: target and coverage goal (:class:`wandcal.calib.run.guidance.GuidanceSettings`; None: the defaults).
        interval_s: the least time between two updates of the background thread.
        on_update: called with each new document (from the background thread).
        process: solve in a child process (spawned at :meth:`start`), so the solve's Python work
            does not compete for the GIL with the capture loop's reader threads; False solves in
            the background thread itself.

    Use as a context manager (or :meth:`start` / :meth:`close`); :meth:`update` computes at once.
    """

    def __init__(self, rig: Rig, settings: GuidanceSettings | None = None,
                 interval_s: float = UPDATE_INTERVAL_S, on_update: Callable[[dict], None] | None = None,
                 process: bool = True):
        self.rig = rig
        self.process = process
        self._pool: ProcessPoolExecutor | None = None
        self.settings = settings or GuidanceSettings()
        self.interval_s = interval_s
        self.on_update = on_update
        self._lock = threading.Lock()
        self._frame = np.zeros(_INITIAL_ROWS, dtype=np.int64)
        self._camera = np.zeros(_INITIAL_ROWS, dtype=np.int64)
        self._uv = np.zeros((_INITIAL_ROWS, 2))
        self._rows = 0
        self._static: StaticObservations | None = None
        self._version = 0
        self._solved_version = -1
        self._solution: Solution | None = None
        self._update_lock = threading.Lock()
        self._document = self._stamp(wanding_guidance(rig, self._observations(), None, self.settings).document,
                                     time.time())
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # -- the capture side ----------------------------------------------------------------------
    def add_pair(self, frame: int, camera: int, uv: np.ndarray) -> None:
        """The two wand blobs (2, 2) camera ``camera`` saw in wand set ``frame``."""
        with self._lock:
            if self._rows + 2 > len(self._frame):
                self._grow()
            k = self._rows
            self._frame[k:k + 2] = frame
            self._camera[k:k + 2] = camera
            self._uv[k:k + 2] = uv
            self._rows += 2
            self._version += 1

    def set_static(self, static: StaticObservations) -> None:
        """The static object's blobs, for the first solve's start."""
        with self._lock:
            self._static = static
            self._version += 1

    def _grow(self) -> None:
        size = 2 * len(self._frame)
        self._frame = np.resize(self._frame, size)
        self._camera = np.resize(self._camera, size)
        self._uv = np.resize(self._uv, (size, 2))

    def _observations(self) -> WandObservations:
        return WandObservations(self._frame[:self._rows].copy(), self._camera[:self._rows].copy(),
                                self._uv[:self._rows].copy())

    # -- the reader side -----------------------------------------------------------------------
    def latest(self) -> dict:
        """The latest guidance document (``wandcal-guidance/1`` with ``updated``, Unix seconds)."""
        with self._lock:
            return self._document

    @property
    def enough(self) -> bool:
        return bool(self.latest()["enough"])

    def update(self) -> dict:
        """Recompute from everything recorded so far (the background thread calls this)."""
        with self._update_lock:  # one solve at a time; a second caller gets the fresh result
            with self._lock:
                version, wand, static, start = self._version, self._observations(), self._static, self._solution
                if version == self._solved_version:
                    return self._document
            if self._pool is not None:
                # the first submit spawns the process, which inherits this thread's signal mask
                # until its initializer ignores them: blocked here, a Ctrl-C then cannot kill it
                blocked = signal.pthread_sigmask(signal.SIG_BLOCK, _CAPTURE_SIGNALS)
                try:
                    future = self._pool.submit(wanding_guidance, self.rig, wand, static, self.settings, start)
                finally:
                    signal.pthread_sigmask(signal.SIG_SETMASK, blocked)
                guidance = future.result()
            else:
                guidance = wanding_guidance(self.rig, wand, static, self.settings, start)
            document = self._stamp(guidance.document, time.time())
            with self._lock:
                self._document = document
                self._solution = guidance.solution or self._solution
                self._solved_version = version
        if self.on_update is not None:
            self.on_update(document)
        return document

    @staticmethod
    def _stamp(document: dict, when: float) -> dict:
        return document | {"updated": when}

    # -- the background thread -----------------------------------------------------------------
    def start(self) -> LiveGuidance:
        if self._thread is None:
            if self.process:
                # spawn: a fork would copy the capture's reader threads' locks in whatever state they are
                self._pool = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"),
                                                 initializer=_ignore_capture_signals)
            self._thread = threading.Thread(target=self._run, name="wandcal-guidance", daemon=True)
            self._thread.start()
        return self

    def _run(self) -> None:
        while not self._stop.wait(self.interval_s):
            with self._lock:
                fresh = self._version != self._solved_version
            if not fresh:
                continue
            try:
                self.update()
            except Exception as exc:  # a bug must not end the guidance of a capture that goes on
                with self._lock:
                    solve = self._document["solve"] | {"ok": False, "message": f"the guidance update failed "
                                                       f"({type(exc).__name__}: {exc}); this is a bug"}
                    self._document = self._document | {"solve": solve, "enough": False}

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def __enter__(self) -> LiveGuidance:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()
