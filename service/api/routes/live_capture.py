"""Live capture's routes: start, status, change, continue and stop (the state machine they drive:
:class:`wandcal.service.live_capture.LiveCapture`)."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, Request
from fastapi.concurrency import run_in_threadpool

from wandcal.service.api.deps import State
from wandcal.service.live_capture import LiveCapture
from wandcal.service.schemas import ErrorPublic, LiveCaptureCreate, LiveCapturePublic, LiveCaptureUpdate

router = APIRouter(prefix="/capture", tags=["live capture"])

ERRORS: dict[int | str, dict[str, Any]] = {
    401: {"model": ErrorPublic, "description": "missing or wrong bearer token"},
    409: {"model": ErrorPublic, "description": "a live capture is already running, or none is"},
}


def get_live(request: Request) -> LiveCapture:
    return request.app.state.live_capture


Live = Annotated[LiveCapture, Depends(get_live)]


@router.post(
    "/start", status_code=202, response_model=LiveCapturePublic,
    responses=ERRORS | {422: {"model": ErrorPublic, "description": "invalid settings, or a camera or the trigger "
                                                                   "cannot be opened (the driver's message)"}},
    summary="Start recording from cameras (and a trigger) into a new capture",
)
async def start_capture(body: LiveCaptureCreate, live: Live, state: State) -> LiveCapturePublic:
    """Answers once the devices are open; ``capture_id`` is the capture it becomes when done."""
    return await run_in_threadpool(live.start, body, state.settings.guidance)


@router.get("", response_model=LiveCapturePublic, responses={401: ERRORS[401]},
            summary="The live capture's state, frame sets recorded, rate and dropped frames")
def capture_status(live: Live) -> LiveCapturePublic:
    return live.status()


@router.patch("", response_model=LiveCapturePublic,
              responses={401: ERRORS[401], 409: {"model": ErrorPublic, "description": "no live capture is running, "
                                                 "or it has no guidance"}},
              summary="Change a running live capture: stop it by itself once the guidance says enough")
def change_capture(body: LiveCaptureUpdate, live: Live) -> LiveCapturePublic:
    """The page's "stop when enough" switch: the capture then ends complete (state ``done``) at the
    first batch of wand sets after the guidance says enough."""
    return live.set_stop_when_enough(body.stop_when_enough)


@router.post("/continue", status_code=202, response_model=LiveCapturePublic,
             responses={401: ERRORS[401], 409: {"model": ErrorPublic, "description": "no live capture is waiting "
                                                "for the wand (state waiting_for_wand)"}},
             summary="Record the wand: the L-frame is out of the volume and the wand is in hand")
def continue_capture(live: Live) -> LiveCapturePublic:
    """After the static recording a capture waits in ``waiting_for_wand``; this starts its wand run."""
    return live.resume()


@router.post("/stop", status_code=202, response_model=LiveCapturePublic, responses=ERRORS,
             summary="Stop the live capture, keeping what was recorded; it is then detected and stored")
def stop_capture(live: Live) -> LiveCapturePublic:
    """While ``waiting_for_wand`` this ends the capture with its static recording alone."""
    return live.stop()
