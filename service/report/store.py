"""Reports of the service's finished jobs: drawn on first request into the data folder, then kept.

Layout: ``<data_dir>/reports/<job id>/{index.html, *.png}``. A job's result never changes once it
is done, so a report is drawn once. It is drawn into a staging folder and renamed into place, so
a crash or a concurrent request never leaves a half report to serve.
"""

from __future__ import annotations

import shutil
import threading
import uuid
from collections.abc import Callable
from pathlib import Path

from wandcal.capture.folder import Capture
from wandcal.capture.result_file import result_from_json
from wandcal.service.report import FILE_NAME, INDEX, write_report

REPORTS_DIR = "reports"
MEDIA_TYPES = {".png": "image/png", ".html": "text/html; charset=utf-8"}
_locks: dict[str, threading.Lock] = {}
_locks_guard = threading.Lock()


def report_folder(data_dir: Path, job_id: str) -> Path:
    return Path(data_dir) / REPORTS_DIR / job_id


def rendered_report(data_dir: Path, job_id: str, result: dict, load_capture: Callable[[], Capture | None]) -> Path:
    """The folder of the job's report, drawn now if it is not there yet.

    Args:
        data_dir: the service's data folder.
        job_id: a job id the job store gave (never a raw request string).
        result: the job's ``wandcal-result/1`` document.
        load_capture: returns the job's capture, or None when the service no longer has it.

    Raises:
        ReportUnavailable: matplotlib is not installed on the server.
        CaptureFormatError: the stored result does not read back.
    """
    folder = report_folder(data_dir, job_id)
    if (folder / INDEX).is_file():
        return folder
    with _lock(job_id):
        if (folder / INDEX).is_file():  # drawn by the request this one waited for
            return folder
        parsed = result_from_json(result, f"the result of job {job_id}")
        staging = folder.parent / f".{job_id}.{uuid.uuid4().hex}.partial"
        try:
            write_report(parsed, load_capture(), staging)
            try:
                staging.rename(folder)
            except OSError:
                if not (folder / INDEX).is_file():  # not another process's report: a real failure
                    raise
        finally:
            shutil.rmtree(staging, ignore_errors=True)
    return folder


def report_file(folder: Path, name: str) -> Path | None:
    """The file ``name`` of a report folder, or None: only names a report is made of
    (:data:`wandcal.service.report.FILE_NAME`), and only files directly in the folder."""
    if not FILE_NAME.match(name):
        return None
    path = folder / name
    if path.parent.resolve() != folder.resolve() or not path.is_file():
        return None
    return path


def media_type(path: Path) -> str:
    return MEDIA_TYPES[path.suffix]


def _lock(job_id: str) -> threading.Lock:
    with _locks_guard:
        return _locks.setdefault(job_id, threading.Lock())
