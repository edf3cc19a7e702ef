"""Watch jobs (issue 36): a take watched with a standing result on a worker, as ``wandcal watch``
does it. A job of method :data:`WATCH_METHOD` names its take folder (``takes/<id>/`` in the data
folder: rig.json, take.csv and the standing result.json, as uploaded); the SQLite workers read it,
the API hands its texts to Redis (a worker elsewhere never sees the data folder). The job's result
is the report of ``wandcal watch --json`` and, when asked (``write``), the updated result under
``"result"``, which records the take and the standing result it was derived from."""

from __future__ import annotations

import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path

from wandcal.drivers.capture_files import RIG_FILE, TAKE_FILE

WATCH_METHOD = "watch"
TAKES_DIR = "takes"  # in the data folder: one folder a watch job
LIVE_TAKE_PREFIX = "live-"  # takes/live-<capture id>: the standing result a live capture is watched with
STANDING_FILE = "result.json"  # the standing result, as uploaded or as the calibration job gave it
WATCH_FILES = (RIG_FILE, TAKE_FILE, STANDING_FILE)


def watch_files(folder: str | Path) -> dict[str, str | None]:
    """The texts of a watch job's take folder: rig.json, take.csv, result.json."""
    return {name: (Path(folder) / name).read_text() for name in WATCH_FILES}


def run_watch(files: Mapping[str, str | None], options: dict, progress: Callable[[dict], None]) -> dict:
    """Watch the take of ``files`` (:data:`WATCH_FILES` texts) with its standing result, exactly as
    ``wandcal watch RESULT TAKE --json [--write]``. ``options``: ``write`` (bool: add the updated result),
    ``take_name`` and ``standing_name`` (how the report and the updated result name them).
    Raises CalibrationError for a take that cannot be watched (the job fails with its message)."""
    from wandcal.calib.errors import CalibrationError
    from wandcal.calib.watch.stream import watch_take
    from wandcal.capture.take_file import read_take, updated_result
    from wandcal.capture.watch_report import check_fit, report_json, resolved_cameras
    from wandcal.service.cli.support.inputs import result_for

    take_name, standing_name = options.get("take_name", TAKE_FILE), options.get("standing_name", STANDING_FILE)
    with tempfile.TemporaryDirectory(prefix="wandcal-watch-") as tmp:
        for name, text in files.items():
            (Path(tmp) / name).write_text(text or "")
        try:
            take = read_take(tmp)
            standing, rig, R, t, _ = result_for(Path(tmp) / STANDING_FILE, take)
        except CalibrationError as exc:  # its messages name the files, not the scratch folder
            raise CalibrationError(str(exc).replace(f"{tmp}/", "").replace(tmp, "the take")) from None
        report = watch_take(rig, R, t, take.blobs, progress=lambda done, total: progress(
            {"stage": "watch", "message": f"watch: frame {done} of {total}"}))
        check_fit(report, take_name, standing_name)
        doc = report_json(report)
        if options.get("write"):
            updated = updated_result(standing, take.path, resolved_cameras(report, take_name))
            updated["watch"] |= {"take": take_name, "standing": standing_name}
            doc["result"] = updated
    return doc
