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
    held = timing.held if timing.held is not None else np.zeros(n, bool)
    every_held = n > 1 and bool(np.all(held | (np.arange(n) == reference)))
    if every_held:
        warnings.append(not_synchronised(ids, reference, timing))
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
        if whole_only and not every_held:
            warnings.append(f"{ids[c]}: its time offset is found in whole frames only: {_why_held(timing, c)}")
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


# what to do where the wand cannot time the cameras to a fraction of a frame
NO_SYNC_ADVICE = ("trigger the cameras from one hardware signal, or wave the wand slower or record at a higher frame "
                  "rate, so that it moves a few pixels from one frame to the next")


def _why_held(timing: Timing, c: int) -> str:
    """Why camera c was held at its whole-frame offset, its figure beside the limit."""
    why = timing.smoothness.why_not(c) if timing.smoothness is not None else ""
    return why or "its wand frames are too sparse or too far apart in time to interpolate"


def not_synchronised(ids: list[str], reference: int, timing: Timing) -> str:
    """The warning of ``--sync auto`` when it held every camera at its whole-frame offset (ids
    (N,), the reference camera's index): no camera's wand track can be interpolated in time, each
    camera's figure beside its limit, and what to do."""
    each = "; ".join(f"{ids[c]}: {_why_held(timing, c)}" for c in range(len(ids)) if c != reference)
    return (f"--sync auto could not time any camera to a fraction of a frame, only in whole frames, because no "
            f"camera's wand can be followed from frame to frame ({each}); for sub-frame timing, {NO_SYNC_ADVICE}")


def sync_advice(why_not: str, fraction: bool = True) -> str:
    """The end of a timing fault's advice, after "check its trigger cable and settings": ``--sync
    auto`` where it can fix the offset, or why it cannot and what to do. ``why_not``: why the
    camera's wand track cannot be interpolated in time (:meth:`TrackSmoothness.why_not
    <wandcal.calib.solve.sync.tracks.TrackSmoothness.why_not>`, the test :func:`~wandcal.calib.solve.sync.fit.fit_timing`
    holds a camera by; "" where it can); ``fraction``: the offset has a fraction of a frame to fit
    (a whole-frame shift alone needs no track: the whole-frame search times it)."""
    if not (fraction and why_not):
        return ", or calibrate with its offset (--sync auto)"
    return (f"; the wand cannot time it to a fraction of a frame, as {why_not}, so --sync auto would shift it by "
            f"whole frames only: {NO_SYNC_ADVICE}")
