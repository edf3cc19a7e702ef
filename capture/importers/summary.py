"""What an import found: the capture, and a printout of cameras, wand frames, other points and
what could not be used."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.capture.folder import Capture, check_capture


@dataclass(frozen=True, eq=False)
class Imported:
    """An imported capture.

    Args:
        capture: the capture, in wandcal's conventions.
        source: what was read (paths), for the printout.
        notes: what was left out or converted, one sentence each, saying why.
    """

    capture: Capture
    source: str
    notes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        check_capture(self.capture, self.source)  # what an import gives, calibrate reads (issue 20, class 8)


def summary_lines(imported: Imported) -> list[str]:
    """The printout of ``wandcal import``: one line per finding."""
    cap = imported.capture
    rig = cap.rig
    lines = [f"read {imported.source}", f"cameras: {len(rig.cameras)}"]
    for cam in rig.cameras:
        dist = " ".join(f"{d:+.4g}" for d in cam.dist)
        lines.append(
            f"  {cam.id}: {cam.width}x{cam.height} px, f = {cam.K[0, 0]:.1f} px, "
            f"principal point ({cam.K[0, 2]:.1f}, {cam.K[1, 2]:.1f}) y down, dist [{dist}]"
        )
    if rig.wand_length is None:
        lines.append("wand: none (point tracks only; the calibration has no metric scale)")
    else:
        frames, per_cam = _frames_per_camera(cap.wand.frame, cap.wand.camera, len(rig.cameras))
        lines.append(
            f"wand: {rig.wand_length:g} m, {len(frames)} frames with both ends seen by some camera, "
            f"{_multi_view(cap.wand.frame, cap.wand.camera)} of them by 2 or more cameras"
        )
        lines.append("  frames with both ends per camera: " + _per_camera(rig.ids, per_cam))
    if cap.points is not None and len(cap.points):
        frames, per_cam = _frames_per_camera(cap.points.frame, cap.points.camera, len(rig.cameras))
        lines.append(
            f"other points: {len(frames)} (frames {frames.min()}-{frames.max()}), "
            f"{_multi_view(cap.points.frame, cap.points.camera)} of them seen by 2 or more cameras"
        )
        lines.append("  points per camera: " + _per_camera(rig.ids, per_cam))
        if cap.points.point is not None:
            names = np.unique(cap.points.point)
            pairs = len(np.unique(np.stack([cap.points.frame.astype(str), cap.points.point]), axis=1)[0])
            lines.append(f"  labelled: {len(names)} point names ({', '.join(names[:8])}{', ...' if len(names) > 8 else ''}), "
                         f"{pairs} (point, frame) pairs, each one 3D point")
    else:
        lines.append("other points: none")
    if cap.axis is not None and len(cap.axis.role):
        roles = []
        for role in dict.fromkeys(cap.axis.role):
            cams = [rig.ids[c] for c in cap.axis.camera[cap.axis.role == role]]
            roles.append(f"{role} ({', '.join(cams)})")
        lines.append("axis points: " + "; ".join(roles))
    else:
        lines.append("axis points: none")
    lines += [f"note: {n}" for n in imported.notes]
    return lines


def _frames_per_camera(frame: np.ndarray, camera: np.ndarray, n_cams: int) -> tuple[np.ndarray, np.ndarray]:
    pairs = np.unique(np.stack([frame, camera], 1), axis=0) if len(frame) else np.zeros((0, 2), int)
    return np.unique(pairs[:, 0]), np.bincount(pairs[:, 1], minlength=n_cams)


def _multi_view(frame: np.ndarray, camera: np.ndarray) -> int:
    if not len(frame):
        return 0
    pairs = np.unique(np.stack([frame, camera], 1), axis=0)
    _, views = np.unique(pairs[:, 0], return_counts=True)
    return int((views >= 2).sum())


def _per_camera(ids: list[str], counts: np.ndarray) -> str:
    return ", ".join(f"{cid} {int(n)}" for cid, n in zip(ids, counts))
