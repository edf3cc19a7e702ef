"""Which camera moved during the capture, from every camera's pose-step test
(:func:`wandcal.calib.judge.faults.pose_steps.pose_step`), and its fault.

A camera is named only when leaving it out leaves no other camera stepping (:func:`moved_camera`):
else its step is another camera's spread through the points; and only when its step stands beside
every other camera's move at that frame (:func:`explained_by`, a nested F test): else one of them
moved and the views cannot say which, a fault of the rig (:func:`unattributed_fault`; decision 0092).
Each camera's test is looked up in :mod:`~wandcal.calib.judge.faults.pose_steps` at call time
(``pose_steps.pose_step``), so that a bench or test wrapping it sees every camera's own tests.

A large rig screens every camera cheaply first (:func:`step_suspects`, :func:`step_screen`), so
that only its few suspects get the full test.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.judge.faults import pose_steps
from wandcal.calib.judge.faults.f_distribution import f_survival
from wandcal.calib.judge.faults.own_errors import TRIM_SIGMAS, Eliminated, Views, eliminate, in_wand_time
from wandcal.calib.judge.faults.pose_steps import STEP_ALPHA, Step
from wandcal.calib.judge.faults.step_columns import MIN_SIDE
from wandcal.calib.judge.residuals import Residuals

# a step is named on its camera c only where, for every other camera d, c's step stands beside d
# having moved (explained_by): were d the one that moved, c is named at most at this rate (the
# conventional 1%, Bonferroni over the alternatives tried; the wrong camera among the moves found)
NAME_ALPHA = 1e-2


@dataclass(frozen=True)
class Moved:
    """What :func:`moved_camera` found: ``camera`` and its ``step`` where one camera is named;
    else, where a step passed the leave-one-out check but another camera's move explains it as
    well, ``unsure``: (the cameras, the first one's and then those whose move explains its step;
    that step): one of them moved at that frame, and the data cannot say which
    (:func:`unattributed_fault`); all None where no camera stepped."""

    camera: int | None = None
    step: Step | None = None
    unsure: tuple[tuple[int, ...], Step] | None = None


class _Refits:
    """Each camera's views with the others' outliers dropped (``trimmed``, :func:`eliminate` of
    ``views``) and all of its own kept, the points fitted again (:func:`eliminate`, no trim, the
    sigmas held), made once a camera: its step test's (:func:`_steps`) and :func:`explained_by`'s.
    Where no view of a camera was trimmed (a clean rig: every camera), its views are every camera's
    kept views, the same set: one fit serves them all (the same input, the same numbers)."""

    def __init__(self, R: np.ndarray, t: np.ndarray, views: Views, trimmed: Eliminated):
        self.R, self.t, self.views, self.trimmed = R, t, views, trimmed
        self._made: dict[bytes, Eliminated] = {}

    def of(self, c: int) -> Eliminated:
        drop = ~(self.trimmed.kept | (self.views.camera == c))
        key = np.packbits(drop).tobytes()
        if key not in self._made:
            self._made[key] = eliminate(self.R, self.t, self.views.without(drop), self.trimmed.sigma, trim=False)
        return self._made[key]


def _steps(refits: _Refits, cameras: list[int] | None = None) -> list[Step | None]:
    """Every camera's best step (of ``cameras`` only where given, None for the others): its own
    views all kept (a knocked camera's later views are far off; each step test trims under its own
    model), the other cameras' outliers as ``trimmed`` (:func:`eliminate` of ``views``) dropped them."""
    out: list[Step | None] = []
    for c in range(len(refits.R)):
        mine = refits.views.camera == c
        if not mine.any() or (cameras is not None and c not in cameras):
            out.append(None)
            continue
        el = refits.of(c)
        out.append(pose_steps.pose_step(el, c) if (el.views.camera == c).any() else None)
    return out


def _found(step: Step | None) -> bool:
    return step is not None and step.p_value < STEP_ALPHA


def moved_camera(R: np.ndarray, t: np.ndarray, views: Views, trimmed: Eliminated,
                 cameras: list[int] | None = None) -> Moved:
    """The camera that moved during the capture, and its step (:class:`Moved`); none named when no
    camera's step is significant, or none explains the others' (with its views left out, another
    still steps), or its step is explained by another camera's move (:func:`explained_by`).
    trimmed: :func:`eliminate` of ``views``; cameras: those to test (every camera when None; in a
    large rig :func:`step_suspects`, and only those of them that step are tested again without
    the one named). Where no camera is named, the first camera whose step passed the leave-one-out
    check but another's move explains is ``unsure``: one of them moved at that frame, the data
    cannot say which (:func:`unattributed_fault`)."""
    refits = _Refits(R, t, views, trimmed)
    steps = _steps(refits, cameras)
    found = sorted((s.p_value, c, s) for c, s in enumerate(steps) if s is not None and _found(s))
    doubt = None
    for _, c, step in found:
        if _others_step_without(R, t, views, trimmed, c, steps, cameras):
            continue
        if not (by := explained_by(R, t, views, trimmed, c, step, steps, refits)):
            return Moved(c, step)
        doubt = doubt or ((c, *by), step)
    return Moved(unsure=doubt)


def _others_step_without(R: np.ndarray, t: np.ndarray, views: Views, trimmed: Eliminated, c: int,
                         steps: list[Step | None], cameras: list[int] | None) -> bool:
    """Whether, with camera c's views left out, another camera still steps (of those ``cameras``
    that stepped with them, where given)."""
    again = None if cameras is None else [k for k in cameras if k != c and _found(steps[k])]
    if again == []:
        return False
    rest = views.without(views.camera == c)
    seen = np.bincount(rest.point, minlength=rest.n_points)
    rest = rest.without(seen[rest.point] < 2)
    return any(_found(s) for k, s in enumerate(_steps(_Refits(R, t, rest, eliminate(R, t, rest, trimmed.sigma)),
                                                      again)) if k != c)


def explained_by(R: np.ndarray, t: np.ndarray, views: Views, trimmed: Eliminated, c: int, step: Step,
                 steps: list[Step | None], refits: _Refits | None = None) -> list[int]:
    """The other cameras whose own move explains camera c's step ``step``: c's step at its frame
    tested again with camera d's two poses in its base (:func:`~wandcal.calib.judge.faults.pose_steps.pose_step` ``given`` and ``at``), d
    split at the same frame, and at d's own best split where that differs; c's step no longer
    significant at :data:`NAME_ALPHA` (Bonferroni over the tests made). steps: every camera's step
    (:func:`_steps`; None where untested, and those are not tried); refits: the step tests' fits
    of the same R, t, views and trimmed (:class:`_Refits`), where already made.

    Why: a nested F test, F(3, the step's dof) of c's step beside d's. Where camera d moved, the
    points d shares with c are placed off after d's move, and c's residuals step there too;
    leaving c out cannot tell (in a rig of three the pair left has nothing to test against).
    Naming c needs the alternative "d moved at that frame" rejected for every d: c's step must
    stand beside d's two poses. The frame is the step test's, common to both hypotheses and taken
    as known (a change point's estimate converges at the rate n, faster than the turns' sqrt n:
    the turns' tests hold as at a known split). Were d alone moved, c is named with a chance of at
    most NAME_ALPHA: the rate of a wrong camera among the moves found (decision 0092)."""
    el = (refits or _Refits(R, t, views, trimmed)).of(c)
    tests = [(d, k) for d, s in enumerate(steps) if d != c and s is not None and (el.views.camera == d).any()
             for k in sorted({s.frame, step.frame})]
    out = []
    for d, k in tests:
        again = pose_steps.given_step(el, c, given=(d, k), at=step.frame)
        if (again is None or again.p_value >= NAME_ALPHA / len(tests)) and d not in out:
            out.append(d)
    return out


def moved_fault(cam: str, s: Step) -> dict:
    return {"kind": "moved", "camera": cam, "evidence": {
        "frame": s.frame, "degrees": round(s.degrees, 3), "degrees_std": round(s.degrees_std, 3),
        "centre_mm": round(s.mm, 2), "centre_std_mm": round(s.mm_std, 2), "f_stat": round(s.f_stat, 1),
        "p_value": float(f"{s.p_value:.3g}"), "explained_share": round(s.explained, 3)},
        "message": f"{cam} moved during the capture: after frame {s.frame} it is turned by {s.degrees:.2f} +- "
                   f"{s.degrees_std:.2f} degrees against its pose before (its centre {s.mm:.0f} +- {s.mm_std:.0f} mm), "
                   f"where the other cameras agree; fix its mount and calibrate again, or re-solve it from the frames "
                   f"after {s.frame} alone (keep only those of {cam}'s rows and run calibrate --from RESULT "
                   f"--solve-only {cam})"}


def unattributed_fault(cams: list[str], s: Step) -> dict:
    """A step one of ``cams`` made, each one's move explaining the first one's (:func:`moved_camera`
    ``unsure``): a fault of the rig (no camera named), with the frame and the step as the first
    camera's test measured it."""
    which = ", ".join(cams[:-1]) + f" or {cams[-1]}"
    return {"kind": "moved", "camera": None, "evidence": {
        "cameras": list(cams), "frame": s.frame, "degrees": round(s.degrees, 3), "p_value": float(f"{s.p_value:.3g}")},
        "message": f"one of {which} moved during the capture, after frame {s.frame} (a step of {s.degrees:.2f} degrees in "
                   f"{cams[0]}'s views, which a move of {' or '.join(cams[1:])} explains as well: these views cannot say "
                   f"which); check their mounts, then wave the wand again and calibrate, or calibrate from the frames "
                   f"up to {s.frame} alone"}


# a large rig (over leave_one_out.MAX_CAMERAS) screens every camera cheaply first (step_screen):
# its own views' turn in SCREEN_BLOCKS blocks of time, a Hotelling test of one level against two;
# the MAX_STEP_SUSPECTS cameras below SCREEN_ALPHA (a pre-filter: the full test decides) are tested
# in full. Simulated 16-camera rigs: clean cameras down to p = 7e-4 (one in 16 under 0.01), a
# camera knocked by 0.1 degree 3e-7, by 0.3 degree 4e-11
SCREEN_BLOCKS = 16
SCREEN_VIEWS = 2000  # of a camera, evenly spaced in time: 125 a block
SCREEN_ALPHA = 1e-3
MAX_STEP_SUSPECTS = 3


def screen_views(time: np.ndarray) -> np.ndarray:
    """(min(K, :data:`SCREEN_VIEWS`),) the views :func:`step_screen` looks at, of K timed ones
    (time (K,) their capture frames): evenly spaced in time order. Views already so chosen (in
    time order, at most that many) are all chosen again, in their order."""
    order = np.argsort(time, kind="stable")
    if len(order) <= SCREEN_VIEWS:  # np.linspace(0, K - 1, K) is 0 .. K - 1 exactly: every view
        return order
    return order[np.linspace(0, len(order) - 1, SCREEN_VIEWS).astype(np.int64)]


def step_screen(xy: np.ndarray, r: np.ndarray, time: np.ndarray) -> float:
    """A cheap look for a step in one camera's pose: p-value (Bonferroni over the block
    boundaries; 1 with too few views). Its timed views xy (K, 2) (normalised), their residuals
    r (K, 2) against points every camera triangulated (in a large rig a point hangs little on any
    one view) and their capture frames time (K,): in :data:`SCREEN_BLOCKS` blocks of time, a turn
    about the camera's centre (three columns; a turn moves an image point by what its direction
    alone decides) fitted in each after dropping the block's views beyond :data:`TRIM_SIGMAS` of
    its median; Hotelling's T^2 of the blocks' mean turn before a boundary against after, the
    blocks' own scatter about their two levels as the covariance (so a misfit that runs on in time
    counts, and the residuals' scale does not matter)."""
    n_blocks = SCREEN_BLOCKS
    if len(xy) < n_blocks * MIN_SIDE:
        return 1.0
    order = screen_views(time)
    size = len(order) // n_blocks
    at = order[: n_blocks * size].reshape(n_blocks, size)  # the last views of the remainder left out
    x, y = xy[at, 0], xy[at, 1]
    # the image motion of a turn about the centre, d(projection of exp(w) (x, y, 1))/dw: (B, S, 2, 3)
    G = np.empty(x.shape + (2, 3))
    G[..., 0, 0], G[..., 0, 1], G[..., 0, 2] = -x * y, 1 + x**2, -y
    G[..., 1, 0], G[..., 1, 1], G[..., 1, 2] = -1 - y**2, x * y, x
    rb = r[at]
    e2 = rb[..., 0] ** 2 + rb[..., 1] ** 2  # np.sum(rb**2, axis=2) bit for bit, without its per-row reduction
    ok = e2 <= TRIM_SIGMAS**2 * np.maximum(np.median(e2, axis=1, keepdims=True), 1e-30)
    Gt = (G * ok[..., None, None]).reshape(n_blocks, -1, 3).transpose(0, 2, 1)
    N = Gt @ G.reshape(n_blocks, -1, 3)
    N += 1e-12 * np.trace(N, axis1=1, axis2=2)[:, None, None] * np.eye(3)
    w = np.linalg.solve(N, Gt @ rb.reshape(n_blocks, -1, 1))[..., 0]
    nu = n_blocks - 2
    j = np.arange(2, n_blocks - 1)  # boundaries: at least two blocks either side
    total, outer = np.cumsum(w, axis=0), np.cumsum(np.einsum("bi,bj->bij", w, w), axis=0)
    before, after = total[j - 1] / j[:, None], (total[-1] - total[j - 1]) / (n_blocks - j)[:, None]
    # the blocks' scatter about their two levels: sum w w^T less each side's n m m^T
    S = (outer[-1] - j[:, None, None] * np.einsum("ji,jk->jik", before, before)
         - (n_blocks - j)[:, None, None] * np.einsum("ji,jk->jik", after, after)) / nu
    S += 1e-12 * np.trace(S, axis1=1, axis2=2)[:, None, None] * np.eye(3)
    d = after - before
    t2 = np.einsum("ji,ji->j", d, np.linalg.solve(S, d[..., None])[..., 0]) / (1 / j + 1 / (n_blocks - j))
    # the p-value falls as T^2 grows: the largest T^2 gives the smallest
    return min(1.0, f_survival(3, nu - 2, float(t2.max()) * (nu - 2) / (3 * nu)) * len(j))


def step_suspects(res: Residuals, track_frames: np.ndarray | None) -> list[int]:
    """The cameras of a large rig whose :func:`step_screen` on the judgement's residuals
    (:class:`wandcal.calib.judge.residuals.Residuals`: every camera's views against points all
    cameras triangulated, a knocked camera's later views left out of them as outliers) is below
    :data:`SCREEN_ALPHA`, at most :data:`MAX_STEP_SUSPECTS`, the smallest p first. Timed views:
    the wand's and the point tracks' (track_frames (T,): each track's capture frame) in the wand's
    time (:func:`wandcal.calib.judge.faults.own_errors.in_wand_time`; all of them without a wand)."""
    wand = res.point >= 0
    time = res.frames[np.maximum(res.point, 0) // 2] if len(res.frames) else np.zeros(len(res.point), np.int64)
    timed = wand.copy()
    if track_frames is not None and len(track_frames):
        track = np.maximum(-1 - res.point, 0)
        time = np.where(wand, time, track_frames[track])
        wand_frames = res.frames[np.unique(res.point[wand] // 2)]
        timed |= ~wand & in_wand_time(track_frames, wand_frames)[track]
    if not timed.any():
        return []
    p = []
    for c in range(int(res.camera.max()) + 1 if len(res.camera) else 0):
        rows = res.rows_of(c)
        rows = rows[timed[rows]]
        mine = time[rows]
        # the screen's views chosen first, then only theirs gathered (step_screen chooses the same again)
        pick = screen_views(mine) if len(rows) >= SCREEN_BLOCKS * MIN_SIDE else slice(None)
        rows, mine = rows[pick], mine[pick]
        p.append((step_screen(np.take(res.xy, rows, axis=0), np.take(res.residual, rows, axis=0), mine), c))
    return [c for pc, c in sorted(p) if pc < SCREEN_ALPHA][:MAX_STEP_SUSPECTS]
