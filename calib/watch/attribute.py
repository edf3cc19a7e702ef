"""Which camera moved, when a pose test alarms and others' tests are raised too: each candidate's move
fitted and every camera's residuals taken under it, the hypotheses compared by Vuong's test
(decision 0089, issue 36).

One marker a frame (MultiCamSelfCal's LED): each camera is tested against the point the others place,
and a turned camera moves the point the others are tested against; the camera whose own statistic
passes first may be one it pulled (decision 0079). So when the alarming camera's test is not alone
(another camera's largest statistic is past :data:`~wandcal.calib.watch.sequential.PEAK_FLOOR`), each
candidate h is taken in turn as the one that moved: its change since the alarm's start k is fitted over
the windows from k on from its residuals at the standing poses (against the markers the others
triangulate, less its baseline's reference change p_0, as its test's change), its pose is moved by that
change, and every camera's residuals against the markers the others place
(:func:`~wandcal.calib.watch.health.camera_windows`) are measured over the same windows with that pose. Window w's log-likelihood under h is ``l_h(w) = -1/2 sum_c RSS_c(w) / s_c^2`` (RSS: camera c's
squared residuals at the hypothesis' poses, whitened by their points' error; s_c^2: its baseline's
residual variance), a composite likelihood whose expectation is largest at the true poses.

The hypotheses each have six parameters and are not nested, so they are compared by Vuong's test: the
mean of the log-likelihood differences over their standard error. The frames are not independent: on a
real take the camera's model error shows as a pose that wanders with where the markers are, so
neighbouring frames' differences move together. The standard error is therefore taken from batch means:
the differences summed over batches of :data:`BATCH_WINDOWS` windows (20 frames, about the persistence span
and about the wander's time scale), the batches taken as independent, and the mean over its standard
error referred to Student's t with (batches - 1) degrees of freedom. The best candidate (largest mean
log-likelihood) is named when it beats every other at one-sided level :data:`LEVEL` / (:data:`LOOKS`
(candidates - 1)) (Bonferroni over the comparisons and the looks); else the candidates it does not beat
and it are reported as "one of A or B moved at frame N", and none is re-solved: a coin toss is never made.

Two looks: the first when the alarm is raised (the windows from k to the end of the batch in hand, often
only 6-12 windows, 3-6 batches), the second once the windows from k span the test's look-back
(:data:`~wandcal.calib.watch.sequential.GLR_WINDOWS`, 300 frames) or the take ends, over all of them. A
group the second look still cannot tell apart stays "one of"; one it names becomes that camera's move, and
the others go back to being watched (:class:`~wandcal.calib.watch.stream.WatchStream`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from wandcal.calib.geometry import camera_centers, rotvec_to_matrix, sum_by
from wandcal.calib.rig import Rig
from wandcal.calib.watch.health import WINDOW_FRAMES, Triangulation, camera_windows, solve_pose_change
from wandcal.calib.watch.match import Tracks
from wandcal.calib.watch.take import PaddedFrames

LEVEL = 0.01  # the chance of naming one camera when the take cannot tell it from another (one-sided, all pairs, both looks)
LOOKS = 2  # the attribution's looks at one move (the module's note), each at LEVEL / LOOKS
BATCH_WINDOWS = 2  # windows a batch of the batch means: 20 frames (the module's note)
MIN_BATCHES = 3  # fewer batches leave the standard error unknown (2 degrees of freedom at least)
# a marker triangulated without a camera by one step from the all-view point (camera_windows' method): every
# hypothesis re-measures every camera, and the refined triangulations were 60% of that (decision 0102)
TRIANGULATION: Triangulation = "downdated"


@dataclass(frozen=True)
class Attribution:
    """Which of the candidates moved. named: the camera indices left, best first (one: it moved;
    several: one of them moved, the take cannot tell which); t: the leader's smallest Vuong t against
    another candidate (inf with one candidate); critical: the t it had to pass; batches: the batch means'
    count; changes: each named camera's change fitted over the windows (none with one candidate)."""

    named: tuple[int, ...]
    t: float = float("inf")
    critical: float = float("nan")
    batches: int = 0
    changes: dict[int, np.ndarray] = field(default_factory=dict)  # each named camera's fitted change (6,)


def moved_pose(R: np.ndarray, t: np.ndarray, c: int, change: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Poses R (C, 3, 3), t (C, 3) with camera c moved by ``change`` (6,): omega radians in its
    camera frame (``R_c' = exp(omega) R_c``), dC metres its centre's move (the watch's parametrisation)."""
    R2, t2 = R.copy(), t.copy()
    C = camera_centers(R[c][None], t[c][None])[0] + change[3:]
    R2[c] = rotvec_to_matrix(change[:3]) @ R[c]
    t2[c] = -R2[c] @ C
    return R2, t2


@dataclass(frozen=True, eq=False)
class _Part:
    """One piece's frames in the attribution's windows: w (F,) each frame's window from w0, padded its
    frames, tracks its tracks with the excluded cameras' views taken out. Cut once and measured under
    every hypothesis (each hypothesis cut them again before, and built their blob trees again)."""

    w: np.ndarray
    padded: PaddedFrames
    tracks: Tracks


def window_parts(pieces: list[tuple[PaddedFrames, Tracks]], excluded: set[int],
                 windows: tuple[int, int, int]) -> list[_Part]:
    """The pieces' frames and tracks in ``windows`` (first_frame, w0, w1): window w holds frames
    ``first_frame + w * WINDOW_FRAMES`` on, w0 <= w < w1; cameras ``excluded`` left out of the tracks."""
    first, w0, w1 = windows
    parts = []
    for padded, tracks in pieces:
        w_of = (padded.frames - first) // WINDOW_FRAMES - w0
        sel = (w_of >= 0) & (w_of < w1 - w0)
        if not sel.any():
            continue
        part = PaddedFrames(padded.frames[sel], padded.xy[sel], padded.row[sel])
        mine = np.isin(tracks.frame, part.frames)
        views = tracks.views[mine].copy()
        views[:, sorted(excluded)] = -1
        parts.append(_Part(w_of[sel], part, Tracks(tracks.frame[mine], views, tracks.X[mine])))
    return parts


def window_sums(rig: Rig, R: np.ndarray, t: np.ndarray, parts: list[_Part], n_windows: int,
                cams: list[int] | None = None) -> tuple[np.ndarray, ...]:
    """Every camera's residuals at poses R, t, window by window over the ``n_windows`` windows of
    ``parts`` (:func:`window_parts`: the take's padded frames and tracks matched at the standing poses).
    Returns g (W, C, 6), H (W, C, 6, 6) (the normal equations in each camera's pose), rss (W, C) px^2
    (squared residuals at these poses: about the window's fit and what the fit took) and n (W, C) the
    residuals kept (:func:`~wandcal.calib.watch.health.camera_windows`, its markers triangulated without
    each camera by one down-dated step: :data:`TRIANGULATION`). ``cams``: the cameras measured (the
    others' rows zero); all when None."""
    n_c = len(R)
    g, H = np.zeros((n_windows, n_c, 6)), np.zeros((n_windows, n_c, 6, 6))
    rss, n = np.zeros((n_windows, n_c)), np.zeros((n_windows, n_c))
    for part in parts:
        cw = camera_windows(rig, R, t, part.padded, part.tracks, cams=cams, method=TRIANGULATION)
        g += sum_by(part.w, cw.g, n_windows)
        H += sum_by(part.w, cw.H, n_windows)
        rss += sum_by(part.w, cw.sse, n_windows)
        n += sum_by(part.w, cw.n, n_windows)
    rss += np.einsum("wci,wcij,wcj->wc", g, np.linalg.pinv(H, rcond=1e-10, hermitian=True), g)
    return g, H, rss, n


def window_loglik(rss: np.ndarray, s2: np.ndarray, excluded: set[int]) -> np.ndarray:
    """(W,) each window's log-likelihood, ``-1/2 sum_c rss_c / s2_c`` of :func:`window_sums`' rss (W, C),
    s2 (C,): each camera's residual variance, px^2; the cameras ``excluded`` not summed."""
    keep = np.array([c not in excluded for c in range(len(s2))])
    return -0.5 * (rss[:, keep] / s2[keep]).sum(1)


def vuong(diff: np.ndarray) -> tuple[float, int]:
    """(t, batches): the mean over its standard error of windows' log-likelihood differences ``diff``
    (W,), by batch means of :data:`BATCH_WINDOWS` windows (a last partial batch joins the one before)."""
    n = len(diff) // BATCH_WINDOWS
    if n < 2:
        return 0.0, n
    sums = np.add.reduceat(diff, np.arange(n) * BATCH_WINDOWS)
    se = np.std(sums, ddof=1) / np.sqrt(n)
    mean = float(np.mean(sums))
    return (mean / se if se > 0 else np.sign(mean) * np.inf), n


def critical_t(batches: int, comparisons: int) -> float:
    """The one-sided Student t quantile at :data:`LEVEL` / (:data:`LOOKS` ``comparisons``) with ``batches - 1``
    degrees of freedom."""
    from scipy.stats import t as student

    return float(student.ppf(1 - LEVEL / (LOOKS * max(comparisons, 1)), batches - 1))


def attribute(rig: Rig, R: np.ndarray, t: np.ndarray, pieces: list[tuple[PaddedFrames, Tracks]], excluded: set[int],
              cams: list[int], base: tuple[np.ndarray, np.ndarray], windows: tuple[int, int, int]) -> Attribution:
    """Which of the cameras ``cams`` moved over ``windows`` (:func:`window_parts`'), the module's note.
    base: each camera's baseline (p_0 (C, 6), its test's reference pose change; s^2 (C,) px^2). Each
    candidate's change is fitted over all the windows from its residuals at the standing poses (the
    markers the others place), less its p_0."""
    if len(cams) == 1:
        return Attribution((cams[0],))
    p0, s2 = base
    parts, n_windows = window_parts(pieces, excluded, windows), windows[2] - windows[1]
    g, H = window_sums(rig, R, t, parts, n_windows, cams)[:2]  # only the candidates' changes are fitted
    changes = {c: solve_pose_change(H[:, c].sum(0), g[:, c].sum(0)) - p0[c] for c in cams}
    each = [window_sums(rig, *moved_pose(R, t, c, changes[c]), parts, n_windows)[2:] for c in cams]
    held = np.all([n[:, [c for c in range(len(R)) if c not in excluded]].sum(1) > 0 for _, n in each], axis=0)
    ll = np.array([window_loglik(rss, s2, excluded)[held] for rss, _ in each])  # windows with residuals under all
    order = np.argsort(-ll.sum(1), kind="stable")
    best = int(order[0])
    tests = [vuong(ll[best] - ll[j]) for j in order[1:]]
    batches = tests[0][1]
    if batches < MIN_BATCHES:
        return Attribution(tuple(cams[i] for i in order), 0.0, float("nan"), batches, changes)
    crit = critical_t(batches, len(cams) - 1)
    left = [cams[best]] + [cams[j] for j, (tv, _) in zip(order[1:], tests) if not tv > crit]
    named = tuple(left)
    return Attribution(named, min(tv for tv, _ in tests), crit, batches, {c: changes[c] for c in named})
