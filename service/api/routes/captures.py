"""Captures: upload or replay a points-level capture, stream frame sets in, solve the static object."""

from __future__ import annotations

import re
from typing import Any

import numpy as np
from fastapi import APIRouter, HTTPException, Request
from fastapi.concurrency import run_in_threadpool
from starlette.datastructures import FormData, UploadFile

from wandcal.calib.rig import StaticObservations
from wandcal.calib.start.static import solve_static
from wandcal.capture.csv_tables import decode_text
from wandcal.capture.world_references import reference_clash
from wandcal.drivers.capture_files import (
    AXIS_FILE,
    DROP_FILE,
    FLOOR_FILE,
    POINTS_FILE,
    RIG_FILE,
    STATIC_FILE,
    WAND_FILE,
)
from wandcal.service.api.deps import CaptureDep, State, require_content_type
from wandcal.service.schemas import (
    CameraCoverage,
    CaptureList,
    CapturePublic,
    ErrorPublic,
    FrameSetPublic,
    StaticCameraPublic,
    StaticSolutionPublic,
)
from wandcal.service.storage import CaptureRow, DuplicateFrameSet, ReplayPathError

router = APIRouter(prefix="/captures", tags=["captures"])

WHOLE = re.compile(r"^[0-9]{1,12}$")  # ASCII digits only; 12 digits outlast any real frame counter
FORM = ("multipart/form-data", "application/x-www-form-urlencoded")
UPLOAD_PARTS = (RIG_FILE, WAND_FILE, STATIC_FILE, POINTS_FILE, AXIS_FILE, FLOOR_FILE, DROP_FILE, "path")  # POST /captures' form fields
MAX_STATIC_IMAGES_PER_CAMERA = 100  # averaging beyond ~100 frames gains nothing (noise falls as 1/sqrt(N))
ERRORS: dict[int | str, dict[str, Any]] = {
    400: {"model": ErrorPublic, "description": "malformed request"},
    401: {"model": ErrorPublic, "description": "missing or wrong bearer token"},
    404: {"model": ErrorPublic, "description": "unknown capture"},
    413: {"model": ErrorPublic, "description": "request body over the upload limit"},
    415: {"model": ErrorPublic, "description": "wrong Content-Type"},
    422: {"model": ErrorPublic, "description": "invalid capture data; the message names the file, line and field"},
}


def _file_schema(description: str) -> dict:
    return {"type": "string", "format": "binary", "description": description}


def _form_body(multipart: dict, urlencoded: dict | None = None, required: bool = True) -> dict:
    """OpenAPI text for a form body the route parses itself (field names are camera ids or file names)."""
    content = {"multipart/form-data": {"schema": multipart}}
    if urlencoded is not None:
        content["application/x-www-form-urlencoded"] = {"schema": urlencoded}
    return {"requestBody": {"required": required, "content": content}}


def to_public(row: CaptureRow, coverage: dict | None = None) -> CapturePublic:
    coverage = coverage or {}
    return CapturePublic(
        id=row.id, created=row.created, source=row.source, name=row.name, cameras=row.cameras, frames=row.frames,
        framesets=row.framesets, has_static=row.has_static,
        coverage=[
            CameraCoverage(id=c, framesets=coverage.get(c), **row.counts.get(c, {"blobs": 0, "pairs": 0}))
            for c in row.cameras
        ],
        static_solution=row.static_solution,
    )


async def _text(value, name: str, limit: int) -> str | None:
    if value is None:
        return None
    data = await value.read() if isinstance(value, UploadFile) else value.encode()
    if len(data) > limit:
        raise HTTPException(413, f"{name} is larger than the upload limit of {limit} bytes")
    return decode_text(data, name)  # the CLI's decoder: a byte-order mark is read alike by both


async def _form(request: Request, state) -> FormData:
    return await request.form(max_files=256, max_fields=256, max_part_size=state.settings.max_upload_bytes)


@router.post(
    "",
    status_code=201,
    response_model=CapturePublic,
    responses=ERRORS | {403: {"model": ErrorPublic, "description": "replay path outside the replay root"}},
    dependencies=[require_content_type(*FORM)],
    summary="Upload a points-level capture, or copy one from the replay root",
    openapi_extra=_form_body(
        {
            "type": "object",
            "properties": {
                RIG_FILE: _file_schema("the rig description (wandcal-capture/1)"),
                WAND_FILE: _file_schema("wand blobs: frame,camera,u,v; omit to stream frame sets later"),
                STATIC_FILE: _file_schema("static-object blobs: camera,u,v"),
                POINTS_FILE: _file_schema("point tracks: frame,camera,u,v[,point]; a capture without a wand "
                                          "needs them (rig.json without wand.length_m)"),
                AXIS_FILE: _file_schema("axis points: role,camera,u,v"),
                FLOOR_FILE: _file_schema("floor points that set the vertical: point,camera,u,v"),
                DROP_FILE: _file_schema("a dropped object's track that sets the vertical (gravity): frame,camera,u,v"),
                "path": {"type": "string", "description": "a capture folder under the replay root"},
            },
        },
        urlencoded={"type": "object", "properties": {"path": {"type": "string"}}, "required": ["path"]},
    ),
)
async def create_capture(request: Request, state: State) -> CapturePublic:
    """Give either the files (``rig.json``, optional ``wand.csv``, ``static.csv``, ``points.csv`` and
    ``axis.csv``, and ``floor.csv`` or ``drop.csv``) or ``path``; any other part is refused (422), never dropped.

    A capture from ``rig.json`` alone starts empty and fills from ``POST /captures/{id}/framesets``.
    """
    form = await _form(request, state)
    limit = state.settings.max_upload_bytes
    unknown = sorted(set(form.keys()) - set(UPLOAD_PARTS))
    if unknown:
        raise HTTPException(422, f"unknown part {unknown[0]!r}; a capture upload takes {', '.join(UPLOAD_PARTS)} "
                                 "(docs/capture-format.md)")
    path = form.get("path")
    if path is not None:
        if form.get(RIG_FILE) is not None:
            raise HTTPException(422, "give either 'path' or the capture files, not both")
        if not isinstance(path, str) or not path.strip():
            raise HTTPException(422, "'path' must be a folder name under the replay root")
        try:
            row = await run_in_threadpool(state.captures.create_from_replay, path.strip())
        except ReplayPathError as exc:
            raise HTTPException(403, str(exc)) from None
        return to_public(row)
    rig_text = await _text(form.get(RIG_FILE), RIG_FILE, limit)
    if rig_text is None:
        raise HTTPException(422, f"no '{RIG_FILE}' part; upload rig.json (and wand.csv), or name a replay 'path'")
    wand_text = await _text(form.get(WAND_FILE), WAND_FILE, limit)
    static_text = await _text(form.get(STATIC_FILE), STATIC_FILE, limit)
    points_text = await _text(form.get(POINTS_FILE), POINTS_FILE, limit)
    axis_text = await _text(form.get(AXIS_FILE), AXIS_FILE, limit)
    floor_text = await _text(form.get(FLOOR_FILE), FLOOR_FILE, limit)
    drop_text = await _text(form.get(DROP_FILE), DROP_FILE, limit)
    # the world-reference rule on the parts given (the store applies it again to the parts with rows)
    clash = reference_clash([name for name, text in ((FLOOR_FILE, floor_text), (DROP_FILE, drop_text)) if text is not None])
    if clash is not None:
        raise HTTPException(422, f"{clash.at_fault}: {clash.message('this upload')}")
    vertical = (FLOOR_FILE, floor_text) if floor_text is not None else (DROP_FILE, drop_text) if drop_text is not None else None
    row = await run_in_threadpool(state.captures.create_from_texts, rig_text, wand_text, static_text, "upload",
                                  points_text, axis_text, vertical)
    return to_public(row)


@router.get("", response_model=CaptureList, responses={401: ERRORS[401]}, summary="List captures, newest first")
def list_captures(state: State) -> CaptureList:
    return CaptureList(captures=[to_public(r) for r in state.captures.newest()])


@router.get(
    "/{capture_id}", response_model=CapturePublic, responses={401: ERRORS[401], 404: ERRORS[404]},
    summary="A capture's summary and detection coverage per camera",
)
def get_capture(capture: CaptureDep, state: State) -> CapturePublic:
    return to_public(capture, state.captures.frameset_coverage(capture.id))


@router.post(
    "/{capture_id}/framesets",
    status_code=201,
    response_model=FrameSetPublic,
    responses=ERRORS | {
        409: {"model": ErrorPublic, "description": "frame already received, or capture not streamable"},
        429: {"model": ErrorPublic, "description": "frame sets arriving faster than the configured rate"},
    },
    dependencies=[require_content_type("multipart/form-data")],
    summary="Add one synchronised frame set: one image per camera; detection runs on arrival",
    openapi_extra=_form_body(
        {
            "type": "object",
            "properties": {
                "frame": {"type": "integer", "minimum": 0, "description": "frame-set index"},
                "trigger_count": {"type": "integer", "minimum": 0},
            },
            "additionalProperties": _file_schema("the image of the camera named by the field"),
            "required": ["frame"],
        }
    ),
)
async def add_frameset(capture: CaptureDep, request: Request, state: State) -> FrameSetPublic:
    """Cameras whose image shows exactly two blobs add both to the capture's wand observations."""
    wait = state.limiter.take(capture.id)
    if wait > 0:
        raise HTTPException(
            429,
            f"frame sets for capture {capture.id} arrive faster than {state.settings.framesets_per_second:g} "
            f"per second; retry in {wait:.2f} s or raise WANDCAL_FRAMESETS_PER_SECOND",
            headers={"Retry-After": str(max(1, round(wait)))},
        )
    form = await _form(request, state)
    frame = _whole(form.get("frame"), "frame")
    trigger = _optional_whole(form.get("trigger_count"), "trigger_count")
    images = {}
    for key, value in form.multi_items():
        if key in ("frame", "trigger_count"):
            continue
        if key not in capture.cameras:
            raise HTTPException(422, f"field {key!r} is not a camera of this capture; cameras: {', '.join(capture.cameras)}")
        if not isinstance(value, UploadFile):
            raise HTTPException(422, f"field {key!r} must be an image file, not text")
        if key in images:
            raise HTTPException(422, f"camera {key!r} has more than one image in this frame set")
        images[key] = await value.read()
    if not images:
        raise HTTPException(422, "the frame set holds no images; send one image per camera, field name = camera id")
    rig = await run_in_threadpool(state.captures.rig, capture.id)
    cameras = {c.id: c for c in rig.cameras}
    from wandcal.service.ingest import detect_frameset

    blobs = await run_in_threadpool(detect_frameset, images, cameras, state.settings.detect.config())
    try:
        await run_in_threadpool(state.captures.append_frameset, capture.id, frame, trigger, blobs)
    except DuplicateFrameSet as exc:
        raise HTTPException(409, str(exc)) from None
    return FrameSetPublic(
        capture_id=capture.id, frame=frame, blobs={c: len(uv) for c, uv in blobs.items()},
        wand_cameras=[c for c, uv in blobs.items() if len(uv) == 2],
    )


@router.post(
    "/{capture_id}/static",
    response_model=StaticSolutionPublic,
    responses=ERRORS,
    summary="Detect the static object (optional images) and solve each camera's pose by PnP",
    openapi_extra=_form_body(
        {
            "type": "object",
            "additionalProperties": {
                "type": "array",
                "items": _file_schema("images of the static object alone from the named camera"),
            },
        },
        required=False,
    ),
)
async def solve_static_object(capture: CaptureDep, request: Request, state: State) -> StaticSolutionPublic:
    """With images (field name = camera id, repeat for several frames), the static markers are
    detected and averaged, replacing static.csv; without a body, the capture's static.csv is used.
    Returns each camera's initial pose and PnP residual, or why PnP failed."""
    loaded = await run_in_threadpool(state.captures.load, capture.id)
    rig = loaded.rig
    if rig.static_markers is None:
        raise HTTPException(
            422, "rig.json has no 'static_object.markers_m'; describe the static object to solve its pose"
        )
    static = loaded.static
    content_type = request.headers.get("content-type", "")
    if content_type.startswith("multipart/form-data"):
        static = await _static_from_images(request, state, capture, rig)
    elif int(request.headers.get("content-length") or 0) > 0:
        raise HTTPException(415, "send the static-object images as multipart/form-data, or send no body")
    if static is None:
        raise HTTPException(
            422, "the capture has no static.csv; upload one with the capture, or send images of the static object"
        )
    poses = await run_in_threadpool(solve_static, rig, static)
    solution = StaticSolutionPublic(cameras=[_static_camera(cam.id, pose) for cam, pose in zip(rig.cameras, poses)])
    await run_in_threadpool(state.captures.set_static_solution, capture.id, solution.model_dump())
    return solution


async def _static_from_images(request: Request, state, capture: CaptureRow, rig) -> StaticObservations:
    form = await _form(request, state)
    images: dict[str, list[bytes]] = {}
    for key, value in form.multi_items():
        if key not in capture.cameras:
            raise HTTPException(422, f"field {key!r} is not a camera of this capture; cameras: {', '.join(capture.cameras)}")
        if not isinstance(value, UploadFile):
            raise HTTPException(422, f"field {key!r} must be an image file, not text")
        images.setdefault(key, []).append(await value.read())
        if len(images[key]) > MAX_STATIC_IMAGES_PER_CAMERA:
            raise HTTPException(422, f"camera {key!r}: more than {MAX_STATIC_IMAGES_PER_CAMERA} static images")
    if not images:
        raise HTTPException(422, "no images; send images of the static object, field name = camera id")
    from wandcal.service.ingest import detect_static, static_observations

    markers = await run_in_threadpool(detect_static, images, {c.id: c for c in rig.cameras},
                                      state.settings.detect.config())
    static = static_observations(markers, rig)
    await run_in_threadpool(state.captures.set_static, capture.id, static, rig)
    return static


def _static_camera(camera_id: str, pose) -> StaticCameraPublic:
    if not pose:
        return StaticCameraPublic(id=camera_id, ok=False, reason=str(getattr(pose, "reason", pose)))
    R, t = np.asarray(pose.R, float), np.asarray(pose.t, float)
    return StaticCameraPublic(
        id=camera_id, ok=True, R=R.tolist(), t=t.tolist(), center=(-R.T @ t).tolist(), rms_px=float(pose.rms_px)
    )


def _whole(value, name: str) -> int:
    """A required whole-number form field; 422 naming it when missing or malformed."""
    if value is None:
        raise HTTPException(422, f"missing form field {name!r}; give the frame-set index as a whole number")
    return _whole_number(value, name)


def _optional_whole(value, name: str) -> int | None:
    """An optional whole-number form field: None when absent."""
    return None if value is None else _whole_number(value, name)


def _whole_number(value, name: str) -> int:
    if not isinstance(value, str) or not WHOLE.match(value.strip()):
        raise HTTPException(422, f"form field {name!r} must be a whole number >= 0, got {str(value)[:40]!r}")
    return int(value)
