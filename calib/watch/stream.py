"""A take watched with a standing calibration as it streams in: batches of frames matched, each camera's
health window by window, the start check, the sequential test and who moved, and a moved camera's re-solve
(issue 36); :func:`watch_take` feeds a whole take. What it reports: :mod:`wandcal.calib.watch.report`."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from wandcal.calib.geometry import sum_by
from wandcal.calib.rig import Rig
from wandcal.calib.watch.attribute import Attribution, attribute
from wandcal.calib.watch.health import (
    PARAMS,
    WINDOW_FRAMES,
    CameraWindows,
    camera_windows,
    solve_pose_change,
)
from wandcal.calib.watch.lost import LOST_THRESHOLD, FoundTest
from wandcal.calib.watch.match import Tracks, match_frames
from wandcal.calib.watch.recover import SETTLE_FRAMES, Resolved, resolve_moved, wander_share
from wandcal.calib.watch.report import ONE_OF_ADVICE, CameraHealth, WatchReport, numbered
from wandcal.calib.watch.sequential import (
    BASELINE_WINDOWS,
    GLR_THRESHOLD,
    GLR_WINDOWS,
    PEAK_FLOOR,
    Alarm,
    CameraTest,
    classify,
)
from wandcal.calib.watch.take import PaddedFrames, TakeBlobs, pad_frames

BATCH_FRAMES = 100  # a second at 100 fps: the unit a live take is processed in (whole windows)
# A camera whose images are this far (rms) from the standing pose over the take's first windows moved
# before the take: a standing result's own pose error moves them ~0.1 px; a 0.05 deg turn at f = 1100 px, 1 px
START_SHIFT_PX = 1.0
# and is tested only on this many degrees of freedom about the windows' fits (a 40-marker take's first window
# holds ~800): a sparse take's first windows (one marker a frame in three cameras) may hold a handful
MIN_START_DOF = 60
# cameras weighed as the one that moved when several tests are raised: the alarming one and the others with the
# largest statistics. Each costs a pass over the move's windows (every camera's residuals); with 12 cameras and
# 40 markers a knock raises all of them (each is pulled), and twelve passes cost ~5 s CPU once. A camera whose
# test is not among the four most raised is taken not to be the mover (every camera of a 4-camera rig is weighed)
MAX_CANDIDATES = 4


def watch_take(rig: Rig, R: np.ndarray, t: np.ndarray, blobs: TakeBlobs, *, resolve: bool = True,
               progress: Callable[[int, int], None] | None = None) -> WatchReport:
    """Watch a take (blobs sorted by frame) at standing poses R (C, 3, 3), t (C, 3): each camera's
    health, the moved ones named (when, how much, knock or drift) and, with ``resolve``, re-solved."""
    numbers, rank = np.unique(blobs.frame, return_inverse=True)
    ranked = TakeBlobs(rank.astype(np.int64), blobs.camera, blobs.uv)  # windows of frames held, not frame numbers
    last = len(numbers) - 1
    stream = WatchStream(rig, R, t, 0, keep_obs=False)
    stream.begin(ranked, np.arange(0, int(np.searchsorted(ranked.frame, stream.baseline_stop))))
    bounds = np.searchsorted(ranked.frame, np.arange(0, last + BATCH_FRAMES + 1, BATCH_FRAMES))
    for b in range(len(bounds) - 1):
        if bounds[b] == bounds[b + 1]:
            continue
        done = stream.add(ranked, np.arange(bounds[b], bounds[b + 1]))
        if progress:
            progress(done + 1, last + 1)
    stream.close()
    report = stream.report(last)
    if resolve:
        _resolve(rig, R, t, ranked, report, stream.tests)
    return numbered(report, numbers)


class WatchStream:
    """A take watched a batch of :data:`BATCH_FRAMES` frames at a time, as it arrives (a live take;
    :func:`watch_take` feeds a whole one): :meth:`begin` with the first :data:`BASELINE_WINDOWS`
    windows' blobs (cameras off the standing result from the start), then :meth:`add` each batch
    in frame order; :meth:`report` any time. ``first``: the take's first frame (windows count from it)."""

    def __init__(self, rig: Rig, R: np.ndarray, t: np.ndarray, first: int, *, keep_obs: bool = True):
        self.rig, self.R, self.t, self.first, self.keep_obs = rig, R, t, first, keep_obs
        self.tests = [CameraTest() for _ in rig.cameras]
        self.found = [FoundTest() for _ in rig.cameras]
        self.before_take: set[int] = set()
        self.excluded: set[int] = set()
        self.sums = np.zeros((len(rig.cameras), 3))  # sse, residuals, markers seen
        self.frames = self.tracks = 0
        self.obs: list[list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = []
        self.recent: list[tuple[PaddedFrames, Tracks]] = []  # the batches a change's start may lie in (attribution)
        self.pending: list[_Group] = []  # "one of" moves awaiting the attribution's second look
        self._head: _Head | None = None  # what begin matched and measured, for the batches of the same frames

    @property
    def baseline_stop(self) -> int:
        """The first frame past the windows :meth:`begin` needs."""
        return self.first + BASELINE_WINDOWS * WINDOW_FRAMES

    def begin(self, blobs: TakeBlobs, rows: np.ndarray) -> None:
        """Name the cameras that disagree with the standing result from the take's start (``rows``:
        the blobs of the frames before :attr:`baseline_stop`)."""
        if not len(rows):
            return
        padded = pad_frames(self.rig, blobs, rows)
        tracks = match_frames(self.rig, self.R, self.t, padded)
        alarms, windows = _off_from_start(self.rig, self.R, self.t, padded, tracks, self.first, keep_obs=self.keep_obs)
        for alarm in alarms:
            self.tests[alarm.camera].alarm = alarm
            self.before_take.add(alarm.camera)
            self.excluded.add(alarm.camera)
        self._head = _Head(blobs.frame[rows], blobs.camera[rows], blobs.uv[rows], padded, tracks, windows,
                           frozenset(self.excluded))

    def add(self, blobs: TakeBlobs, rows: np.ndarray) -> int:
        """Match one batch (``rows`` of ``blobs``: whole windows, later than any added) and add its
        windows to every camera's test. Returns its last frame."""
        again = None if self._head is None else self._head.part(blobs, rows, self.excluded)
        if again is None:
            padded = pad_frames(self.rig, blobs, rows)
            tracks, windows = match_frames(self.rig, self.R, self.t, padded), None
        else:
            padded, tracks, windows = again
        self.frames += len(padded.frames)
        self.tracks += len(tracks)
        windows = _test_batch(self.rig, self.R, self.t, padded, tracks, (self.tests, self.found), self.excluded,
                              self.first, keep_obs=self.keep_obs, windows=windows, earlier=self.recent,
                              pending=self.pending)
        self.recent.append((padded, tracks))
        last = int(padded.frames[-1])
        self._second_looks(lambda group: (last - self.first) // WINDOW_FRAMES + 1 >= group.w0 + GLR_WINDOWS)
        oldest = min([last - (GLR_WINDOWS + 1) * WINDOW_FRAMES]  # no change starts before it, nor a pending move
                     + [self.first + g.w0 * WINDOW_FRAMES for g in self.pending])
        self.recent = [piece for piece in self.recent if piece[0].frames[-1] >= oldest]
        self.sums += np.stack([windows.sse.sum(0), windows.n.sum(0), windows.seen.sum(0)], 1)
        if self.keep_obs:
            self.obs.append(windows.obs or [])
        return int(padded.frames[-1])

    def close(self) -> None:
        """The take has ended: the attribution's second look at every "one of" move still pending."""
        self._second_looks(lambda group: True)

    def _second_looks(self, due: Callable[[_Group], bool]) -> None:
        """The attribution's second look (:mod:`wandcal.calib.watch.attribute`) at each pending "one of" move
        that is ``due``, over every window from its start that the stream holds: a camera named becomes the
        move, the others go back to being watched (in their markers, tested from the next window on)."""
        if not self.recent:
            return
        stop = (int(self.recent[-1][0].frames[-1]) - self.first) // WINDOW_FRAMES + 1
        for group in [g for g in self.pending if due(g)]:
            self.pending.remove(group)
            tests = self.tests
            out = attribute(self.rig, self.R, self.t, self.recent, set(group.excluded), list(group.cams), _baselines(tests),
                            (self.first, group.w0, min(stop, group.w0 + GLR_WINDOWS)))
            if len(out.named) > 1:
                continue
            for m in group.cams:
                alarm = tests[m].alarm
                assert alarm is not None
                if m == out.named[0]:
                    tests[m].alarm = replace(alarm, one_of=(), change=out.changes.get(m, alarm.change), settled=True)
                else:
                    tests[m].alarm, tests[m].since = None, len(tests[m].g)
                    self.excluded.discard(m)

    def report(self, last: int) -> WatchReport:
        """Every camera's health so far (``last``: the last frame seen)."""
        report = WatchReport([CameraHealth(cam.id) for cam in self.rig.cameras], frames=self.frames,
                             tracks=self.tracks, first_frame=self.first, last_frame=last, obs=self.obs)
        sums = self.sums
        for c, health in enumerate(report.cameras):
            health.before_take = c in self.before_take
            health.residual_px = float(np.sqrt(sums[c, 0] / max(2 * sums[c, 1], 1)))
            health.matched = float(sums[c, 1] / max(sums[c, 2], 1))
            health.alarm = self.tests[c].alarm
            health.peak = self.tests[c].peak
            health.detectable_turn_deg = self.tests[c].smallest_turn_deg()
            health.test = self.tests[c]
            alarm = health.alarm
            if alarm is not None and health.before_take:
                health.kind, health.moved_at, health.change = "knock", self.first, alarm.change
            elif alarm is not None and health.lost:
                health.kind, health.moved_at, health.change = "knock", alarm.frame, alarm.change
            elif alarm is not None:
                health.kind, health.moved_at, health.drift_frames, health.change = classify(self.tests[c], alarm)
            if alarm is not None and alarm.settled and health.kind == "knock":
                health.moved_at = alarm.frame  # its test lost the group's markers from the alarm on (Alarm.settled)
            if alarm is not None and alarm.one_of:
                health.one_of = [self.rig.cameras[m].id for m in alarm.one_of]
                health.moved_at, health.drift_frames = alarm.frame, 0  # the move they share: the alarm's start
        return report


@dataclass(frozen=True)
class _Group:
    """A "one of" move awaiting the attribution's second look: its candidates (camera indices), its
    start's window number w0 (from the take's first frame), the cameras left out of the markers before it."""

    cams: tuple[int, ...]
    w0: int
    excluded: frozenset[int]


def _baselines(tests: list[CameraTest]) -> tuple[np.ndarray, np.ndarray]:
    """Every camera's baseline: p_0 (C, 6), its reference pose change, and s^2 (C,) px^2, its residual
    variance (zeros and 1 before its baseline is in)."""
    bases = [test.baseline() for test in tests]
    return (np.array([np.zeros(PARAMS) if b is None else b[0] for b in bases]),
            np.array([1.0 if b is None else b[2] for b in bases]))


@dataclass(frozen=True, eq=False)
class _Head:
    """What :meth:`WatchStream.begin` matched and measured of the take's first frames, for the
    batches that hold the same frames again: its blobs (frame, camera, uv of its rows), their
    padding and tracks, and the windows measured with ``excluded`` left out (None if none were)."""

    frame: np.ndarray
    camera: np.ndarray
    uv: np.ndarray
    padded: PaddedFrames
    tracks: Tracks
    windows: CameraWindows | None
    excluded: frozenset[int]

    def part(self, blobs: TakeBlobs, rows: np.ndarray,
             excluded: set[int]) -> tuple[PaddedFrames, Tracks, CameraWindows | None] | None:
        """(padding, tracks, windows or None) of a batch (``rows`` of ``blobs``) whose blobs are exactly
        the head's of the same frames; None for any other batch. The windows only where the batch
        starts a window of the head's (they are fitted window by window) and leaves out the same cameras."""
        frame = blobs.frame[rows]
        if not len(frame):
            return None
        lo, hi = frame.min(), frame.max()
        sel = (self.frame >= lo) & (self.frame <= hi)
        if not (np.array_equal(self.frame[sel], frame) and np.array_equal(self.camera[sel], blobs.camera[rows])
                and np.array_equal(self.uv[sel], blobs.uv[rows])):
            return None
        keep = (self.padded.frames >= lo) & (self.padded.frames <= hi)
        padded = PaddedFrames(self.padded.frames[keep], self.padded.xy[keep], self.padded.row[keep])
        mine = (self.tracks.frame >= lo) & (self.tracks.frame <= hi)
        tracks = Tracks(self.tracks.frame[mine], self.tracks.views[mine], self.tracks.X[mine])
        w = self.windows
        if w is None or self.excluded != excluded or np.argmax(keep) % WINDOW_FRAMES:
            return padded, tracks, None
        obs = None if w.obs is None else [(f[(f >= lo) & (f <= hi)], X[(f >= lo) & (f <= hi)], xy[(f >= lo) & (f <= hi)])
                                          for f, X, xy in w.obs]
        return padded, tracks, CameraWindows(w.frames[keep], w.g[keep], w.H[keep], w.n[keep], w.seen[keep],
                                             w.sse[keep], obs)


def _off_from_start(rig: Rig, R, t, padded: PaddedFrames, tracks: Tracks, first: int, *,
                    keep_obs: bool = False) -> tuple[list[Alarm], CameraWindows | None]:
    """Cameras that disagree with the standing result from the take's start (``padded``, ``tracks``:
    its first frames and their markers): over the first :data:`BASELINE_WINDOWS` windows, a pose
    change whose statistic passes the test's threshold and that moves the camera's images
    :data:`START_SHIFT_PX` or more. Named one at a time, the largest first, each left out of the
    others' markers before the next is looked for (its blobs pull them). Returns them, and the windows
    measured with all of them left out (None if the last were measured with fewer)."""
    alarms: list[Alarm] = []
    w = None
    while len(alarms) < len(R) - 3:  # three cameras held at least: a marker is two views and a third
        views = tracks.views.copy()
        views[:, [a.camera for a in alarms]] = -1
        w = camera_windows(rig, R, t, padded, Tracks(tracks.frame, views, tracks.X), keep_obs=keep_obs)
        I0, g0, n0 = w.H.sum(0), w.g.sum(0), w.n.sum(0)
        p0 = solve_pose_change(I0, g0)
        fit = np.einsum("ci,cij,cj->c", p0, I0, p0)  # px^2 the change explains
        dof = _fit_dof(w.n)
        s2 = w.sse.sum(0) / np.maximum(dof, 1)
        S = np.where(dof >= MIN_START_DOF, fit / np.maximum(s2, 1e-12), 0.0)  # too few residuals say nothing
        shift = np.sqrt(fit / np.maximum(n0, 1))
        S[[a.camera for a in alarms]] = 0
        c = int(np.argmax(np.where(shift >= START_SHIFT_PX, S, 0)))
        if S[c] <= GLR_THRESHOLD or shift[c] < START_SHIFT_PX:
            return alarms, w
        alarms.append(Alarm(c, first, int(padded.frames[-1]), float(S[c]), p0[c]))
    return alarms, None


def _fit_dof(n: np.ndarray) -> np.ndarray:
    """(C,) degrees of freedom left about each window's pose fit, of residuals n (F, C) a frame: each
    window's 2 n scalars less the :data:`PARAMS` its fit takes (all of them, when fewer)."""
    per_window = sum_by(np.arange(len(n)) // WINDOW_FRAMES, n, (len(n) - 1) // WINDOW_FRAMES + 1)
    return np.maximum(2 * per_window - PARAMS, 0).sum(0)


def _test_batch(rig, R, t, padded, tracks: Tracks, tests: tuple[list[CameraTest], list[FoundTest]], excluded: set[int],
                first: int, keep_obs: bool, windows: CameraWindows | None = None,
                earlier: list[tuple[PaddedFrames, Tracks]] | None = None, pending: list[_Group] | None = None) -> CameraWindows:
    """Add a batch's windows to every camera's test, window by window; when cameras alarm, the one
    that moved is named (:func:`_add_windows`; or the ones the take cannot tell apart), left out of
    every other camera's markers, and the batch is tested again without it (a moved camera's blobs
    pull the markers it shares). A camera's pose and found-share tests take each window together, so
    one mark rewinds both. ``windows``: the batch's, if measured already with ``excluded`` left out;
    ``earlier``: the batches before it that a change's start may lie in (padded frames, tracks);
    ``pending``: where a "one of" move is put for the attribution's second look."""
    pieces = [*(earlier or []), (padded, tracks)]

    def judge(candidates: list[int], span: tuple[int, int, int]) -> Attribution:
        out = attribute(rig, R, t, pieces, excluded, candidates, _baselines(tests[0]), span)
        if len(out.named) > 1 and pending is not None:
            pending.append(_Group(out.named, span[1], frozenset(excluded)))
        return out

    blobs = np.isfinite(padded.xy[:, :, :, 0]).sum(2)  # each camera's blobs a frame, whoever is left out
    while True:
        if windows is None:
            views = tracks.views.copy()
            views[:, sorted(excluded)] = -1
            windows = camera_windows(rig, R, t, padded, Tracks(tracks.frame, views, tracks.X), keep_obs=keep_obs)
        marks = [pose.mark() for pose in tests[0]]
        named = _add_windows(windows, blobs, tests, first, judge)
        if not named:
            return windows
        excluded.update(named)
        windows = None
        for c, (pose, found) in enumerate(zip(*tests)):  # the named one too: it keeps its alarm, and the batch's
            pose.rewind(marks[c])                          # windows come again (once, not twice: classify reads them)
            found.rewind(marks[c])


def _add_windows(windows: CameraWindows, blobs: np.ndarray, tests: tuple[list[CameraTest], list[FoundTest]],
                 first: int, judge: Callable[[list[int], tuple[int, int, int]], Attribution]) -> list[int]:
    """Add each window in turn; at the first window where cameras alarm, name the one that moved (or
    the ones the take cannot tell apart) and return them (the others' tests are then run again by the
    caller); none when none alarms. A camera whose blobs left its markers
    (:mod:`wandcal.calib.watch.lost`) goes first: its pose test has lost its residuals. Else
    :func:`_pose_alarm`. ``blobs`` (F, C): each camera's blobs a frame; ``judge``: the attribution of
    a move among candidates (:func:`wandcal.calib.watch.attribute.attribute` over the take's windows)."""
    poses, founds = tests
    w_of = (windows.frames - first) // WINDOW_FRAMES
    for w in np.unique(w_of):
        sel = w_of == w
        tested, lost = [], []
        for c, (test, found) in enumerate(zip(poses, founds)):
            start = first + int(w) * WINDOW_FRAMES
            test.add(windows.g[sel, c].sum(0), windows.H[sel, c].sum(0), float(windows.sse[sel, c].sum()),
                     float(windows.n[sel, c].sum()), start)
            found.add(float(windows.n[sel, c].sum()), float(windows.seen[sel, c].sum()), float(blobs[sel, c].sum()), start)
            if test.alarm is None:
                S, k, d = test.glr()
                tested.append((S, test.raw, c, k, d))
                S_lost, frame = found.glr()
                if S_lost > LOST_THRESHOLD:
                    lost.append((S_lost, S_lost, c, frame, np.full(PARAMS, np.nan)))
        detected = int(windows.frames[sel].max())
        if lost:
            _, raw, c, frame, d = max(lost, key=lambda x: x[1])  # a lost camera's frame is its frame already
            poses[c].alarm = Alarm(c, frame, detected, raw, d)
            return [c]
        if any(S > GLR_THRESHOLD for S, *_ in tested):
            span = (first, 0, int(w_of.max()) + 1)
            return _pose_alarm(poses, tested, detected, span, judge)
    return []


def _pose_alarm(poses: list[CameraTest], tested: list[tuple[float, float, int, int, np.ndarray]], detected: int,
                span: tuple[int, int, int], judge) -> list[int]:
    """The cameras named when pose tests alarm (``tested``: each untested-yet camera's (S, raw S, camera,
    k, d_k) at window ending at frame ``detected``): the alarming one is the one with the largest
    statistic, persistent or not (a moved camera's blobs pull the markers another is tested against,
    and the other's change may persist first). Alone when no other camera's largest statistic is past
    :data:`PEAK_FLOOR`; else it and those raised (the :data:`MAX_CANDIDATES` largest) are the candidates, and
    :func:`~wandcal.calib.watch.attribute.attribute` names the one that moved over the windows from the
    alarm's start k to ``span``'s end, or the ones it cannot tell apart (each given the alarm, with the
    others as ``one_of``)."""
    _, raw, c, k, d = max(tested, key=lambda x: x[1])
    frame = poses[c].start[k]
    top = sorted(((r, m) for _, r, m, _, _ in tested if m != c and r > PEAK_FLOOR), reverse=True)[:MAX_CANDIDATES - 1]
    raised = {c: raw} | {m: r for r, m in top}
    if len(raised) == 1:
        poses[c].alarm = Alarm(c, frame, detected, raw, d)
        return [c]
    first, _, stop = span
    out = judge(list(raised), (first, (frame - first) // WINDOW_FRAMES, stop))
    for m in out.named:
        poses[m].alarm = Alarm(m, frame, detected, raised[m], out.changes[m], tuple(x for x in out.named if x != m))
    return list(out.named)


def _resolve(rig: Rig, R, t, blobs: TakeBlobs, report: WatchReport, tests: list[CameraTest]) -> None:
    """Every moved camera re-solved from the frames after its move completed and settled (``blobs``:
    the take by frame rank, as ``report``), with its pose's wander from its test's baseline; or why not."""
    moved = [c for c, h in enumerate(report.cameras) if h.alarm is not None]
    for c in moved:
        health = report.cameras[c]
        assert health.moved_at is not None
        if health.one_of:  # which of them moved the take cannot tell: neither is re-solved (a coin toss is not made)
            health.not_resolved = ONE_OF_ADVICE
            continue
        out = resolve_moved(rig, R, t, blobs, c, health.moved_at + health.drift_frames + SETTLE_FRAMES, moved,
                            before=None if health.before_take else health.moved_at, wander=wander_share(tests[c]))
        if isinstance(out, Resolved):
            health.resolved = out
        else:
            health.not_resolved = out.reason
