"""What a take's watch reports: each camera's health (:class:`CameraHealth`: residual, matched share,
its alarm, knock or drift, when, how much, re-solved or why not, the "one of" advice) and the take's
(:class:`WatchReport`), read by the CLI, the service and the written result; :func:`numbered`, a report
watched by frame rank given the take's own frame numbers (issue 36)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from wandcal.calib.watch.health import WINDOW_FRAMES
from wandcal.calib.watch.recover import Resolved
from wandcal.calib.watch.sequential import BASELINE_WINDOWS, PERSIST_WINDOWS, Alarm, CameraTest

# frames a take needs before any camera can be judged: the baseline, then a change's two halves
BASELINE_FRAMES = BASELINE_WINDOWS * WINDOW_FRAMES
MIN_JUDGED_FRAMES = BASELINE_FRAMES + 2 * PERSIST_WINDOWS * WINDOW_FRAMES
ONE_OF_ADVICE = ("the take cannot tell which (none beats the others by Vuong's test at its level), so none was re-solved: "
                 "wave the wand briefly and run wandcal check, or re-solve the one found moved: wandcal calibrate CAPTURE "
                 "--from RESULT --solve-only CAM")


@dataclass
class CameraHealth:
    """One camera over the take. residual_px: rms of its residuals about each window's fit;
    matched: its share of the markers two others triangulated that it was found to see;
    alarm: the test's alarm, if any; kind: "knock" or "drift"; moved_at: the first frame of the
    move; drift_frames: how long a drift took (0 for a knock); change: (6,) the full pose change."""

    id: str
    residual_px: float = float("nan")
    matched: float = float("nan")
    alarm: Alarm | None = None
    kind: str | None = None
    moved_at: int | None = None
    drift_frames: int = 0
    change: np.ndarray | None = None
    resolved: Resolved | None = None
    not_resolved: str = ""  # why a moved camera was not re-solved, and what to do
    before_take: bool = False  # it had moved already when the take began
    one_of: list[str] = field(default_factory=list)  # the other cameras the take cannot tell from it as the one that moved
    peak: float = 0.0  # the test's largest statistic over the take
    # degrees: the smallest turn (its worst axis) the test names as often as not over the take's last windows
    detectable_turn_deg: float = float("nan")
    test: CameraTest | None = field(default=None, repr=False, compare=False)  # its pose test: what a given move would score

    @property
    def lost(self) -> bool:
        """Moved too far to follow: its blobs left the markers (:mod:`wandcal.calib.watch.lost`), no change measured."""
        return self.alarm is not None and not np.isfinite(self.alarm.change).all()

    @property
    def status(self) -> str:
        """ok, moved, drifting, or one_of: it or one of :attr:`one_of` moved, the take cannot tell which."""
        if self.alarm is None:
            return "ok"
        return "one_of" if self.one_of else "drifting" if self.kind == "drift" else "moved"

    @property
    def message(self) -> str:
        """For a camera in a "one of" move: what happened and what to do ("" otherwise)."""
        if not self.one_of:
            return ""
        return f"one of {' or '.join([self.id, *self.one_of])} moved at frame {self.moved_at}: {ONE_OF_ADVICE}"


@dataclass
class WatchReport:
    """A take's watch: every camera's health, frames and markers matched."""

    cameras: list[CameraHealth]
    frames: int = 0
    tracks: int = 0
    first_frame: int = 0
    last_frame: int = 0
    obs: list[list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = field(default_factory=list)

    @property
    def moved(self) -> list[CameraHealth]:
        return [c for c in self.cameras if c.alarm is not None]

    @property
    def judged(self) -> bool:
        """Whether the take outlasted the test's baseline by a change's shortest span: a shorter one
        was matched and measured, but no camera's change over it could be tested."""
        return self.frames >= MIN_JUDGED_FRAMES


def numbered(report: WatchReport, numbers: np.ndarray) -> WatchReport:
    """The report of a take watched by frame rank, with the take's own frame numbers (``numbers``:
    the frame number of each rank). A digitised take keeps every n-th frame, or only some: its test
    windows are ten frames it holds, whatever their numbers."""
    def number(rank: int) -> int:
        return int(numbers[min(max(rank, 0), len(numbers) - 1)])

    for h in report.cameras:
        if h.alarm is not None:
            h.alarm = replace(h.alarm, frame=number(h.alarm.frame), detected_frame=number(h.alarm.detected_frame))
        if h.moved_at is not None:
            end = number(h.moved_at + h.drift_frames)
            h.moved_at = number(h.moved_at)
            h.drift_frames = end - h.moved_at
    report.first_frame, report.last_frame = number(report.first_frame), number(report.last_frame)
    report.obs = [[(numbers[f], X, xy) for f, X, xy in batch] for batch in report.obs]
    return report
