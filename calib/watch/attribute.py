"""Which camera moved, when a camera's test alarms (issue 36; decision 0077d).

A camera's residuals are measured against markers the other cameras triangulate, so a camera that
moved pulls the markers it shares, and every camera that sees them shows part of its move. With many
cameras a marker's other views outweigh the moved one and the pull is small; with few (one LED seen
by four cameras, MultiCamSelfCal) a pulled camera whose own pose wanders little may pass the
threshold before the moved one, whose statistic is scaled by a larger wander of its own
(bench_watch_real: Basler_21275577 turned 0.3 deg, Basler_21283677 named at 77.9 while the turn alone
scored 21 on its own camera).

The hypotheses "camera h moved" are compared by what each leaves unexplained: if h moved, the markers
triangulated without h are where they were, and no other camera's test, measured against them, shows
a change; if another moved, it still pulls them and still shows its own move. For each candidate h
(every camera not named already: the moved one's own statistic may be far below the floor a
statistic is looked at from, 14.5 on a simulated one-marker take) the other cameras' tests
are measured again over the frames the test looks back on (:data:`RECENT_BATCHES` batches) with h
left out of their markers, and the sum of their largest statistics is h's score: the camera whose
leaving-out leaves the least is named. The alarming camera is tried first: when, left out, it leaves
every other camera's largest statistic under :data:`~wandcal.calib.watch.sequential.PEAK_FLOOR`
(chi2_6's tail 3e-3: no sign of a change left to explain) it is named without trying the others
(with twelve cameras their tries cost twice the take's own watch). Each hypothesis frees the same six parameters (h's pose), so
the scores are compared as they are, at even odds, as the chi-square evidence against "nothing else
moved" that each leaves.
"""

from __future__ import annotations

import copy

import numpy as np

from wandcal.calib.rig import Rig
from wandcal.calib.watch.health import WINDOW_FRAMES, camera_windows
from wandcal.calib.watch.match import Tracks
from wandcal.calib.watch.sequential import BASELINE_WINDOWS, GLR_WINDOWS, PEAK_FLOOR, CameraTest
from wandcal.calib.watch.take import PaddedFrames

Batch = tuple[PaddedFrames, Tracks]
MIN_LEFT = 3  # cameras left when a candidate is left out: each then tests against markers two others place


def which_moved(rig: Rig, R: np.ndarray, t: np.ndarray, recent: list[Batch], tests: list[CameraTest],
                excluded: set[int], *, first: int, alarmed: int, detected: int) -> int:
    """The camera named moved when ``alarmed``'s test alarmed at the window ending ``detected`` (a frame):
    ``alarmed`` or another candidate (the module's note). recent: the batches (padding, tracks) the
    tests' last :data:`~wandcal.calib.watch.sequential.GLR_WINDOWS` windows came from, the alarm's
    last; tests: every camera's, holding the windows up to the alarm's (each non-alarmed one's
    :meth:`~CameraTest.glr` taken there); excluded: cameras left out of the markers already; first:
    the take's first frame (windows count from it)."""
    candidates = [alarmed] + [c for c, test in enumerate(tests) if c != alarmed and c not in excluded and test.alarm is None]
    if len(candidates) < 2 or not recent or len(tests) - len(excluded) - 1 < MIN_LEFT:
        return alarmed
    own = _unexplained(rig, R, t, recent, tests, excluded | {alarmed}, first, detected)
    if max(own, default=0.0) <= PEAK_FLOOR:  # left out, it leaves no other camera a sign of a change: it moved
        return alarmed
    scores = [sum(own)] + [sum(_unexplained(rig, R, t, recent, tests, excluded | {h}, first, detected))
                           for h in candidates[1:]]
    return candidates[int(np.argmin(scores))]


def _unexplained(rig: Rig, R, t, recent: list[Batch], tests: list[CameraTest], left_out: set[int], first: int,
                 detected: int) -> list[float]:
    """The largest statistics of the tests of the cameras not ``left_out``, their windows
    after the baseline from the first of ``recent`` to the one ending ``detected`` measured again with
    ``left_out`` out of their markers (the tests themselves are not changed)."""
    copies = {c: _clone(test) for c, test in enumerate(tests) if c not in left_out}
    remeasure(rig, R, t, recent, copies, left_out, first=first, until=detected)
    raws = []
    for test in copies.values():
        test.glr()
        raws.append(test.raw)
    return raws


def remeasure(rig: Rig, R, t, batches: list[Batch], tests: dict[int, CameraTest], left_out: set[int], *, first: int,
              until: int | None = None) -> None:
    """Measure the windows of ``batches`` (the tests' last ones, in order) again with ``left_out`` out of
    the markers, in the ``tests`` given (camera: its test), up to the window starting at ``until`` (a
    frame; all by default). The baseline's windows are kept: nothing had moved in them."""
    if not batches or not tests:
        return
    span = int(batches[0][0].frames[0])
    cut: dict[int, float] = {}  # each test's first window measured again (inf: none)
    for c, test in tests.items():
        k = max(int(np.searchsorted(np.array(test.start), span)), BASELINE_WINDOWS)
        cut[c] = test.start[k] if k < len(test.start) else np.inf
        test.rewind(k)
    for padded, tracks in batches:
        views = tracks.views.copy()
        views[:, sorted(left_out)] = -1
        w = camera_windows(rig, R, t, padded, Tracks(tracks.frame, views, tracks.X))
        w_of = (w.frames - first) // WINDOW_FRAMES
        for win in np.unique(w_of):
            start = first + int(win) * WINDOW_FRAMES
            if until is not None and start > until:
                return
            sel = w_of == win
            for c, test in tests.items():
                if start >= cut[c]:
                    test.add(w.g[sel, c].sum(0), w.H[sel, c].sum(0), float(w.sse[sel, c].sum()),
                             float(w.n[sel, c].sum()), start)


def _clone(test: CameraTest) -> CameraTest:
    """A copy of a test whose windows can be rewound and added to without changing ``test``."""
    out = copy.copy(test)
    out.g, out.H, out.sse, out.n, out.start = list(test.g), list(test.H), list(test.sse), list(test.n), list(test.start)
    return out


RECENT_BATCHES_OF = GLR_WINDOWS * WINDOW_FRAMES  # frames the test looks back on: the batches kept cover them
