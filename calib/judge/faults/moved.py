"""Which camera moved during the capture, from every camera's pose-step test
(:func:`wandcal.calib.judge.faults.pose_steps.pose_step`), and its fault.

A camera is named only when leaving it out leaves no other camera stepping (:func:`moved_camera`):
else its step is another camera's spread through the points; and only when its step stands beside
every other camera's move at that frame (:func:`explained_by`, a nested F test): else one of them
moved and the views cannot say which, a fault of the rig (:func:`unattributed_fault`; decision 0092).
Each camera's test is looked up in :mod:`~wandcal.calib.judge.faults.pose_steps` at call time
(``pose_steps.pose_step``), so that a bench or test wrapping it sees every camera's own tests.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.judge.faults import pose_steps
from wandcal.calib.judge.faults.own_errors import Eliminated, Views, eliminate
from wandcal.calib.judge.faults.pose_steps import STEP_ALPHA, Step

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
