"""Which camera is out of time, from every pair of cameras that sees the moving wand at once.

The suspect screen's timing analysis (:func:`wandcal.calib.judge.faults.screen.analyse_camera`) needs a
camera's wand ends triangulated by two other cameras in many frames. Sparse, hand-digitised
sessions do not have them: Brown's cameras share 2-8 such frames, while every frame a camera shares
with *one* other still holds the timing. Two cameras that see a point at the same time see it on
each other's epipolar lines (``x_c^T E x_d = 0``, ``E = [t_cd]x R_cd`` from the final poses, which
the static background points pin where there are any). Offsets follow docs/result-format.md's
convention, as ``--sync auto`` reports them: a camera ``delta`` frames late (positive) exposes its
frame k at the others' time ``k + delta``, so it records there where the point was at ``k + delta``.

- **Whole frames**: each camera's samples shifted by ``s`` frames against all the others',
  ``|s| <=`` :data:`MAX_SHIFT`; the median Sampson distance of its pairs at each shift. A camera
  whose pairs agree far better at a shift (:data:`WHOLE_GAIN`) than unshifted, by far more than
  any other camera's, is ``s`` frames off.
- **A fraction of a frame** (after the whole shift): to first order the epipolar product of a
  pair moves by ``-delta_c v_c^T E x_d - delta_d x_c^T E v_d``, with ``v`` each camera's own
  image velocity (its samples at the frames before and after). Least squares of every pair's
  Sampson-normalised product on every camera's offset (the rig's common offset is a null
  direction: the cameras on time are the median). A camera is named when its offset is
  :data:`MIN_T` standard errors from the others', explains :data:`MIN_SHARE` of its pairs'
  residual, and moves its blobs by :data:`MIN_EFFECT` of its own residual's scatter at the wand's
  speed: timing is judged by its effect in pixels, whatever the frame rate.

Only samples with a time take part: the wand's ends, or the point tracks where there is no wand
(a moving marker); static background points are the same at every time. The pair samples are
built in :mod:`wandcal.calib.judge.faults.epipolar_pairs`; the judging is here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.judge.faults.epipolar_pairs import PairRows, Track, camera_track, pair_rows, timed_samples
from wandcal.calib.judge.faults.screen import MIN_T_STAT, offset_text
from wandcal.calib.observations import PointTracks, WandPairs
from wandcal.calib.solve.sync.fit import smoothness
from wandcal.calib.solve.sync.report import sync_advice

MAX_SHIFT = 3  # whole frames searched either way
MIN_PAIRS = 10  # pair samples of a camera before its timing is judged
# a camera's pairs agree at a whole-frame shift when their median Sampson distance falls to this
# share of the unshifted one; and no other camera's improves nearly as much (COMPARE_MARGIN)
WHOLE_GAIN = 0.5
COMPARE_MARGIN = 1.5
# a fractional offset is named at this many standard errors from the other cameras' (the
# reference's own error included), the significance the suspect screen asks of a pattern
# (faults.MIN_T_STAT); on a solve the late camera bent, the pairs' residual holds the bend too,
# so its standard error is already on the large side ...
MIN_T = MIN_T_STAT
# ... or at this many for a camera already found at fault by its own noise: the offset then only
# says which kind of fault it is (Brown 2's cam4 0.5 frame late: t = 4.0, 30% explained, 143 px;
# 3x noise on a camera of Brown's: t <= 1.4, 5%; by chance a noisy camera's offset passes 3
# standard errors once in 370)
KIND_T = 3.0
# ... explaining this share of the camera's pairs' residual ...
MIN_SHARE = 0.3
# ... and moving its blobs, at the median speed, by this share of its pairs' residual scatter
MIN_EFFECT = 0.5
MIN_PAIR_ROWS = 8  # rows of a pair of cameras before its own scatter weighs them (_pair_scales)
TRIM = 5.0  # rows beyond this many robust sigmas are left out of the fit (a mislabelled end)


@dataclass(frozen=True)
class CameraTiming:
    """A camera's offset against the others, frames (docs/result-format.md: positive is late, its
    frame k exposed at the others' frame k + offset, as ``--sync auto`` reports it): ``whole`` the
    whole-frame part, ``offset`` in all, ``std`` its standard error; ``explained`` the share of its pairs' residual the offset explains;
    ``effect_px`` how far the offset moves its blobs at the median speed; ``pairs`` samples;
    ``untimeable`` why ``--sync auto`` cannot fit a fraction of a frame to its wand track ("" where it can)."""

    camera: int
    whole: int
    offset: float
    std: float
    explained: float
    effect_px: float
    pairs: int
    untimeable: str = ""



def _median_abs(rows: PairRows, c: int) -> tuple[float, int]:
    mine = (rows.first == c) | (rows.second == c)
    return (float(np.median(np.abs(rows.value[mine]))) if mine.any() else np.inf), int(mine.sum())


def whole_shifts(R: np.ndarray, t: np.ndarray, tracks: list[Track]) -> np.ndarray:
    """(N,) each camera's whole-frame shift: 0, or the one camera whose pairs agree far better
    shifted (:data:`WHOLE_GAIN`), standing out of every other camera's gain (:data:`COMPARE_MARGIN`)."""
    n = len(tracks)
    gains, best = np.ones(n), np.zeros(n, int)
    for c in range(n):
        at0, count = _median_abs(pair_rows(R, t, tracks, np.zeros(n, int), only=c), c)
        if count < MIN_PAIRS or not np.isfinite(at0) or at0 <= 0:
            continue
        for s in (s for s in range(-MAX_SHIFT, MAX_SHIFT + 1) if s):
            shifts = np.zeros(n, int)
            shifts[c] = s
            med, count_s = _median_abs(pair_rows(R, t, tracks, shifts, only=c), c)
            if count_s >= MIN_PAIRS and med / at0 < gains[c]:
                gains[c], best[c] = med / at0, s
    out = np.zeros(n, int)
    c = int(np.argmin(gains))
    others = np.delete(gains, c)
    if gains[c] <= WHOLE_GAIN and (not len(others) or gains[c] * COMPARE_MARGIN <= others.min()):
        out[c] = best[c]
    return out


def _speed(track: Track) -> float:
    """A camera's median image speed, normalised units per frame."""
    speed = np.linalg.norm(track.v, axis=2)[:, 0]
    speed = speed[np.isfinite(speed)]
    return float(np.median(speed)) if len(speed) else 0.0


def _fit(A: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least squares of y (J,) on A (J, N), twice, rows beyond :data:`TRIM` robust sigmas of the
    first fit's residual left out of the second (a mislabelled end, a blob on the wrong marker).
    Returns (offsets (N,), the rows kept (J,))."""
    keep = np.ones(len(y), bool)
    delta = np.zeros(A.shape[1])
    for _ in range(3):
        delta, *_ = np.linalg.lstsq(A[keep], y[keep], rcond=None)  # minimum norm: the common offset is free
        r = y - A @ delta
        mad = 1.4826 * np.median(np.abs(r[keep]))
        keep = np.abs(r) <= TRIM * max(mad, 1e-15)
    return delta, keep


def _pair_scales(first: np.ndarray, second: np.ndarray, A: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(J,) each row's noise scale: the robust scatter of its pair of cameras' rows about their own
    fit (the pair's two offsets free). A camera out of time bends the solve, and the pairs it is
    in scatter several times more than the others; weighted alike, a pair of two cameras in time
    that holds fewer rows could not outvote them, and the offset could go to the wrong camera of
    a pair. Pairs of under :data:`MIN_PAIR_ROWS` rows take the median pair's scale."""
    out = np.full(len(y), np.nan)
    pair = first * A.shape[1] + second
    for p in np.unique(pair):
        rows = pair == p
        if rows.sum() < MIN_PAIR_ROWS:
            continue
        cols = A[rows][:, [first[rows][0], second[rows][0]]]
        r = y[rows] - cols @ np.linalg.lstsq(cols, y[rows], rcond=None)[0]
        out[rows] = 1.4826 * np.median(np.abs(r))
    fallback = float(np.nanmedian(out)) if np.isfinite(out).any() else 1.0
    out = np.where(np.isfinite(out) & (out > 0), out, fallback)
    return np.maximum(out, 1e-12)


def camera_timings(R: np.ndarray, t: np.ndarray, labelled: WandPairs, tracks: PointTracks | None,
                   focal: np.ndarray) -> list[CameraTiming]:
    """Every camera's offset against the others (whole frames, then the fraction by the velocity
    fit). R, t: (N, 3, 3), (N, 3) poses; focal: (N, 2) focal lengths (fx, fy), or (N,), pixels. Empty where the
    samples are too few to judge."""
    n = len(R)
    s = timed_samples(labelled, tracks)
    if not len(s.camera):
        return []
    by_camera = [camera_track(s, c) for c in range(n)]
    shifts = whole_shifts(R, t, by_camera)
    rows = pair_rows(R, t, by_camera, shifts)
    usable = np.isfinite(rows.a) & np.isfinite(rows.b)
    if usable.sum() < MIN_PAIRS:
        return []
    first, second, y = rows.first[usable], rows.second[usable], rows.value[usable]
    A = np.zeros((len(y), n))
    A[np.arange(len(y)), first] = rows.a[usable]
    A[np.arange(len(y)), second] = rows.b[usable]
    scale = _pair_scales(first, second, A, y)
    A, y = A / scale[:, None], y / scale
    delta, keep = _fit(A, y)
    A, y, first, second = A[keep], y[keep], first[keep], second[keep]
    sigma = float(np.sqrt(np.mean((y - A @ delta) ** 2)))
    reference = float(np.median(delta))  # the cameras on time are the majority
    # each camera's own offset variance, its column's least squares: every camera with rows is in
    # the reference, judged (MIN_PAIRS) or not (decision 0077)
    gram_all = (A**2).sum(axis=0)
    own_var = np.where(gram_all > 0, sigma**2 / np.maximum(gram_all, 1e-300), np.nan)
    found = {}
    for c in range(n):
        mine = (first == c) | (second == c)
        if mine.sum() < MIN_PAIRS:
            continue
        col = A[mine, c]
        # c's offset against the others held at theirs (from the reference): its own column's least squares
        other = y[mine] - A[mine] @ np.where(np.arange(n) == c, 0.0, delta - reference)
        gram = float(col @ col)
        if gram <= 0:
            continue
        own = float(col @ other) / gram
        before, after = float(other @ other), float(((other - col * own) ** 2).sum())
        found[c] = (own, sigma / np.sqrt(gram), 1 - after / before if before > 0 else 0.0, int(mine.sum()))
    out = []
    untimeable = _untimeable(labelled, focal) if found or shifts.any() else []
    for c, (own, own_std, explained, pairs) in found.items():
        # against the reference (the others' median), whose own error adds: the variance of a mean of
        # the others, every other camera with rows, judged or not: the reference is theirs too
        others = own_var[np.isfinite(own_var) & (np.arange(n) != c)]
        std = float(np.sqrt(own_std**2 + (np.mean(others) / len(others) if len(others) else 0.0)))
        # docs/result-format.md's sign: the pairs matched c's frame k + shift with the others' k, so
        # c's frame k was exposed at the others' k - shift - own
        offset = -float(shifts[c] + own)
        out.append(CameraTiming(c, -int(shifts[c]), offset, std, explained,
                                abs(offset) * _speed(by_camera[c]) * float(np.mean(focal[c])), pairs, untimeable[c]))
    return out + [_whole_only(int(c), int(shifts[c]), by_camera[c], focal[c], untimeable[c])
                  for c in np.flatnonzero(shifts) if c not in found]


def _whole_only(c: int, shift: int, track: Track, focal: np.ndarray, untimeable: str) -> CameraTiming:
    """Camera c out of time by whole frames (``shift``, found by :func:`whole_shifts` from at least
    :data:`MIN_PAIRS` pair samples) whose samples, shifted, are too few with a velocity on both sides
    to fit the fraction of a frame: its whole shift alone, the fraction unmeasured (``std`` NaN).
    On a hand-digitised session the shift leaves a camera few frames that it shares with another
    (Brown 2's cam1, 1.6 frames slow by the end: 12 pair samples a frame early against 14 in time,
    the median product halved; then 0 with both velocities), and the shift is what to fix."""
    return CameraTiming(c, -shift, -float(shift), float("nan"), 0.0,
                        abs(shift) * _speed(track) * float(np.mean(focal)), 0, untimeable)


def _untimeable(labelled: WandPairs, focal: np.ndarray) -> list[str]:
    """(N,) why ``--sync auto`` would hold each camera at its whole-frame offset ("" where it can fit
    a fraction): its own test with the focal lengths it takes, (N, 2) (fx, fy) pixels as
    :func:`wandcal.calib.solve.sync.fit.why_untimeable` gives them (or (N,))."""
    if not len(labelled):  # point tracks only: --sync auto times the wand
        return [""] * len(focal)
    smooth = smoothness(labelled, np.asarray(focal, float).reshape(len(focal), -1))
    return [smooth.why_not(c) for c in range(len(focal))]


def _t(timing: CameraTiming) -> float:
    """How many standard errors the fractional part is from zero; a whole shift counts as certain."""
    return np.inf if timing.whole else abs(timing.offset) / max(timing.std, 1e-12)


def timing_faults(ids: list[str], R: np.ndarray, t: np.ndarray, labelled: WandPairs, tracks: PointTracks | None,
                  focal: np.ndarray, noise_px: list[float | None], timings: list[CameraTiming] | None = None) -> list[dict]:
    """The camera out of time, as a fault (``{"kind": "timing", "camera", "message", "evidence"}``;
    at most one), or nothing. A whole-frame shift found by :func:`whole_shifts` names its camera;
    a fraction of a frame is named at :data:`MIN_T` standard errors, :data:`MIN_SHARE` of the
    camera's pairs' residual explained and an effect of :data:`MIN_EFFECT` times its noise_px
    (pixels) or more, its t :data:`COMPARE_MARGIN` times every other camera's. timings:
    :func:`camera_timings` where the caller has them."""
    timings = camera_timings(R, t, labelled, tracks, focal) if timings is None else timings
    if not timings:
        return []
    best = max(timings, key=_t)
    if not best.whole and not _explains(best, timings, noise_px[best.camera] or 0.0, MIN_T):
        return []
    return [timing_fault(ids, best)]


def _explains(timing: CameraTiming, timings: list[CameraTiming], noise_px: float, min_t: float,
              min_share: float = MIN_SHARE) -> bool:
    """The fractional offset stands at ``min_t`` standard errors, explains ``min_share`` of its
    pairs' residual, moves the blobs :data:`MIN_EFFECT` of ``noise_px`` and its t is
    :data:`COMPARE_MARGIN` times every other camera's."""
    runner_up = max((_t(o) for o in timings if o.camera != timing.camera), default=0.0)
    return (_t(timing) >= min_t and timing.explained >= min_share and timing.effect_px >= MIN_EFFECT * noise_px
            and _t(timing) >= COMPARE_MARGIN * runner_up)


def timing_instead(ids: list[str], timings: list[CameraTiming], c: int, noise_px: float | None) -> dict | None:
    """A camera already found at fault (its own noise stands out) named out of time instead, as
    a fault, where its offset stands out as :func:`timing_faults` asks, at :data:`KIND_T` standard
    errors rather than :data:`MIN_T` and with no share of the pairs' residual asked of it: the
    fault is certain, and the offset only has to say which kind it is better than noise does (noise
    explains none of it: the share follows from t and the pairs' number). None otherwise."""
    mine = [o for o in timings if o.camera == c]
    if not mine or not (mine[0].whole or _explains(mine[0], timings, noise_px or 0.0, KIND_T, 0.0)):
        return None
    return timing_fault(ids, mine[0])


def timing_fault(ids: list[str], best: CameraTiming) -> dict:
    """A camera's offset as a fault: ``{"kind": "timing", "camera", "message", "evidence"}``."""
    cam, d = ids[best.camera], best.offset
    if not np.isfinite(best.std):  # a whole shift whose fraction could not be fitted (_whole_only)
        return _whole_fault(cam, best)
    whole = f" ({best.whole:+d} whole frames and the rest by the wand's speed)" if best.whole and abs(d - best.whole) > 3 * best.std else ""
    return {"kind": "timing", "camera": cam, "evidence": {"timing": {
        "offset_frames": round(d, 4), "offset_std_frames": round(best.std, 4), "whole_frames": best.whole,
        "explained_share": round(best.explained, 3), "effect_px": round(best.effect_px, 2), "pairs": best.pairs}},
        "message": f"{cam} is out of time: its samples match the other cameras' {offset_text(d, best.std)}{whole} "
                   f"(offset {d:+.2f}: positive is late), which moves its blobs "
                   f"{best.effect_px:.1f} px at the wand's median speed; check its trigger cable and settings"
                   f"{sync_advice(best.untimeable, fraction=not best.whole or abs(d - best.whole) > 3 * best.std)}"}


def _whole_fault(cam: str, best: CameraTiming) -> dict:
    """A camera out of time by whole frames, its fraction of a frame unmeasured (:func:`_whole_only`), as a fault."""
    n = abs(best.whole)
    return {"kind": "timing", "camera": cam, "evidence": {"timing": {
        "offset_frames": float(best.whole), "offset_std_frames": None, "whole_frames": best.whole,
        "explained_share": None, "effect_px": round(best.effect_px, 2), "pairs": best.pairs}},
        "message": f"{cam} is out of time: its samples match the other cameras' best about {n} frame{'s' if n != 1 else ''} "
                   f"{'late' if best.whole > 0 else 'early'} (offset {best.whole:+d}: positive is late; too few of its "
                   f"frames pair with the others' once shifted to measure the fraction of a frame), which moves its blobs "
                   f"{best.effect_px:.1f} px at the wand's median speed; check its trigger cable and settings"
                   f"{sync_advice(best.untimeable, fraction=True)}"}


def timing_refusal(error: Exception, ids: list[str], R: np.ndarray, t: np.ndarray, labelled: WandPairs,
                   tracks: PointTracks | None, focal: np.ndarray) -> Exception:
    """A refusal (the cameras do not agree on the wand) with the camera out of time named first
    where the pairs find one: its shift, not the wand's length, is then what to fix. ``error``
    itself where no camera is out of time or the rig is not of 3-5 cameras."""
    from wandcal.calib.errors import CalibrationError
    from wandcal.calib.judge.faults.leave_one_out import MAX_CAMERAS

    if not 3 <= len(ids) <= MAX_CAMERAS:
        return error
    found = timing_faults(ids, R, t, labelled, tracks, focal, [None] * len(ids))
    if not found:
        return error
    return CalibrationError(f"{found[0]['message']}. It makes the calibration fail: {error}")
