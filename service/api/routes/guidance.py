"""Wanding guidance for any capture: where each camera still needs the wand, and whether to stop."""

from __future__ import annotations

import threading
from typing import Annotated, Literal

from fastapi import APIRouter, HTTPException, Query, Request

from wandcal.service.api.deps import State
from wandcal.service.guidance_cache import GuidanceBoard
from wandcal.service.schemas import ErrorPublic, GuidancePublic
from wandcal.service.storage import CaptureNotFound

router = APIRouter(prefix="/captures", tags=["guidance"])
SyncMode = Literal["none", "auto"]  # as the job option "sync" (wandcal.calib.solve.sync.SYNC_MODES)
_board_lock = threading.Lock()


def _board(request: Request, state) -> GuidanceBoard:
    """The app's board, made on first use (the app holds it in its state)."""
    with _board_lock:
        board = getattr(request.app.state, "guidance_board", None)
        if board is None:
            board = request.app.state.guidance_board = GuidanceBoard(state.captures, state.settings.guidance)
        return board


@router.get(
    "/{capture_id}/guidance",
    response_model=GuidancePublic,
    responses={401: {"model": ErrorPublic, "description": "missing or wrong bearer token"},
               404: {"model": ErrorPublic, "description": "unknown capture"},
               422: {"model": ErrorPublic, "description": "a capture the guidance cannot judge (no wand)"}},
    summary="Wanding guidance: per camera frames, image coverage, links and predicted centre 1-sigma; enough?",
)
def get_guidance(capture_id: str, request: Request, state: State,
                 sync: Annotated[SyncMode, Query(description="auto: cameras without a trigger, their frames "
                                                 "realigned by the offsets found from the wand (docs/sync.md)")] = "none") -> dict:
    """For a stored capture, or for the live capture while it records (``capture_id`` as announced
    by ``POST /capture/start``; the document then has ``live: true`` and updates every second or
    so). ``enough`` is true when every camera's ``center_std_mm`` is below the target and its
    coverage reaches the goal (settings group ``guidance``; docs/api.md)."""
    document = request.app.state.live_capture.guidance_for(capture_id)
    if document is not None:
        return document
    try:
        return _board(request, state).get(capture_id, sync)
    except CaptureNotFound:
        raise HTTPException(404, f"no capture with id {capture_id!r}; list captures with GET /api/v1/captures, "
                                 "or GET /api/v1/capture for the live one") from None
