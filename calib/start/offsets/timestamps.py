"""Whole-frame offsets from frame timestamps on a clock the cameras share (a host's monotonic
clock): the start of :func:`wandcal.calib.start.offsets.whole_frames.frame_offsets`'s search (docs/sync.md)."""

from __future__ import annotations

import numpy as np

from wandcal.calib.errors import CalibrationError

# a camera's lead over the reference, from timestamps, may wander this far (median absolute
# deviation, frames) before they contradict themselves: drift of 100 ppm moves it 1 frame in 10,000
CONTRADICTION_FRAMES = 1.0


def timestamp_offsets(
    ids: list[str], frames: list[np.ndarray], stamps_us: list[np.ndarray], rate_hz: float | None = None, reference: int = 0
) -> np.ndarray:
    """Whole-frame offsets from frame timestamps on a clock the cameras share (a host's monotonic
    clock), the start of :func:`frame_offsets`'s search.

    Args:
        ids: camera ids (N,).
        frames: per camera, (K_c,) int frame numbers that carry a timestamp.
        stamps_us: per camera, (K_c,) their timestamps, microseconds.
        rate_hz: the frame rate; default from the reference camera's own timestamps.
        reference: the camera of offset 0.

    Returns:
        (N,) int: camera c's frame k was exposed about ``offsets[c]`` frames after the reference
        camera's frame k (0 for a camera without timestamps in common with the reference).

    Raises:
        CalibrationError: a camera's timestamps go backwards, or its lead over the reference
            changes by more than ``CONTRADICTION_FRAMES`` within the recording; the message names it.
    """
    for c, (f, ts) in enumerate(zip(frames, stamps_us)):
        order = np.argsort(f)
        back = np.flatnonzero(np.diff(np.asarray(ts, dtype=float)[order]) <= 0)
        if len(back):
            raise CalibrationError(
                f"camera {ids[c]!r}: its timestamps go backwards (or repeat) at frame {int(np.asarray(f)[order][back[0] + 1])}; "
                "the timestamps contradict the frame order: fix sync.csv, or calibrate with --sync auto without them"
            )
    f0, t0 = np.asarray(frames[reference]), np.asarray(stamps_us[reference], dtype=float)
    if rate_hz:
        period = 1e6 / rate_hz
    else:
        order = np.argsort(f0)
        period = float(np.median(np.diff(t0[order]) / np.diff(f0[order]))) if len(f0) > 1 else float("nan")
    offsets = np.zeros(len(ids), np.int64)
    for c, (f, ts) in enumerate(zip(frames, stamps_us)):
        common, ia, ib = np.intersect1d(f0, np.asarray(f), return_indices=True)
        if c == reference or not len(common) or not np.isfinite(period):
            continue
        lead = (np.asarray(ts, dtype=float)[ib] - t0[ia]) / period
        centre = float(np.median(lead))
        wander = float(np.median(np.abs(lead - centre)))
        if wander > CONTRADICTION_FRAMES:
            raise CalibrationError(
                f"camera {ids[c]!r}: its timestamps contradict themselves: its lead over {ids[reference]} wanders by "
                f"{wander:.1f} frames (median deviation) within the recording; its clock is not the others', or frames "
                "were renumbered: fix sync.csv, or calibrate with --sync auto without timestamps"
            )
        offsets[c] = int(np.round(centre))
    return offsets
