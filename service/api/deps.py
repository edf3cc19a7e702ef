"""Named dependencies of the routes (``Annotated`` aliases) and the state they draw on."""

from __future__ import annotations

import secrets
from dataclasses import dataclass
from typing import Annotated
from urllib.parse import unquote

from fastapi import Depends, HTTPException, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from wandcal.service.jobs.queue import JobQueue
from wandcal.service.request_limits import RateLimiter
from wandcal.service.settings import Settings
from wandcal.service.storage import CaptureNotFound, CaptureRow, CaptureStore


@dataclass
class AppState:
    settings: Settings
    captures: CaptureStore
    queue: JobQueue
    limiter: RateLimiter


def get_state(request: Request) -> AppState:
    return request.app.state.wandcal


State = Annotated[AppState, Depends(get_state)]

_bearer = HTTPBearer(auto_error=False, description="required when the server was given a token (WANDCAL_TOKEN)")
# The page sets this cookie (SameSite=Strict) beside its Authorization header, so that a link it
# opens in a tab of its own (a job's report and its images) is let in. It is honoured for reads
# only (GET, HEAD): a request that changes anything needs the header, so a cookie cannot be
# ridden into one, and SameSite keeps other sites from sending it at all.
TOKEN_COOKIE = "wandcal_token"
SAFE_METHODS = ("GET", "HEAD")


def require_token(
    state: State, request: Request, credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)]
) -> None:
    expected = state.settings.token
    if expected is None:
        return
    challenge = {"WWW-Authenticate": "Bearer"}
    if credentials is not None:
        given = credentials.credentials
    elif request.method in SAFE_METHODS and TOKEN_COOKIE in request.cookies:
        given = unquote(request.cookies[TOKEN_COOKIE])  # the page percent-encodes it
    else:
        raise HTTPException(401, "missing bearer token; send 'Authorization: Bearer <token>'", headers=challenge)
    if not secrets.compare_digest(given.encode(), expected.encode()):
        raise HTTPException(401, "wrong bearer token; use the token the server was started with", headers=challenge)


def get_capture(capture_id: str, state: State) -> CaptureRow:
    try:
        return state.captures.get(capture_id)
    except CaptureNotFound:
        raise HTTPException(
            404, f"no capture with id {capture_id!r}; list captures with GET /api/v1/captures"
        ) from None


CaptureDep = Annotated[CaptureRow, Depends(get_capture)]


def require_content_type(*kinds: str):
    """A dependency refusing other request content types with 415 and the expected one."""

    def check(request: Request) -> None:
        given = request.headers.get("content-type", "").split(";")[0].strip().lower()
        if given not in kinds:
            raise HTTPException(
                415, f"Content-Type must be {' or '.join(kinds)}, not {given or 'missing'!r}"
            )

    return Depends(check)
