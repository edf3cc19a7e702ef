"""What a fresh capture says of a standing result: did a camera move (``wandcal check``, ``POST
/captures/{id}/check``), and the named cameras re-solved (``wandcal calibrate --from RESULT
--solve-only CAM``, a job's ``solve_only`` option). The command line and the service call these
same functions, so they give the same answers (tests/service/test_http_parity.py). Nothing here
loads a web framework: ``wandcal check`` imports it."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

from wandcal.service.cli.support.exits import FAULT, NO_ANSWER, OK  # the command line's one table (constants only)

if TYPE_CHECKING:  # the types only: each function imports the solver parts it runs
    from wandcal.calib.judge.bumps import RigCheck
    from wandcal.calib.rig import Rig
    from wandcal.calib.run.options import CalibrationOptions
    from wandcal.calib.run.result import CalibrationResult
    from wandcal.capture.folder import Capture
    from wandcal.capture.result_file import ResultFile

EXIT_AGREES = OK  # wandcal check: every camera agrees with the others
EXIT_MOVED = FAULT  # wandcal check: a camera moved (named)
EXIT_UNJUDGED = NO_ANSWER  # wandcal check: some camera could not be judged, or no knock explains the disagreement
VERDICTS = {EXIT_AGREES: "agrees", EXIT_MOVED: "moved", EXIT_UNJUDGED: "unjudged"}  # "rebuilt" is also exit 3


def in_capture_order(prev: ResultFile, capture_rig: Rig, source: str):
    """The result's cameras (calibrated intrinsics, poses and figures) in the capture's camera order:
    (rig, R (N, 3, 3), t (N, 3) world->camera metres, [CameraFigures]). Raises CalibrationError,
    naming ``source``, when the capture is not of the result's rig."""
    from wandcal.calib.errors import CalibrationError
    from wandcal.calib.judge.bumps import rig_mismatches

    mismatch = rig_mismatches(prev.rig, capture_rig)
    if mismatch:
        raise CalibrationError(f"{source}: the capture is not of this result's rig: {'; '.join(mismatch[:3])}; check "
                               "that the capture and the result are of one rig, or calibrate the capture afresh")
    order = [prev.rig.index(cid) for cid in capture_rig.ids]
    rig = replace(capture_rig, cameras=tuple(prev.rig.cameras[k] for k in order))
    return rig, prev.R[order], prev.t[order], [prev.result.cameras[k] for k in order]


def _has_wand(cap: Capture) -> bool:
    return cap.wand is not None and len(cap.wand) > 0 and cap.rig.wand_length is not None


def checkable(cap: Capture, capture_name: str) -> None:
    """Raise CalibrationError, naming the capture, when it has neither a wand nor point tracks."""
    from wandcal.calib.errors import CalibrationError

    if not _has_wand(cap) and (cap.points is None or not len(cap.points)):
        raise CalibrationError(f"{capture_name}: has no wand blobs and no point tracks (points.csv); 'wandcal check' "
                               "needs a fresh capture of the wand or of points seen by several cameras at once")


@dataclass(frozen=True, eq=False)
class CheckAnswer:
    """``check``'s answer: the rig's check and the exit status it means (0 agrees, 1 moved, 3 could
    not judge, or another rig / rebuilt)."""

    found: RigCheck

    @property
    def moved(self) -> list[str]:
        return [c.id for c in self.found.cameras if c.moved]

    @property
    def unjudged(self) -> list[str]:
        return [c.id for c in self.found.cameras if c.moved is None]

    @property
    def exit_code(self) -> int:
        if self.found.rebuilt:
            return EXIT_UNJUDGED
        return EXIT_MOVED if self.moved else EXIT_UNJUDGED if self.unjudged else EXIT_AGREES

    @property
    def verdict(self) -> str:
        """"agrees", "moved", "unjudged" or "rebuilt" (another rig or a rebuilt one: calibrate afresh)."""
        return "rebuilt" if self.found.rebuilt else VERDICTS[self.exit_code]

    def document(self) -> dict:
        """``wandcal check --json``'s document."""
        return {"cameras": [vars(c) for c in self.found.cameras], "moved": self.moved, "unjudged": self.unjudged,
                "rebuilt": self.found.rebuilt, "rebuilt_why": self.found.why}


def check_capture(prev: ResultFile, cap: Capture, source: str, capture_name: str) -> CheckAnswer:
    """Judge each camera of the result ``prev`` against the fresh capture ``cap`` (its wand, of any
    kind, and its point tracks: calib/judge/bumps.py). ``source`` names the result and
    ``capture_name`` the capture in messages. Raises CalibrationError for a capture with neither a
    wand nor point tracks, or of another rig (other camera ids or sizes)."""
    import numpy as np

    from wandcal.calib.judge.bumps import check_rig

    checkable(cap, capture_name)
    has_wand = _has_wand(cap)
    rig, R, t, entries = in_capture_order(prev, cap.rig, source)
    expected = np.array([e.reprojection_rms_px or np.nan for e in entries], float)
    return CheckAnswer(check_rig(rig, R, t, cap.wand if has_wand else None,
                                 None if np.isnan(expected).any() else expected, cap.points))


def solve_only_capture(prev: ResultFile, cap: Capture, cameras: list[str], options: CalibrationOptions, *,
                       source: str, capture_name: str, progress=None) -> CalibrationResult:
    """Re-solve ``cameras`` of the standing result ``prev`` from the fresh capture ``cap``; every
    other camera keeps its pose exactly, and the world frame is the result's
    (:func:`wandcal.calib.run.resolve.solve_only`, which refuses a method other than ba)."""
    from wandcal.calib.errors import CalibrationError
    from wandcal.calib.run.resolve import solve_only

    rig, R, t, entries = in_capture_order(prev, cap.rig, source)
    has_wand = cap.wand is not None and len(cap.wand) > 0
    if not has_wand and (cap.points is None or not len(cap.points)):
        raise CalibrationError(f"{capture_name}: has no wand blobs and no point tracks; --solve-only needs a fresh "
                               "capture of the wand or of points seen by several cameras at once (points.csv)")
    return solve_only(rig, cap.wand if has_wand else None, R, t, list(cameras), prev.result.world, entries,
                      progress=progress, options=options, points=cap.points)
