"""The result's ``sync`` section (docs/result-format.md) from the fitted offsets
(:class:`wandcal.calib.solve.sync.fit.Timing`), the warnings of cameras found out of time, and the
``--sync`` modes.
"""

from __future__ import annotations

import numpy as np

from wandcal.calib.solve.sync.fit import Timing

SYNC_MODES = ("none", "auto")
DEFAULT_SYNC = "none"  # docs/decisions/0018-sync-from-the-wand.md: a trigger's frames need no search
# an offset this many standard errors (and OUT_OF_TIME_FRAMES) from its start is worth a warning
OUT_OF_TIME_SIGMAS = 4.0
OUT_OF_TIME_FRAMES = 0.05  # frames: below the accuracy the issue asks of the estimate


def sync_report(
    ids: list[str], whole: np.ndarray, reference: int, timing: Timing, start: np.ndarray | None, rate_hz: float | None,
    drift: bool,
) -> tuple[dict, list[str]]:
    """The result's ``sync`` section (docs/result-format.md) and the warnings of cameras found out
    of time.

    Args:
        ids: camera ids (N,).
        whole: (N,) int whole-frame offsets the frames were renumbered by.
        reference: the camera held at offset 0.
        timing: the sub-frame model fitted on the renumbered frames.
        start: (N,) the offsets the capture's timestamps gave (frames), or None (zeros).
        rate_hz: the reference camera's frame rate, for seconds; None when unknown.
        drift: whether drift was estimated.
    """
    n = len(ids)
    start = np.zeros(n) if start is None else np.asarray(start, dtype=float)
    at_zero, std = timing.offset_at(whole.astype(float))  # phi at each camera's own frame 0 (renumbered to whole)
    offset = whole + at_zero
    cameras, warnings = [], []
    for c in range(n):
        whole_only = timing.held is not None and timing.held[c] and c != reference
        entry = {
            "id": ids[c],
            "offset_frames": float(offset[c]),
            "offset_std_frames": None if whole_only else float(std[c]),
            "offset_s": float(offset[c] / rate_hz) if rate_hz else None,
            "drift_ppm": float(1e6 * timing.drift[c]) if drift else None,
            "drift_std_ppm": float(1e6 * np.sqrt(max(timing.cov[c, 1, 1], 0.0))) if drift else None,
        }
        cameras.append(entry)
        gap = offset[c] - start[c]
        if whole_only:
            warnings.append(f"{ids[c]}: its wand frames are too sparse or too far apart in time to interpolate, so its "
                            "time offset is found in whole frames only")
        entry["out_of_time"] = bool(c != reference and abs(gap) > max(OUT_OF_TIME_SIGMAS * std[c], OUT_OF_TIME_FRAMES))
        if entry["out_of_time"]:
            said = "its timestamps" if np.any(start) else "its frame numbers"
            warnings.append(
                f"{ids[c]} is out of time: its frame k was exposed at {ids[reference]}'s frame k {offset[c]:+.3f} "
                f"(+-{std[c]:.3f}) frames, {gap:+.3f} from what {said} said; its frames were realigned by the wand"
            )
    doc = {"mode": "auto", "reference": ids[reference], "rate_hz": rate_hz, "residual_sigma_px": timing.sigma_px,
           "cameras": cameras}
    return doc, warnings
