"""Calibration jobs: queue one for a capture, follow its progress, fetch or cancel it."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, HTTPException, Query, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse, RedirectResponse

from wandcal.service.api.deps import State, require_content_type
from wandcal.service.api.security import relative_paths
from wandcal.service.datafolder.retention import delete_finished_job
from wandcal.service.jobs.records import JobRecord, JobState
from wandcal.service.jobs.watch_job import WATCH_METHOD
from wandcal.service.schemas import (
    ErrorPublic,
    JobCreate,
    JobList,
    JobPublic,
    JobSummary,
    ResultFormat,
    ValidationErrorPublic,
)
from wandcal.service.storage import CaptureNotFound

router = APIRouter(prefix="/jobs", tags=["jobs"])

MIN_CAMERAS = 2  # a camera pose is only defined relative to another camera's
MEDIA_TYPES = {
    ResultFormat.json: ("application/json", "json"),
    ResultFormat.anipose_toml: ("application/toml", "toml"),
    ResultFormat.opencv_yaml: ("application/x-yaml", "yaml"),
    ResultFormat.dlt_csv: ("text/csv", "csv"),
    ResultFormat.qca: ("application/xml", "qca.txt"),
    ResultFormat.xcp: ("application/xml", "xcp"),
}
UNKNOWN_JOB = {"model": ErrorPublic, "description": "unknown job"}
UNAUTHORISED = {"model": ErrorPublic, "description": "missing or wrong bearer token"}
QUEUE_AWAY = {"model": ErrorPublic, "description": "the job queue (Redis) is unreachable; Retry-After says when to ask again"}


def _job(state, job_id: str) -> JobRecord:
    record = state.queue.refresh(job_id) if len(job_id) <= 64 else None
    if record is None:
        raise HTTPException(404, f"no job with id {job_id!r}; list jobs with GET /api/v1/jobs")
    if record.method == WATCH_METHOD:  # issue 36: a watch is read at /watch (service/api/routes/watch.py)
        raise HTTPException(404, f"job {job_id} is a watch; read it with GET /api/v1/watch/{job_id}")
    return record


def to_public(r: JobRecord, state=None) -> JobPublic:
    """The record as answered; a job's error and progress message show paths relative to the
    data directory (a solver's message names the capture's files by their absolute path)."""
    roots = [str(state.settings.data_dir)] if state is not None else []
    progress = r.progress
    if isinstance(progress, dict) and isinstance(progress.get("message"), str):
        progress = progress | {"message": relative_paths(progress["message"], roots)}
    return JobPublic(
        id=r.id, capture_id=r.capture_id, method=r.method, options=r.options, state=r.state, attempts=r.attempts,
        created=r.created, started=r.started, finished=r.finished, progress=progress,
        error=relative_paths(r.error, roots) if r.error else r.error, cancel_requested=r.cancel_requested,
        result=r.result,
    )


@router.post(
    "",
    status_code=202,
    response_model=JobPublic,
    dependencies=[require_content_type("application/json")],
    responses={
        401: UNAUTHORISED,
        404: {"model": ErrorPublic, "description": "unknown capture"},
        415: {"model": ErrorPublic, "description": "the body must be JSON"},
        422: {"model": ValidationErrorPublic, "description": "invalid request or a capture that cannot be solved"},
        503: QUEUE_AWAY,
    },
    summary="Queue a calibration of a capture",
)
def create_job(body: JobCreate, state: State) -> JobPublic:
    try:
        capture = state.captures.get(body.capture_id)
    except CaptureNotFound:
        raise HTTPException(
            404, f"no capture with id {body.capture_id!r}; create one with POST /api/v1/captures"
        ) from None
    seeing = capture.cameras_seeing_wand()
    if len(seeing) < MIN_CAMERAS and len(_cameras_seeing_points(state, capture.id)) < MIN_CAMERAS:
        if not seeing:
            why = ("no camera has wand observations yet, nor do two cameras share point tracks; upload wand.csv "
                   "(or points.csv) or stream frame sets first")
        else:
            why = (
                f"only camera {seeing[0]!r} saw the wand; calibration needs at least {MIN_CAMERAS} cameras "
                "that see it, so wave the wand where the other cameras see it too"
            )
        raise HTTPException(422, f"capture {capture.id} cannot be calibrated: {why}")
    if body.options.from_job:
        _check_standing(state, body, capture.id)
    record = state.queue.store.create(capture.id, body.method.value, body.options.model_dump())
    state.queue.submit(record)
    return to_public(record, state)


def _cameras_seeing_points(state, capture_id: str) -> list[str]:
    """The cameras with point tracks (points.csv): a capture without a wand calibrates from them."""
    import numpy as np

    from wandcal.calib.errors import CalibrationError

    try:
        capture = state.captures.load(capture_id)
    except CalibrationError:  # an empty streamed capture reads as none: the caller says what to send
        return []
    if capture.points is None or not len(capture.points):
        return []
    return [capture.rig.ids[k] for k in np.unique(capture.points.camera)]


def _check_standing(state, body: JobCreate, capture_id: str) -> None:
    """A ``solve_only`` job's ``from_job``: a done job whose result is of this capture's rig, and
    ``solve_only`` ids of its cameras; else a 4xx naming the field."""
    from wandcal.capture.result_file import result_from_json
    from wandcal.service.standing_result import in_capture_order

    standing = state.queue.refresh(body.options.from_job) if len(body.options.from_job or "") <= 64 else None
    if standing is None:
        raise HTTPException(422, f"options.from_job: no job with id {body.options.from_job!r}; give the id of a done "
                                 "job whose result stands (GET /api/v1/jobs)")
    if standing.state is not JobState.done or standing.result is None:
        raise HTTPException(409, f"options.from_job: job {standing.id} is {standing.state.value}, it has no result "
                                 "to re-solve from; wait until it is done")
    source = f"options.from_job: the result of job {standing.id}"
    rig = state.captures.load(capture_id).rig  # (CaptureStore.rig reads no rig without a wand)
    in_capture_order(result_from_json(standing.result, source), rig, source)  # CalibrationError: 422
    unknown = [cid for cid in body.options.solve_only if cid not in rig.ids]
    if unknown:
        raise HTTPException(422, f"options.solve_only: unknown camera id {unknown[0]!r}; capture {capture_id} has "
                                 f"{', '.join(rig.ids)}")


@router.get("", response_model=JobList, responses={401: UNAUTHORISED}, summary="List jobs, newest first")
def list_jobs(
    state: State, capture_id: Annotated[str | None, Query(max_length=64)] = None
) -> JobList:
    records = [state.queue.refresh(r.id) if not r.state.finished else r for r in state.queue.store.newest(capture_id)]
    return JobList(jobs=[JobSummary(**to_public(r, state).model_dump(exclude={"result"})) for r in records
                         if r and r.method != WATCH_METHOD])  # issue 36: watches are listed nowhere yet


@router.get(
    "/{job_id}", response_model=JobPublic, responses={401: UNAUTHORISED, 404: UNKNOWN_JOB},
    summary="A job's state, progress and, when done, its wandcal-result/1 document",
)
def get_job(job_id: str, state: State) -> JobPublic:
    return to_public(_job(state, job_id), state)


@router.delete(
    "/{job_id}", response_model=JobPublic,
    responses={401: UNAUTHORISED, 404: UNKNOWN_JOB, 503: QUEUE_AWAY},
    summary="Cancel a job (at once if queued; at its next progress report if running), or delete a finished one",
)
def cancel_job(job_id: str, state: State, response: Response,
               keep_result: Annotated[bool, Query(description="deleting a finished job: keep its result document "
                                                  "in the data folder as results/<id>.json")] = False) -> JobPublic:
    """An unfinished job is cancelled (its record stays, ``cancelled``); a finished one is removed
    from the list with its result and report, or with ``keep_result`` its result is kept in
    ``results/<id>.json`` (the answer's ``Wandcal-Kept-Result`` header names it). The answer is
    the job's record as it was."""
    record = _job(state, job_id)
    if not record.state.finished:
        return to_public(state.queue.cancel(job_id) or record, state)  # None only if its row went meanwhile
    data_dir = state.settings.data_dir
    try:
        kept = delete_finished_job(data_dir, state.settings.db_path, job_id, keep_result)
    except LookupError:
        raise HTTPException(404, f"job {job_id} was deleted meanwhile; list jobs with GET /api/v1/jobs") from None
    if kept is not None:
        response.headers["Wandcal-Kept-Result"] = str(kept.relative_to(data_dir))
    return to_public(record, state)


@router.get(
    "/{job_id}/result",
    responses={
        200: {
            "description": "the result in the requested format",
            "content": {media: {"schema": {"type": "string"}} for media, _ in MEDIA_TYPES.values()},
        },
        401: UNAUTHORISED,
        404: UNKNOWN_JOB,
        409: {"model": ErrorPublic, "description": "the job is not done"},
        422: {"model": ErrorPublic, "description": "the result cannot be written in that format"},
    },
    summary="The finished calibration as JSON, anipose TOML, OpenCV YAML, DLT CSV, Qualisys qca or Vicon xcp",
)
async def get_result(
    job_id: str,
    state: State,
    format: ResultFormat = ResultFormat.json,
    unit: Annotated[str | None, Query(pattern="^(m|mm)$", description="length unit of positions (default: the "
                                      "format's own: m, and mm for qca and xcp, which hold mm only)")] = None,
    origin: Annotated[str | None, Query(pattern="^(top-left|bottom-left)$", description="dlt-csv: the pixel origin "
                                        "the coefficients expect (default bottom-left, y up: DLTdv, easyWand, Argus); "
                                        "the other formats are top-left only")] = None,
) -> Response:
    record = await run_in_threadpool(_job, state, job_id)
    if record.state is not JobState.done or record.result is None:
        hint = f": {relative_paths(record.error, [str(state.settings.data_dir)])}" if record.error else "; poll GET /api/v1/jobs/{id} until its state is done"
        raise HTTPException(409, f"job {job_id} is {record.state.value}, it has no result{hint}")
    media, ext = MEDIA_TYPES[format]
    if format is ResultFormat.json:
        import json

        if unit not in (None, "m") or origin not in (None, "top-left"):
            raise HTTPException(422, "the json result is wandcal-result/1 as written: metres, pixels from the "
                                     "top-left; unit and origin choose another format's (docs/formats.md)")
        text = json.dumps(record.result, indent=2)
    else:
        from wandcal.capture.formats import export

        rig = await run_in_threadpool(_capture_rig, state, record.capture_id)
        text = export.export(record.result, format.value, rig, unit=unit, origin=origin)
    return Response(
        text, media_type=media,
        headers={"Content-Disposition": f'attachment; filename="wandcal-{job_id[:8]}.{ext}"'},
    )


def _capture_rig(state, capture_id: str):
    """The job's capture's rig; a rig without a wand (a points-only capture), which
    ``CaptureStore.rig`` does not read, from the capture itself."""
    from wandcal.capture.rig_file import CaptureFormatError

    try:
        return state.captures.rig(capture_id)
    except CaptureFormatError:
        return state.captures.load(capture_id).rig


# -- the illustrated report (service/report) --------------------------------------------------
# no scripts, nothing from elsewhere: the page is HTML, inline CSS and the report's own PNGs
REPORT_CSP = "default-src 'none'; img-src 'self'; style-src 'unsafe-inline'"
NOT_DONE = {"model": ErrorPublic, "description": "the job is not done"}
NO_MATPLOTLIB = {"model": ErrorPublic, "description": "the server lacks matplotlib (the 'report' extra)"}


def _report(state, job_id: str):
    """The folder of a done job's report, drawn on the first request (with the job's capture)."""
    from wandcal.service.report import ReportUnavailable
    from wandcal.service.report.store import rendered_report

    record = _job(state, job_id)
    if record.state is not JobState.done or record.result is None:
        hint = f": {relative_paths(record.error, [str(state.settings.data_dir)])}" if record.error else "; poll GET /api/v1/jobs/{id} until its state is done"
        raise HTTPException(409, f"job {job_id} is {record.state.value}, it has no report{hint}")

    def capture():
        try:
            return state.captures.load(record.capture_id)
        except CaptureNotFound:
            return None  # the page says what needs the capture

    try:
        return rendered_report(state.settings.data_dir, record.id, record.result, capture)
    except ReportUnavailable as exc:
        raise HTTPException(503, f"{exc} on the server") from None


@router.get(
    "/{job_id}/report", status_code=307, response_class=RedirectResponse,
    responses={307: {"description": "to the report's page, report/"}, 401: UNAUTHORISED, 404: UNKNOWN_JOB,
               409: NOT_DONE, 503: NO_MATPLOTLIB},
    summary="The job's illustrated report (drawn on the first request): redirects to its page",
)
async def get_report(job_id: str, state: State) -> RedirectResponse:
    await run_in_threadpool(_report, state, job_id)
    return RedirectResponse("report/", status_code=307)  # relative: the page's image links are relative too


@router.get(
    "/{job_id}/report/",
    responses={200: {"description": "the report's index.html", "content": {"text/html": {"schema": {"type": "string"}}}},
               401: UNAUTHORISED, 404: UNKNOWN_JOB, 409: NOT_DONE, 503: NO_MATPLOTLIB},
    response_class=FileResponse, summary="The job's report page (index.html)",
)
async def get_report_page(job_id: str, state: State) -> FileResponse:
    return await get_report_file(job_id, "index.html", state)


@router.get(
    "/{job_id}/report/{name}",
    responses={200: {"description": "a figure (PNG) or the page of the report",
                     "content": {"image/png": {"schema": {"type": "string", "format": "binary"}},
                                 "text/html": {"schema": {"type": "string"}}}},
               401: UNAUTHORISED, 404: {"model": ErrorPublic, "description": "unknown job or file"}, 409: NOT_DONE,
               503: NO_MATPLOTLIB},
    response_class=FileResponse, summary="A file of the job's report: index.html or one of its PNGs",
)
async def get_report_file(job_id: str, name: str, state: State) -> FileResponse:
    from wandcal.service.report.store import media_type, report_file

    folder = await run_in_threadpool(_report, state, job_id)
    path = report_file(folder, name)
    if path is None:
        raise HTTPException(404, f"job {job_id}'s report has no file {name!r}; its page is report/index.html")
    headers = {"Content-Security-Policy": REPORT_CSP, "X-Content-Type-Options": "nosniff"}
    return FileResponse(path, media_type=media_type(path), headers=headers)


# -- the page's 3D view: the capture's samples in the world (service/report/scene.py) ----------
def _scene(state, job_id: str) -> dict:
    from wandcal.calib.errors import CalibrationError
    from wandcal.capture.result_file import result_from_json
    from wandcal.service.report.scene import scene

    record = _job(state, job_id)
    if record.state is not JobState.done or record.result is None:
        raise HTTPException(409, f"job {job_id} is {record.state.value}, it has no rig to draw yet")
    try:
        capture = state.captures.load(record.capture_id)
    except CaptureNotFound:
        capture = None  # the cameras alone: the page draws them from the result
    try:
        return scene(result_from_json(record.result, f"the result of job {job_id}"), capture)
    except CalibrationError as exc:  # the stored capture is not the result's (CaptureFormatError), or will not triangulate
        raise HTTPException(422, f"job {job_id}'s capture {record.capture_id}: {exc}") from None


@router.get(
    "/{job_id}/scene",
    responses={401: UNAUTHORISED, 404: UNKNOWN_JOB, 409: NOT_DONE,
               422: {"model": ErrorPublic, "description": "the stored capture does not match the result"}},
    summary="The wand's samples, single points, axis points and volume of a done job's capture, in its world "
            "frame (wandcal-scene/1), for the page's 3D view",
)
async def get_scene(job_id: str, state: State) -> dict:
    return await run_in_threadpool(_scene, state, job_id)
