"""Watch over HTTP (issue 36), as ``wandcal watch RESULT TAKE``: upload a take to a capture with its
standing result (a done calibration job's, or a result file), watch it as a job, read each
camera's health, any moved camera and, when asked, the updated result."""

from __future__ import annotations

import json
import shutil
import threading
import time
import uuid
from pathlib import Path
from typing import Any

from fastapi import APIRouter, HTTPException, Request
from fastapi.concurrency import run_in_threadpool
from pydantic import BaseModel, Field

from wandcal.calib.errors import CalibrationError
from wandcal.calib.watch.sequential import GLR_THRESHOLD
from wandcal.drivers.capture_files import RIG_FILE, TAKE_FILE
from wandcal.service.api.deps import State, require_content_type
from wandcal.service.api.routes.captures import _file_schema, _form, _form_body, _text
from wandcal.service.jobs.records import JobRecord, JobState
from wandcal.service.jobs.watch_job import LIVE_TAKE_PREFIX, STANDING_FILE, TAKES_DIR, WATCH_METHOD
from wandcal.service.schemas import ErrorPublic, JobProgress
from wandcal.service.storage import CaptureNotFound

router = APIRouter(prefix="/watch", tags=["watch"])

PARTS = (TAKE_FILE, RIG_FILE, STANDING_FILE, "job_id", "capture_id", "write")
LIVE_RIG_WAIT_S = 5.0  # a live capture writes rig.json as its recording starts
TRUE, FALSE = ("1", "true", "yes", "on"), ("", "0", "false", "no", "off")
ERRORS: dict[int | str, dict[str, Any]] = {
    401: {"model": ErrorPublic, "description": "missing or wrong bearer token"},
    404: {"model": ErrorPublic, "description": "unknown capture or job"},
    409: {"model": ErrorPublic, "description": "the standing job, or the watch, is not done"},
    413: {"model": ErrorPublic, "description": "request body over the upload limit"},
    422: {"model": ErrorPublic, "description": "a take or result that cannot be watched; the message names the "
                                               "part (take.csv, result.json, job_id) and the line"},
    503: {"model": ErrorPublic, "description": "the job queue (Redis) is unreachable; Retry-After says when"},
}


class WatchPublic(BaseModel):
    """A watch job: its state and, once done, the report of ``wandcal watch --json``."""

    id: str
    capture_id: str
    state: JobState
    created: float
    finished: float | None = None
    write: bool = Field(description="the updated result was asked for (GET /watch/{id}/result once done)")
    progress: JobProgress | None = None
    error: str | None = None
    report: dict[str, Any] | None = Field(None, description="each camera's health and the moved ones, as "
                                          "`wandcal watch --json` prints them (frames, judged, markers, cameras, moved)")


def _public(r: JobRecord) -> WatchPublic:
    report = {k: v for k, v in r.result.items() if k != "result"} if r.result else None
    return WatchPublic(id=r.id, capture_id=r.capture_id, state=r.state, created=r.created, finished=r.finished,
                       write=bool(r.options.get("write")), progress=r.progress, error=r.error, report=report)


def _record(state, job_id: str, method: str | None = WATCH_METHOD) -> JobRecord:
    record = state.queue.refresh(job_id) if len(job_id) <= 64 else None
    if record is None or (method is not None and record.method != method):
        raise HTTPException(404, f"no watch with id {job_id!r}; start one with POST /api/v1/watch")
    return record


def _flag(value, name: str) -> bool:
    text = (value if isinstance(value, str) else "").strip().lower()
    if text not in TRUE + FALSE:
        raise HTTPException(422, f"{name}: {value!r} is not a yes or no; give true or false")
    return text in TRUE


def _standing(state, form, upload: str | None) -> tuple[str, str, str | None]:
    """(the standing result's text, how it is named, the capture of its job): ``job_id`` (a done
    calibration job) or the uploaded ``result.json``, not both."""
    job_id = form.get("job_id")
    if (job_id is None) == (upload is None):
        raise HTTPException(422, f"give the standing result: job_id (a done calibration job) or a {STANDING_FILE} part, "
                                 "one of them")
    if upload is not None:
        return upload, STANDING_FILE, None
    record = state.queue.refresh(job_id) if isinstance(job_id, str) and len(job_id) <= 64 else None
    if record is None or record.method == WATCH_METHOD:
        raise HTTPException(404, f"job_id: no calibration job with id {job_id!r}; list jobs with GET /api/v1/jobs")
    if record.state is not JobState.done or record.result is None:
        raise HTTPException(409, f"job_id: job {job_id} is {record.state.value}; watch with a done calibration")
    return json.dumps(record.result, indent=2) + "\n", f"job {job_id}'s result", record.capture_id


def _store_take(state, texts: dict[str, str], source: str) -> Path:
    """The take folder written and checked as ``wandcal watch`` reads it (its messages name the part);
    removed again when refused."""
    from wandcal.capture.take_file import read_take
    from wandcal.service.cli.support.inputs import result_for

    folder = state.settings.data_dir / TAKES_DIR / uuid.uuid4().hex
    folder.mkdir(parents=True)
    try:
        for name, text in texts.items():
            (folder / name).write_text(text)
        take = read_take(folder)
        result_for(folder / STANDING_FILE, take)
    except CalibrationError as exc:
        shutil.rmtree(folder, ignore_errors=True)
        raise CalibrationError(str(exc).replace(f"{folder}/{STANDING_FILE}", source).replace(f"{folder}/", "")
                               .replace(str(folder), "the take")) from None
    except BaseException:
        shutil.rmtree(folder, ignore_errors=True)
        raise
    return folder


@router.post(
    "", status_code=202, response_model=WatchPublic, responses=ERRORS,
    dependencies=[require_content_type("multipart/form-data")],
    summary="Watch a take with a standing result: each camera's health, a moved camera named and re-solved",
    openapi_extra=_form_body({
        "type": "object", "required": [TAKE_FILE],
        "properties": {
            TAKE_FILE: _file_schema("every blob of the take: frame,camera,u,v, no labels (docs/capture-format.md, Takes)"),
            RIG_FILE: _file_schema("the take's rig (default: the capture's rig.json)"),
            STANDING_FILE: _file_schema("the standing wandcal-result/1 (or give job_id)"),
            "job_id": {"type": "string", "description": "a done calibration job whose result is the standing one"},
            "capture_id": {"type": "string", "description": "the capture the take is of (default: job_id's capture)"},
            "write": {"type": "boolean", "description": "also write the updated result (GET /watch/{id}/result)"},
        }}),
)
async def create_watch(request: Request, state: State) -> WatchPublic:
    form = await _form(request, state)
    unknown = sorted(set(form.keys()) - set(PARTS))
    if unknown:
        raise HTTPException(422, f"unknown part {unknown[0]!r}; a watch takes {', '.join(PARTS)}")
    limit = state.settings.max_upload_bytes
    take_text = await _text(form.get(TAKE_FILE), TAKE_FILE, limit)
    if take_text is None:
        raise HTTPException(422, f"no '{TAKE_FILE}' part; upload the take's blobs (frame,camera,u,v)")
    standing, source, job_capture = await run_in_threadpool(
        _standing, state, form, await _text(form.get(STANDING_FILE), STANDING_FILE, limit))
    capture_id = form.get("capture_id") or job_capture
    if not isinstance(capture_id, str):
        raise HTTPException(422, "capture_id: give the capture the take is of (or a job_id, whose capture it is then)")
    try:
        capture = await run_in_threadpool(state.captures.get, capture_id)
    except CaptureNotFound:
        raise HTTPException(404, f"capture_id: no capture with id {capture_id!r}; list captures with GET /api/v1/captures") from None
    rig = await _text(form.get(RIG_FILE), RIG_FILE, limit) or (state.captures.folder(capture.id) / RIG_FILE).read_text()
    write = _flag(form.get("write", ""), "write")
    texts = {RIG_FILE: rig, TAKE_FILE: take_text, STANDING_FILE: standing}
    return await run_in_threadpool(_queue_watch, state, capture.id, texts, source, write)


def _queue_watch(state, capture_id: str, texts: dict[str, str], source: str, write: bool) -> WatchPublic:
    """The take folder stored and checked (:func:`_store_take`), and its watch job queued."""
    folder = _store_take(state, texts, source)
    options = {"folder": str(folder), "write": write, "take_name": f"{TAKES_DIR}/{folder.name}/{TAKE_FILE}",
               "standing_name": source}
    record = state.queue.store.create(capture_id, WATCH_METHOD, options)
    state.queue.submit(record)
    return _public(record)


# -- the live capture watched as it records (service/live_watch.py) ------------------------------
class LiveWatchCreate(BaseModel):
    """The standing result to watch the live capture with: a done calibration job's (``job_id``)
    or a wandcal-result/1 document (``result``), one of them."""

    job_id: str | None = Field(None, max_length=64)
    result: dict[str, Any] | None = None


_live_lock = threading.Lock()


def _live_watch(request: Request):
    return getattr(request.app.state, "live_watch", None)


def _start_live(request: Request, state, body: LiveWatchCreate) -> dict:
    from types import SimpleNamespace

    from wandcal.capture.rig_file import read_rig
    from wandcal.drivers.capture_files import BLOBS_FILE
    from wandcal.service.cli.support.inputs import result_for
    from wandcal.service.live_capture import BUSY
    from wandcal.service.live_watch import LiveWatch

    live = request.app.state.live_capture
    status = live.status()
    if status.state not in BUSY or status.capture_id is None:
        raise HTTPException(409, f"no live capture is recording (it is {status.state.value}); start one with POST "
                                 "/api/v1/capture/start, then watch it")
    if (body.job_id is None) == (body.result is None):
        raise HTTPException(422, "give the standing result: job_id (a done calibration job) or result, one of them")
    if body.job_id is not None:
        standing, source, _ = _standing(state, {"job_id": body.job_id}, None)
    else:
        standing, source = json.dumps(body.result, indent=2) + "\n", "result"
    staging = state.captures.root / f".{status.capture_id}.partial"
    deadline = time.monotonic() + LIVE_RIG_WAIT_S
    while not (staging / RIG_FILE).is_file():  # the recording writes it as it starts
        if time.monotonic() > deadline:
            raise HTTPException(409, f"live capture {status.capture_id} has not started recording yet; try again")
        time.sleep(0.05)
    folder = state.settings.data_dir / TAKES_DIR / f"{LIVE_TAKE_PREFIX}{status.capture_id}"
    folder.mkdir(parents=True, exist_ok=True)
    (folder / STANDING_FILE).write_text(standing)
    rig = read_rig(staging, allow_no_wand=True)
    try:
        _, ordered, R, t, _ = result_for(folder / STANDING_FILE, SimpleNamespace(rig=rig))
    except CalibrationError as exc:
        raise CalibrationError(str(exc).replace(str(folder / STANDING_FILE), source)) from None
    with _live_lock:
        previous = _live_watch(request)
        if previous is not None:
            previous.stop()
        request.app.state.live_watch = LiveWatch(
            status.capture_id, staging / BLOBS_FILE, ordered, R, t, standing=source, folder=folder,
            busy=lambda: live.status().state in BUSY).start()
    return request.app.state.live_watch.status()


@router.post("/live", status_code=202, responses=ERRORS, summary="Watch the live capture as it records: each "
             "camera's health at GET /watch/live, updated every half second")
async def start_live_watch(body: LiveWatchCreate, request: Request, state: State) -> dict:
    return await run_in_threadpool(_start_live, request, state, body)


@router.get("/live", responses=ERRORS, summary="The live capture's health: state (idle, watching, done, failed), the "
            "report so far (as GET /watch/{id}'s) and when it was updated")
async def get_live_watch(request: Request) -> dict:
    watch = _live_watch(request)
    return {"state": "idle"} if watch is None else watch.status() | {"threshold": GLR_THRESHOLD}


def _resolve_live(request: Request, state) -> WatchPublic:
    watch = _live_watch(request)
    if watch is None:
        raise HTTPException(409, "no live capture was watched; start one with POST /api/v1/watch/live")
    if watch.status()["state"] != "done":
        raise HTTPException(409, f"live capture {watch.capture_id} is still recording: the re-solve uses the whole take, "
                                 "so stop the capture (POST /api/v1/capture/stop) first")
    try:
        folder = state.captures.folder(state.captures.get(watch.capture_id).id)
    except CaptureNotFound:
        raise HTTPException(409, f"live capture {watch.capture_id} was not stored (its recording failed); "
                                 "nothing to re-solve from") from None
    from wandcal.drivers.capture_files import BLOBS_FILE

    texts = {RIG_FILE: (folder / RIG_FILE).read_text(), TAKE_FILE: (folder / BLOBS_FILE).read_text(),
             STANDING_FILE: (watch.folder / STANDING_FILE).read_text()}
    return _queue_watch(state, watch.capture_id, texts, watch.standing, True)


@router.post("/live/resolve", status_code=202, response_model=WatchPublic, responses=ERRORS,
             summary="Re-solve the moved cameras of the live capture just recorded: a watch job (write=true) on its "
                     "blobs, read as GET /watch/{id}")
async def resolve_live(request: Request, state: State) -> WatchPublic:
    return await run_in_threadpool(_resolve_live, request, state)


@router.get("/{job_id}", response_model=WatchPublic, responses=ERRORS,
            summary="A watch's state, progress and, once done, each camera's health")
async def get_watch(job_id: str, state: State) -> WatchPublic:
    return _public(await run_in_threadpool(_record, state, job_id))


@router.delete("/{job_id}", response_model=WatchPublic, responses=ERRORS, summary="Cancel a watch that has not finished")
async def cancel_watch(job_id: str, state: State) -> WatchPublic:
    record = await run_in_threadpool(_record, state, job_id)
    if not record.state.finished:
        record = await run_in_threadpool(_cancel, state, record)
    return _public(record)


def _cancel(state, record: JobRecord) -> JobRecord:
    return state.queue.cancel(record.id) or record  # None only if its row went meanwhile


@router.get("/{job_id}/result", responses=ERRORS,
            summary="The updated wandcal-result/1: the moved cameras re-solved from the take, with a record "
                    "(`watch`) of the take and the standing result it was derived from")
async def get_watch_result(job_id: str, state: State) -> dict:
    record = await run_in_threadpool(_record, state, job_id)
    if record.state is not JobState.done or record.result is None:
        raise HTTPException(409, f"watch {job_id} is {record.state.value}, it has no result"
                                 + (f": {record.error}" if record.error else "; poll GET /api/v1/watch/{id}"))
    if "result" not in record.result:
        raise HTTPException(409, f"watch {job_id} was not asked to write the updated result; start it with write=true")
    return record.result["result"]



