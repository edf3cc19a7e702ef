"""A job option and a command-line flag cannot drift apart: every field of CalibrationOptions is a
flag of ``wandcal calibrate`` (its dest is the field's name) and a field of the HTTP job, and both
check their values as calibrate does (docs/decisions/0030-calibration-options.md)."""

from __future__ import annotations

import argparse
import dataclasses
import typing

import pytest
from pydantic import ValidationError

from wandcal.calib.errors import CalibrationError
from wandcal.calib.run.options import METHODS, CalibrationOptions, options_from
from wandcal.calib.solve.ba import LOSSES
from wandcal.calib.solve.reprojection import INTRINSICS
from wandcal.calib.solve.sync import SYNC_MODES
from wandcal.service.cli import build_parser
from wandcal.service.schemas import NOT_CALIBRATION_OPTIONS, JobCreate, JobOptions, Method

FIELDS = [f.name for f in dataclasses.fields(CalibrationOptions)]
# the fields that cannot be a flag: the command line reads them from the capture folder
NOT_FLAGS = {
    "sync_start": "from sync.csv's camera timestamps (service/cli/support/inputs.py timestamp_start)",
    "frame_rate_hz": "from capture.json's rate_hz (service/cli/support/inputs.py capture_rate)",
}
# the fields that are not a job option: the job has them elsewhere, or the service cannot give them
NOT_JOB_OPTIONS = {
    "method": "JobCreate.method, beside the options (the job lists and the page show it)",
    "sync_start": "the service's captures keep no sync.csv timestamps",
}
# the flags of calibrate that are no CalibrationOptions field, and the job's field that gives each
FLAGS_AS_JOB_FIELDS = {
    "capture": "JobCreate.capture_id",
    "from_result": "JobOptions.from_job",  # a result on the server is a done job's
    "solve_only": "JobOptions.solve_only",
}
# the flags a job has no field for, deliberately, with why (issue 32: every other flag is a job's)
CLI_ONLY = {
    "help": "argparse's own",
    "out": "a file on the client's disk: a job's result is GET /jobs/{id}/result, in any export format",
    "quiet": "the terminal's progress line: a job reports its progress in its record (GET /jobs/{id})",
    "require": "an exit status for scripts: a job's result carries verdict.level, which the client compares",
}


def _calibrate_flags() -> dict[str, argparse.Action]:
    parser = build_parser(["calibrate"])
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return {action.dest: action for action in sub.choices["calibrate"]._actions}


def test_every_option_is_a_flag_of_calibrate():
    flags = _calibrate_flags()
    missing = [name for name in FIELDS if name not in flags and name not in NOT_FLAGS]
    assert missing == []
    assert set(NOT_FLAGS) <= set(FIELDS) and not set(NOT_FLAGS) & set(flags)


def test_every_option_is_a_job_option():
    job = set(JobOptions.model_fields)
    missing = [name for name in FIELDS if name not in job and name not in NOT_JOB_OPTIONS]
    assert missing == []
    assert "method" in JobCreate.model_fields
    # and the job has no option calibrate does not take, but the job's own (with why)
    assert job - set(FIELDS) == set(NOT_CALIBRATION_OPTIONS) == {"use_static", "from_job", "solve_only"}


def test_every_flag_of_calibrate_is_a_job_field_or_cli_only_with_a_reason():
    """Issue 32: the service does what the command line does; a flag with no job field is listed with why."""
    flags = set(_calibrate_flags())
    models = {"JobCreate": JobCreate.model_fields, "JobOptions": JobOptions.model_fields}
    for flag, where in FLAGS_AS_JOB_FIELDS.items():
        model, field = where.split(".")
        assert flag in flags and field in models[model], (flag, where)
    unmapped = flags - set(FIELDS) - set(FLAGS_AS_JOB_FIELDS) - set(CLI_ONLY)
    assert unmapped == set(), f"give these calibrate flags a job field or a CLI_ONLY reason: {sorted(unmapped)}"
    assert set(CLI_ONLY) <= flags  # no stale entry


def test_flag_defaults_and_job_defaults_are_the_options_defaults():
    flags = _calibrate_flags()
    defaults = CalibrationOptions()
    from_flags = options_from({name: action.default for name, action in flags.items()})
    from_job = JobOptions().calibration(defaults.method)
    assert from_flags == defaults
    assert from_job == defaults


def test_the_choices_are_calibrates():
    flags = _calibrate_flags()
    assert tuple(flags["method"].choices) == METHODS
    assert tuple(m.value for m in Method) == METHODS
    assert tuple(flags["loss"].choices) == LOSSES
    assert tuple(flags["sync"].choices) == SYNC_MODES
    fields = JobOptions.model_fields
    assert typing.get_args(fields["loss"].annotation) == LOSSES
    assert typing.get_args(fields["sync"].annotation) == SYNC_MODES
    assert typing.get_args(typing.get_args(fields["refine_intrinsics"].annotation)[0]) == tuple(INTRINSICS)


@pytest.mark.parametrize(("options", "words"), [
    ({"max_rounds": 5}, "max_rounds (--max-rounds) counts the paper method's rounds"),
    ({"time_limit": 3.0}, "time_limit (--lp-time-limit) bounds the LP solves"),
    ({"refine_intrinsics": ("focal",), "method": "lp"}, "refine_intrinsics (--refine-intrinsics) needs --method ba"),
    ({"refine_intrinsics": ("skew",)}, "unknown 'skew'"),
    ({"method": "fast"}, "unknown method 'fast'"),
    ({"loss": "huber"}, "unknown loss 'huber'"),
    ({"sync": "sometimes"}, "unknown sync 'sometimes'"),
    ({"sync_max_offset": 0}, "sync_max_offset (--sync-max-offset): must be a whole number, at least 1"),
    ({"max_rounds": 2.5, "method": "paper"}, "max_rounds (--max-rounds): must be a whole number"),
    ({"time_limit": float("inf"), "method": "lp"}, "time_limit (--lp-time-limit): must be a number, more than 0"),
    ({"frame_rate_hz": -1.0}, "frame_rate_hz (capture.json's rate_hz): must be a number, more than 0"),
    ({"sync_start": (0, 1.5)}, "sync_start (sync.csv's timestamps): give a tuple of whole-frame offsets"),
    ({"reject_outliers": "yes"}, "reject_outliers (--keep-outliers): give true or false"),
])
def test_check_names_the_field_and_what_to_do(options, words):
    with pytest.raises(CalibrationError, match=words.replace("(", r"\(").replace(")", r"\)")):
        CalibrationOptions(**options).check()


def test_the_options_of_every_method_pass_check():
    CalibrationOptions(method="paper", max_rounds=3, time_limit=10.0).check()
    CalibrationOptions(method="lp", time_limit=10.0, sync="auto", sync_start=(0, -2, 5), frame_rate_hz=100.0).check()
    CalibrationOptions(refine_intrinsics=("focal", "k1"), loss="linear", reject_outliers=False, sync_drift=True).check()


def test_a_job_the_method_cannot_run_is_refused():
    with pytest.raises(ValidationError, match="max_rounds"):
        JobCreate(capture_id="c", method="ba", options={"max_rounds": 5})
    with pytest.raises(ValidationError, match="refine_intrinsics"):
        JobCreate(capture_id="c", method="lp", options={"refine_intrinsics": ["focal"]})
    job = JobCreate(capture_id="c", method="paper", options={"max_rounds": 5, "time_limit": 2.5})
    assert job.options.calibration(job.method.value) == CalibrationOptions(method="paper", max_rounds=5, time_limit=2.5)
    with pytest.raises(ValidationError, match="from_job and solve_only go together"):
        JobCreate(capture_id="c", options={"solve_only": ["cam1"]})
    with pytest.raises(ValidationError, match="method ba only, intrinsics held"):
        JobCreate(capture_id="c", options={"from_job": "j", "solve_only": ["cam1"], "refine_intrinsics": ["focal"]})
    resolve = JobCreate(capture_id="c", options={"from_job": "j", "solve_only": ["cam1"], "loss": "linear"})
    assert resolve.options.calibration("ba") == CalibrationOptions(loss="linear")  # the re-solve's own fields aside


def test_a_job_stored_before_the_options_were_typed_still_reads():
    """A job stored with the five options it had before issue 30 reads: the rest take their defaults."""
    old = {"use_static": False, "sync": "auto", "sync_max_offset": None, "sync_drift": True, "frame_rate_hz": 120.0}
    options = JobOptions.model_validate(old).calibration("lp")
    assert options == CalibrationOptions(method="lp", sync="auto", sync_drift=True, frame_rate_hz=120.0)
    assert JobCreate.model_validate({"capture_id": "c", "options": old}).options.use_static is False
