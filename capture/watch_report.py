"""A watch's report as written: each camera's health as JSON (``wandcal watch --json`` and the
service's watch jobs print the same document), the check that the take fits the standing result,
and the moved cameras' entries of the updated result (:func:`wandcal.capture.take_file.updated_result`)."""

from __future__ import annotations

import math

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.watch.report import WatchReport

# Markers triangulated by two cameras that the others see: ~95% on a healthy rig (blobs dropped, views
# beside another marker's image left out); under half for most cameras is not a bumped camera but a
# result of another rig, or a rig rebuilt
MIN_MATCHED = 0.5


def check_fit(report: WatchReport, take: str, result: str) -> None:
    """Refuse a take that most cameras do not fit (another rig's, or a rebuilt one) as bad input;
    ``take`` and ``result`` name them in the message."""
    matched = np.array([h.matched for h in report.cameras])
    if np.median(matched) < MIN_MATCHED:
        raise CalibrationError(f"{take}: the take does not fit {result}: its cameras find only "
                               f"{np.median(matched):.0%} of the markers the others triangulate (a healthy rig finds "
                               "~95%); the take is of another rig, or the rig was rebuilt: calibrate afresh")


def report_json(report: WatchReport) -> dict:
    """Every camera's health: id, status (ok, moved, drifting, or one_of: it or one of the cameras listed in
    ``one_of`` moved and the take cannot tell which, said in ``message``), residual_px, matched (share), detectable_turn_deg (the
    smallest turn, its worst axis, the take lets the test name as often as not); a moved
    one's frames, kind, statistic and whether it was lost (moved too far to follow), and once re-solved its turn (deg), move (mm), their sigmas and fit, or why it was not (not_resolved)."""
    cameras = []
    for h in report.cameras:
        entry = {"id": h.id, "status": h.status, "residual_px": round(h.residual_px, 4), "matched": round(h.matched, 4)}
        if math.isfinite(h.detectable_turn_deg):  # the smallest turn the take lets the test name, as often as not
            entry["detectable_turn_deg"] = round(h.detectable_turn_deg, 3)
        if h.alarm is not None:
            entry |= {"moved_at_frame": h.moved_at, "detected_at_frame": h.alarm.detected_frame, "kind": h.kind,
                      "drift_frames": h.drift_frames, "before_take": h.before_take,
                      "statistic": round(h.alarm.statistic, 1), "lost": h.lost}
        if h.one_of:
            entry |= {"one_of": list(h.one_of), "message": h.message}
        if h.resolved is not None:
            entry |= {"rotation_deg": round(h.resolved.turned_deg, 4), "translation_mm": round(h.resolved.moved_mm, 3),
                      "center_std_mm": round(h.resolved.center_std_mm, 3),
                      "rotation_std_deg": round(h.resolved.rotation_std_deg, 4), "resolved_rms_px": round(h.resolved.rms_px, 4),
                      "resolved_points": h.resolved.points}
        elif h.not_resolved:  # a re-solve was tried and could not be made (a live take's is not tried)
            entry["not_resolved"] = h.not_resolved
        cameras.append(entry)
    return {"frames": report.frames, "judged": report.judged, "markers": report.tracks, "first_frame": report.first_frame,
            "last_frame": report.last_frame, "cameras": cameras, "moved": [h.id for h in report.moved]}


def resolved_cameras(report: WatchReport, take: str) -> dict[str, dict]:
    """The re-solved cameras as :func:`~wandcal.capture.take_file.updated_result` takes them: id ->
    R, t, sigmas, rms and a verdict (good when the fit's rms is under twice the camera's own residual)."""
    cameras = {}
    for h in report.moved:
        r = h.resolved
        if r is None:
            continue
        level = "good" if r.rms_px < 2 * max(h.residual_px, 0.1) else "poor"
        cameras[h.id] = {"R": r.R, "t": r.t, "center_std_mm": r.center_std_mm, "rotation_std_deg": r.rotation_std_deg,
                         "reprojection_rms_px": r.rms_px,
                         "verdict": {"level": level, "reasons": [f"re-solved from {r.points} markers of the take "
                                                                 f"{take} at {r.rms_px:.2f} px"]}}
    return cameras
