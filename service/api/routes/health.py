"""Liveness and what this server can do."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

from fastapi import APIRouter

from wandcal.service.api.deps import State
from wandcal.service.jobs.records import JobState
from wandcal.service.schemas import Health

router = APIRouter(tags=["health"])


def _version() -> str:
    try:
        return version("wandcal")
    except PackageNotFoundError:
        return "0+unknown"


@router.get("/health", response_model=Health, summary="Liveness, queue depth and available stages")
def health(state: State) -> Health:
    store = state.queue.store
    return Health(
        version=_version(),
        queue=state.settings.queue,
        workers=state.settings.workers,
        jobs_queued=store.count(JobState.queued),
        jobs_running=store.count(JobState.running),
    )
