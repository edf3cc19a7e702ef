"""``wandcal check`` over HTTP: judge a standing result's cameras against a stored capture. Answered
at once, not queued: the check is bounded (leave-one-out errors and at most one resection per moved
camera: 0.3 CPU s a request at 16 cameras and 0.6 at 128; docs/decisions/0043-check-over-http.md)."""

from __future__ import annotations

import json
import math
from typing import Any, Literal

from fastapi import APIRouter, HTTPException
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from wandcal.service.api.deps import CaptureDep, State, require_content_type
from wandcal.service.jobs.records import JobState
from wandcal.service.schemas import ErrorPublic, ValidationErrorPublic
from wandcal.service.standing_result import CheckAnswer

router = APIRouter(prefix="/captures", tags=["check"])


class CheckCreate(BaseModel):
    """``POST /captures/{id}/check``: the standing result to judge the capture against, as a done
    job's id or as a posted wandcal-result/1 document (what ``wandcal check RESULT CAPTURE`` reads)."""

    model_config = ConfigDict(extra="forbid")

    job_id: str | None = Field(None, max_length=64, description="a done job whose result stands")
    result: dict[str, Any] | None = Field(None, description="a wandcal-result/1 document (docs/result-format.md)")

    @model_validator(mode="after")
    def _one_result(self) -> CheckCreate:
        if (self.job_id is None) == (self.result is None):
            raise ValueError("give one of job_id (a done job's id) and result (a wandcal-result/1 document)")
        return self


class CameraCheckPublic(BaseModel):
    """One camera against the others (wandcal.calib.judge.bumps.CameraCheck)."""

    id: str
    moved: bool | None = Field(description="true: it moved; null: too few frames to judge")
    rms_px: float | None = Field(description="RMS of its leave-one-out errors, pixels")
    median_px: float | None = Field(description="their median, pixels")
    frames: int = Field(description="frames it was judged on (a point seen with two others counts half)")
    reason: str
    turned_deg: float | None = Field(None, description="a moved camera placed again: how far it turned, degrees")
    shifted_m: float | None = Field(None, description="and how far it shifted, metres")

    @field_validator("rms_px", "median_px", "turned_deg", "shifted_m", mode="before")
    @classmethod
    def _finite(cls, value):
        return None if isinstance(value, float) and not math.isfinite(value) else value


class CheckPublic(BaseModel):
    """``wandcal check --json``'s document with the exit status it means."""

    capture_id: str
    job_id: str | None = Field(None, description="the job whose result was judged (null: a posted result)")
    exit_code: int = Field(description="wandcal check's exit status: 0 every camera agrees, 1 a camera moved, 3 some "
                           "camera could not be judged, or no knock explains the disagreement (another rig)")
    verdict: Literal["agrees", "moved", "unjudged", "rebuilt"] = Field(
        description="rebuilt: another rig or a rebuilt one, calibrate afresh (exit_code 3)")
    cameras: list[CameraCheckPublic]
    moved: list[str]
    unjudged: list[str]
    rebuilt: bool
    rebuilt_why: list[str]
    advice: str = Field(description="what to do next, in words")


def _standing(state, body: CheckCreate) -> tuple[object, str]:
    """The result document to judge and how messages name it."""
    if body.result is not None:
        return body.result, "the posted result"
    record = state.queue.refresh(body.job_id) if len(body.job_id or "") <= 64 else None
    if record is None:
        raise HTTPException(404, f"job_id: no job with id {body.job_id!r}; list jobs with GET /api/v1/jobs")
    if record.state is not JobState.done or record.result is None:
        raise HTTPException(409, f"job_id: job {record.id} is {record.state.value}, it has no result to check; wait "
                                 "until it is done")
    return record.result, f"the result of job {record.id}"


def _advice(answer: CheckAnswer, capture_id: str, job_id: str | None) -> str:
    """What to do next, as ``wandcal check`` says it, with the HTTP requests instead of commands."""
    found = answer.found
    if found.rebuilt:
        return (f"no knock explains this ({'; '.join(found.why)}): this is not a bumped camera but a rebuilt rig or a "
                f"capture of another one; calibrate afresh: POST /api/v1/jobs with capture_id {capture_id}")
    parts = []
    if answer.moved:
        job = {"capture_id": capture_id, "options": {"from_job": job_id or "JOB", "solve_only": answer.moved}}
        parts.append(f"moved: {', '.join(answer.moved)}; recalibrate with: POST /api/v1/jobs {json.dumps(job)}"
                     + ("" if job_id else ", JOB the done job of this result (or calibrate afresh)"))
    if answer.unjudged:
        parts.append(f"could not judge {', '.join(answer.unjudged)}: too few frames shared with two other cameras; "
                     "record a longer wand capture where every camera sees the wand with two others")
    return "; ".join(parts) or "every camera agrees with the others"


@router.post(
    "/{capture_id}/check",
    response_model=CheckPublic,
    dependencies=[require_content_type("application/json")],
    responses={401: {"model": ErrorPublic, "description": "missing or wrong bearer token"},
               404: {"model": ErrorPublic, "description": "unknown capture or job"},
               409: {"model": ErrorPublic, "description": "the job is not done"},
               415: {"model": ErrorPublic, "description": "the body must be JSON"},
               422: {"model": ValidationErrorPublic, "description": "an invalid result, a capture of another rig's "
                     "camera ids or sizes, or one with neither a wand nor point tracks"}},
    summary="Did any camera of a result move? Judge it against this capture (wandcal check RESULT CAPTURE)",
)
def check_capture(capture: CaptureDep, body: CheckCreate, state: State) -> CheckPublic:
    """Each camera of the result (a done job's, or a posted wandcal-result/1 document) judged by its
    leave-one-out errors against the points the other cameras triangulate in this capture: its wand
    of any kind and its point tracks. ``exit_code`` is what ``wandcal check`` exits with: 0 agrees,
    1 a camera moved (re-solve it: a job with ``from_job`` and ``solve_only``), 3 could not judge or
    another rig (``verdict`` ``rebuilt``: calibrate afresh)."""
    from wandcal.capture.result_file import result_from_json
    from wandcal.service.standing_result import check_capture as check

    doc, source = _standing(state, body)
    cap = state.captures.load(capture.id)
    answer = check(result_from_json(doc, source), cap, source, f"capture {capture.id}")
    return CheckPublic(capture_id=capture.id, job_id=body.job_id, exit_code=answer.exit_code, verdict=answer.verdict,
                       advice=_advice(answer, capture.id, body.job_id), **answer.document())
