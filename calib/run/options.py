"""What a calibration is asked to do: one frozen dataclass, :class:`CalibrationOptions`, with its
own validation (:meth:`CalibrationOptions.check`, as COLMAP's ``IncrementalPipelineOptions::Check``).

The command line (``wandcal calibrate``'s flags, ``service/cli/calibrate.py``), the HTTP job
options (``JobOptions``, ``service/schemas.py``) and the worker build it from their own input
with :func:`options_from`; ``tests/service/test_options_drift.py`` finds each field in both the
flags and the job options, so the two cannot drift apart (docs/decisions/0030-calibration-options.md).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

from wandcal.calib.errors import CalibrationError
from wandcal.calib.solve.ba import DEFAULT_LOSS, LOSSES
from wandcal.calib.solve.reprojection import INTRINSICS
from wandcal.calib.solve.sync import DEFAULT_SYNC, SYNC_MODES
from wandcal.calib.start.offsets.whole_frames import DEFAULT_MAX_OFFSET

METHODS = ("ba", "lp", "paper")
DEFAULT_METHOD = "ba"  # docs/decisions/0002-default-method.md
# Bounds of the numeric options (the flags exit 2 outside them, a job is refused with a 422).
# 10,000 paper rounds are ~40 min at 8 x 1500, where the scheme converges in ~170; a day is a
# time limit no LP step needs.
MAX_PAPER_ROUNDS = 10_000
MAX_LP_SECONDS = 86_400.0
MAX_SYNC_OFFSET = 10_000  # frames: 100 s at 100 fps; further off is another recording
MAX_FRAME_RATE_HZ = 1_000_000.0  # the fastest high-speed cameras record at about this; more is a typo

# where the command line takes a field from, when not from --field-name: messages name both, so
# that they make sense on the command line and over HTTP
FLAGS = {"time_limit": "--lp-time-limit", "reject_outliers": "--keep-outliers",
         "sync_start": "sync.csv's timestamps", "frame_rate_hz": "capture.json's rate_hz"}


@dataclass(frozen=True)
class CalibrationOptions:
    """The options of :func:`wandcal.calib.run.calibrate.calibrate` (and, ``loss`` and
    ``reject_outliers`` only, of :func:`wandcal.calib.run.resolve.solve_only`).

    method: the refinement, "ba", "lp" or "paper" (``METHODS``).
    loss: ``ba``'s loss, "cauchy" (robust) or "linear" (plain least squares).
    time_limit: seconds allowed for each LP solve of ``lp`` and ``paper``; None: no limit.
    max_rounds: ``paper``'s most rotation/LP rounds; None: the method's own (``paper.MAX_ROUNDS``).
    reject_outliers: drop gross-outlier camera-frames and refine again.
    refine_intrinsics: names from ``INTRINSICS`` ("focal", "principal", "k1") that ``ba`` also
        refines per camera.
    sync: "none" (frames with one number were exposed together) or "auto" (each camera's time
        offset found from the wand, docs/sync.md).
    sync_max_offset: with sync "auto": whole frames searched either side of ``sync_start``.
    sync_start: (N,) whole-frame offsets the capture's timestamps give, searched around (the
        command line's, from sync.csv); None: zeros.
    sync_drift: with sync "auto": also each camera's clock-rate difference.
    frame_rate_hz: the cameras' frame rate, Hz, for offsets in seconds; None when unknown.
    """

    method: str = DEFAULT_METHOD
    loss: str = DEFAULT_LOSS
    time_limit: float | None = None
    max_rounds: int | None = None
    reject_outliers: bool = True
    refine_intrinsics: tuple[str, ...] = ()
    sync: str = DEFAULT_SYNC
    sync_max_offset: int = DEFAULT_MAX_OFFSET
    sync_start: tuple[int, ...] | None = None
    sync_drift: bool = False
    frame_rate_hz: float | None = None

    def check(self) -> None:
        """Raise a CalibrationError naming the first field that cannot be run, and what to do."""
        _choice("method", self.method, METHODS)
        _choice("loss", self.loss, LOSSES)
        _choice("sync", self.sync, SYNC_MODES)
        _flag_type("reject_outliers", self.reject_outliers)
        _flag_type("sync_drift", self.sync_drift)
        _number("time_limit", self.time_limit, 0.0, MAX_LP_SECONDS, low_open=True)
        _number("max_rounds", self.max_rounds, 1, MAX_PAPER_ROUNDS, whole=True)
        _number("sync_max_offset", self.sync_max_offset, 1, MAX_SYNC_OFFSET, whole=True)
        _number("frame_rate_hz", self.frame_rate_hz, 0.0, MAX_FRAME_RATE_HZ, low_open=True)
        self._check_intrinsics()
        self._check_sync_start()
        self._check_method_options()

    def _check_intrinsics(self) -> None:
        if not isinstance(self.refine_intrinsics, tuple):
            raise CalibrationError(f"{_named('refine_intrinsics')}: a tuple of names from {','.join(INTRINSICS)}, "
                                   f"not {type(self.refine_intrinsics).__name__}")
        unknown = [name for name in self.refine_intrinsics if name not in INTRINSICS]
        if unknown:
            raise CalibrationError(f"{_named('refine_intrinsics')}: unknown {unknown[0]!r}; choose from {','.join(INTRINSICS)}")
        if self.refine_intrinsics and self.method != "ba":
            raise CalibrationError(f"{_named('refine_intrinsics')} needs --method ba, not {self.method!r}")

    def _check_sync_start(self) -> None:
        start = self.sync_start
        if start is not None and not (isinstance(start, tuple) and all(_is_whole(v) for v in start)):
            raise CalibrationError(f"{_named('sync_start')}: give a tuple of whole-frame offsets, one per camera "
                                   "(or None to search around zeros)")

    def _check_method_options(self) -> None:
        """The options another method has: refused rather than ignored."""
        if self.max_rounds is not None and self.method != "paper":
            raise CalibrationError(f"{_named('max_rounds')} counts the paper method's rounds; --method {self.method} "
                                   "has none (drop it, or add --method paper)")
        if self.time_limit is not None and self.method == "ba":
            raise CalibrationError(f"{_named('time_limit')} bounds the LP solves of --method lp and paper; ba solves "
                                   "no LP (drop it, or choose one of those)")

    @property
    def polish(self) -> bool:
        """An outlier pass follows the first solve (a robust ``ba``'s polish; ``lp``'s and
        ``paper``'s passes): that solve is not the final one."""
        return self.reject_outliers and (self.method != "ba" or self.loss != "linear")


def options_from(values: Mapping[str, Any]) -> CalibrationOptions:
    """The options named in ``values`` (the command line's parsed flags, a job's options): keys
    that are no field are left out, and so are None values (the field's default then holds);
    lists become tuples. Not checked: call :meth:`CalibrationOptions.check`."""
    names = {f.name for f in fields(CalibrationOptions)}
    given: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in values.items()
                             if k in names and v is not None}
    return CalibrationOptions(**given)


def _flag(name: str) -> str:
    """Where the command line takes a field from: its flag (``--max-rounds``), or a file."""
    return FLAGS.get(name, "--" + name.replace("_", "-"))


def _named(name: str) -> str:
    """A field as a message names it: ``max_rounds (--max-rounds)``."""
    return f"{name} ({_flag(name)})"


def _choice(name: str, value: object, choices: tuple[str, ...]) -> None:
    if value not in choices:
        raise CalibrationError(f"unknown {name} {value!r} ({_flag(name)}); choose one of {', '.join(choices)}")


def _flag_type(name: str, value: object) -> None:
    if not isinstance(value, bool):
        raise CalibrationError(f"{_named(name)}: give true or false, not {value!r}")


def _is_whole(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _number(name: str, value: object, low: float, high: float, *, low_open: bool = False, whole: bool = False) -> None:
    """None, or a finite number from ``low`` (excluded when ``low_open``) to ``high``; a whole one if ``whole``."""
    if value is None:
        return
    number = value if isinstance(value, (int, float)) and not isinstance(value, bool) else None
    above = number is not None and (number > low if low_open else number >= low)
    if number is None or (whole and not isinstance(number, int)) or not (math.isfinite(number) and above and number <= high):
        kind = "a whole number" if whole else "a number"
        lower = f"more than {low:g}" if low_open else f"at least {low:g}"
        raise CalibrationError(f"{_named(name)}: must be {kind}, {lower} and at most {high:g}; got {value!r}")
