"""``create_app(settings)``: the FastAPI application. Nothing is created at import time.

Run it with ``wandcal serve`` or ``uvicorn --factory wandcal.service.main:app_from_env``.
"""

from __future__ import annotations

import logging
import shutil
import sqlite3
import time
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import Depends, FastAPI, HTTPException, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse
from fastapi.staticfiles import StaticFiles
from threadpoolctl import threadpool_limits

from wandcal.calib.errors import CalibrationError
from wandcal.service.api.deps import AppState, require_token
from wandcal.service.api.routes import blobsets, captures, checks, guidance, health, jobs, live_capture, watch
from wandcal.service.api.security import CrossSiteGuard, HostGuard, RelativePaths
from wandcal.service.connection_limits import install_repeat_filter
from wandcal.service.datafolder.lock import hold_data_folder
from wandcal.service.datafolder.recovery import recover
from wandcal.service.datafolder.retention import Pruner, Retention
from wandcal.service.db import disk_full, init_db
from wandcal.service.jobs.queue import JobQueue, QueueUnavailable, SQLiteQueue
from wandcal.service.jobs.records import JobStore
from wandcal.service.live_capture import BUSY, LiveCapture
from wandcal.service.request_limits import BodySizeLimit, RateLimiter
from wandcal.service.settings import Settings
from wandcal.service.storage import CaptureNotFound, CaptureStore, ReplayPathError

API_PREFIX = "/api/v1"
STATIC_DIR = Path(__file__).parent / "static"
log = logging.getLogger("wandcal.service")
RETRY_AFTER_S = 5  # a busy database frees in milliseconds, a full disk when someone acts: ask again soon
# On shutdown a live capture is stopped and given this long to store what it recorded (it stops at
# its next frame set and registers the folder); past it, the next start recovers the staging folder.
LIVE_STOP_S = 1.5


def _queue(settings: Settings, store: JobStore, capture_store: CaptureStore) -> JobQueue:
    if settings.queue == "redis":
        from wandcal.service.jobs.redis_queue import PAYLOAD_FILES, RedisQueue

        def read_files(capture_id: str) -> dict[str, str | None]:
            folder = capture_store.folder(capture_id)
            return {name: (folder / name).read_text() if (folder / name).is_file() else None for name in PAYLOAD_FILES}

        return RedisQueue(store, read_files, settings.redis_url, settings.redis_queue_name)
    return SQLiteQueue(store, capture_store.load, settings.data_dir, settings.workers)


def _validation_message(exc: RequestValidationError) -> str:
    parts = []
    for err in exc.errors():
        where = ".".join(str(p) for p in err.get("loc", ()) if p != "body") or "body"
        if err.get("type") == "json_invalid":
            parts.append(f"the body is not valid JSON ({err.get('ctx', {}).get('error', 'parse error')})")
        else:
            parts.append(f"{where}: {err.get('msg')}")
    return "; ".join(parts) or "invalid request"


def create_app(settings: Settings) -> FastAPI:
    """Build the app: database, capture store, job queue (started with the app), routes and page."""
    data_dir = settings.data_dir.resolve()
    settings = settings.model_copy(update={"data_dir": data_dir})
    folder_lock = hold_data_folder(settings)  # before anything reads or writes the folder: one owner recovers it
    install_repeat_filter()
    init_db(settings.db_path)  # a corrupt database is moved aside; recover() registers the captures again
    capture_store = CaptureStore(data_dir, settings.db_path, settings.replay_root)
    recover(capture_store, data_dir)
    log.info("data folder %s (database %s; captures, results and reports in it)", data_dir, settings.db_path.name)
    if settings.replay_root is None:
        log.info("no replay root: POST /captures takes uploads only (set WANDCAL_REPLAY_ROOT to name folders)")
    else:
        log.info("replay root %s: POST /captures and replay:// cameras may name capture folders under it",
                 settings.replay_root.resolve())
    queue = _queue(settings, JobStore(settings.db_path), capture_store)
    pruner = Pruner(data_dir, settings.db_path, Retention(settings.keep_results_days, settings.keep_captures_days))

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        # one connection held open for the app's life keeps the WAL's -shm file in place: without
        # it the last connection's close removes it and the next open must create it, which fails
        # on a full disk and would turn every read into an I/O error (tests/reliability, full disk)
        keeper = sqlite3.connect(settings.db_path)
        keeper.execute("SELECT COUNT(*) FROM captures").fetchall()  # maps the -shm file now
        # BLAS on one thread while the app serves, set here and never by a request: the request
        # threads already share the cores, and the solvers' `threadpool_limits(1)` (guidance runs
        # one in a request thread) then have nothing to change, so concurrent ones cannot leave the
        # process-wide count altered (tests/reliability/test_global_state.py). Restored when the
        # app stops, so a process that builds an app (a test) keeps its own BLAS afterwards.
        one_blas_thread = threadpool_limits(limits=1, user_api="blas")
        queue.start()
        pruner.start()
        try:
            yield
        finally:
            pruner.stop()
            _stop_live_capture(app.state.live_capture)
            queue.stop()
            one_blas_thread.restore_original_limits()
            keeper.close()

    app = FastAPI(
        title="wandcal",
        summary="Capture-and-calibrate service for multi-camera motion-capture rigs",
        version="1",
        lifespan=lifespan,
    )
    app.state.folder_lock = folder_lock  # held while the app lives (service/datafolder/lock.py)
    app.state.wandcal = AppState(
        settings=settings, captures=capture_store, queue=queue, limiter=RateLimiter(settings.framesets_per_second)
    )
    _add_middleware(app, settings, data_dir)
    secured = [Depends(require_token)]
    app.include_router(health.router, prefix=API_PREFIX)
    app.include_router(captures.router, prefix=API_PREFIX, dependencies=secured)
    app.include_router(blobsets.router, prefix=API_PREFIX, dependencies=secured)
    app.include_router(jobs.router, prefix=API_PREFIX, dependencies=secured)
    app.state.live_capture = LiveCapture(capture_store, settings.capture_continue_timeout_s)
    app.include_router(live_capture.router, prefix=API_PREFIX, dependencies=secured)
    app.include_router(guidance.router, prefix=API_PREFIX, dependencies=secured)
    app.include_router(checks.router, prefix=API_PREFIX, dependencies=secured)
    app.include_router(watch.router, prefix=API_PREFIX, dependencies=secured)
    _add_error_handlers(app, data_dir)

    @app.get("/", include_in_schema=False)
    def page() -> FileResponse:
        return FileResponse(STATIC_DIR / "index.html", media_type="text/html")

    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")
    return app


def _add_middleware(app: FastAPI, settings: Settings, data_dir: Path) -> None:
    """The request guards, innermost first: body size, relative paths, cross-site, host."""
    app.add_middleware(BodySizeLimit, max_bytes=settings.max_upload_bytes)
    roots = [str(data_dir)] + ([str(settings.replay_root.resolve())] if settings.replay_root else [])
    app.add_middleware(RelativePaths, roots=roots)
    app.add_middleware(CrossSiteGuard, has_token=settings.token is not None)
    app.add_middleware(HostGuard, bound=settings.host, allowed=settings.allowed_hosts)  # outermost: first


def _add_error_handlers(app: FastAPI, data_dir: Path) -> None:
    """Each error an answer: 422 for bad input, 404/403 for captures and paths, 507 for a full disk,
    503 for a busy database, 500 (logged) for a bug."""

    @app.exception_handler(RequestValidationError)
    async def invalid_request(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = [{k: v for k, v in e.items() if k in ("loc", "msg", "type")} for e in exc.errors()]
        return JSONResponse({"detail": _validation_message(exc), "errors": errors}, status_code=422)

    @app.exception_handler(CalibrationError)
    async def bad_capture(request: Request, exc: CalibrationError) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=422)

    @app.exception_handler(CaptureNotFound)
    async def no_capture(request: Request, exc: CaptureNotFound) -> JSONResponse:
        return JSONResponse({"detail": f"no capture with id {str(exc)!r}"}, status_code=404)

    @app.exception_handler(ReplayPathError)
    async def outside_root(request: Request, exc: ReplayPathError) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=403)

    @app.exception_handler(OSError)
    async def disk_error(request: Request, exc: OSError) -> JSONResponse:
        if disk_full(exc):
            return _disk_full(request, exc, data_dir)
        return await internal(request, exc)

    @app.exception_handler(sqlite3.OperationalError)
    async def database_error(request: Request, exc: sqlite3.OperationalError) -> JSONResponse:
        if disk_full(exc):
            return _disk_full(request, exc, data_dir)
        log.error("database error on %s %s: %s", request.method, request.url.path, exc)
        return JSONResponse({"detail": f"the database is busy or unavailable ({exc}); retry in a few seconds"},
                            status_code=503, headers={"Retry-After": str(RETRY_AFTER_S)})

    @app.exception_handler(QueueUnavailable)
    async def queue_away(request: Request, exc: QueueUnavailable) -> JSONResponse:
        return JSONResponse({"detail": f"{exc}; job records can still be read"}, status_code=503,
                            headers={"Retry-After": str(max(1, round(exc.retry_after_s)))})

    @app.exception_handler(Exception)
    async def internal(request: Request, exc: Exception) -> JSONResponse:
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return JSONResponse(
            {"detail": f"internal error ({type(exc).__name__}); this is a bug, the server log has the details"},
            status_code=500,
        )


def _stop_live_capture(live: LiveCapture, timeout_s: float = LIVE_STOP_S) -> None:
    """Stop a live capture that is recording or waiting, and wait (briefly) until it has ended."""
    try:
        live.stop()
    except HTTPException:
        return  # none is running
    deadline = time.monotonic() + timeout_s
    while live.status().state in BUSY and time.monotonic() < deadline:
        time.sleep(0.02)


def _disk_full(request: Request, exc: BaseException, data_dir: Path) -> JSONResponse:
    free = shutil.disk_usage(data_dir).free
    log.error("disk full on %s %s: %s", request.method, request.url.path, exc)
    return JSONResponse(
        {"detail": f"the data directory's disk is full ({free} bytes free); nothing of this request was stored. "
                   "Free some space (or move WANDCAL_DATA_DIR to a larger disk) and send it again"},
        status_code=507, headers={"Retry-After": str(RETRY_AFTER_S)},
    )


def app_from_env() -> FastAPI:
    """Factory for ``uvicorn --factory``: settings from ``WANDCAL_*`` and ``$WANDCAL_CONFIG``."""
    return create_app(Settings.load())
