"""The guidance document (``wandcal-guidance/1``, docs/api.md): per camera its frames, links,
coverage and predicted sigma, and the advice to the operator, worst camera first."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.judge.coverage import GRID, WAND, Sampling, coverage_advice, coverage_grid, covered_fraction
from wandcal.calib.observations import WandPairs
from wandcal.calib.rig import Rig
from wandcal.calib.run.guidance.settings import GuidanceSettings

GUIDANCE_FORMAT = "wandcal-guidance/1"
# Advice names a camera's links when it shares fewer frames than this with the rest: two
# frames per 8 x 8 cell, so the shared frames can at least spread over its image.
FEW_SHARED_FRAMES = 2 * GRID[0] * GRID[1]
# A camera that has seen no wand while the rest of the rig saw it in this many frames (as many as a
# camera needs shared to be linked at all) is off, blocked or aimed away: say so then, and not
# before -- with no wand yet (the L-frame still being recorded, nobody waving) silence says nothing
# about a camera.
SILENT_CAMERA_FRAMES = FEW_SHARED_FRAMES


@dataclass(frozen=True, eq=False)
class Seen:
    """What the blobs say before any solve: the two-blob camera-frames and their links."""

    pairs: WandPairs
    frames: np.ndarray  # (N,) frames in which each camera saw both ends
    linked: np.ndarray  # (N, N) frames both cameras saw both ends in
    shared: np.ndarray  # (N,) frames in which the camera and at least one other saw both ends


def guidance_document(rig: Rig, seen: Seen, center: np.ndarray, rotation: np.ndarray, solve_set: np.ndarray,
                      settings: GuidanceSettings, info: dict, *, words: Sampling = WAND) -> dict:
    """The ``wandcal-guidance/1`` document of one update: each camera's frames, links, coverage
    grid and predicted sigmas (``center`` (N,) metres, ``rotation`` (N,) radians, NaN outside the
    solve), the advice worst first, and whether it is ``enough``; ``info`` is the solve's.
    ``words``: what the advice calls the samples (a wand's frames, or a points-only rig's points)."""
    ids = rig.ids
    target, goal = settings.target_std_mm, settings.min_coverage
    cameras, worst = [], []
    rig_frames = int(len(np.unique(seen.pairs.frames[seen.pairs.frame])) if len(seen.pairs) else 0)
    # each camera's blobs as one slice of the pairs sorted by camera (a mask per camera is N passes)
    order = np.argsort(seen.pairs.camera, kind="stable")
    by_camera = seen.pairs.uv[order]
    bounds = np.searchsorted(seen.pairs.camera[order], np.arange(len(rig.cameras) + 1))
    for c, cam in enumerate(rig.cameras):
        uv = by_camera[bounds[c] : bounds[c + 1]].reshape(-1, 2)
        grid = coverage_grid(uv, cam.width, cam.height, settings.grid)
        fraction = covered_fraction(grid)
        sigma_mm = None if np.isnan(center[c]) else float(1000 * center[c])
        entry = {
            "id": cam.id,
            "frames": int(seen.frames[c]),
            "shared_frames": int(seen.shared[c]),
            "coverage": round(fraction, 4),
            "grid": grid.tolist(),
            "linked": {ids[d]: int(seen.linked[c, d]) for d in range(len(ids)) if d != c},
            "center_std_mm": sigma_mm,
            "rotation_std_deg": None if np.isnan(rotation[c]) else float(np.degrees(rotation[c])),
        }
        advice, severity = _camera_advice(entry, grid, bool(solve_set[c]), settings, rig_frames, words)
        entry["advice"] = advice
        cameras.append(entry)
        if advice is not None:
            worst.append((severity, c, advice))
    enough = info["ok"] and not worst
    worst.sort(key=lambda w: (-w[0], w[1]))
    # a failed solve is the rig's problem, not one camera's: it leads the list
    # a camera out of time spoils every other figure it touches: it leads the list
    late = [f"{cid} looks out of time: its wand matches the others' {shift:+d} frames away; check its trigger "
            "connection, or calibrate with --sync auto" for cid, shift in info.get("out_of_time", {}).items()]
    rig_advice = late + ([info["message"]] if not info["ok"] and info["message"] else []) + [w[2] for w in worst]
    enough = enough and not info.get("out_of_time")
    return {
        "format": GUIDANCE_FORMAT,
        "frames": rig_frames,
        "enough": bool(enough),
        "advice": rig_advice,
        "target": {"center_std_mm": target, "coverage": goal},
        "cameras": cameras,
        "solve": info,
    }


def _camera_advice(entry: dict, grid: np.ndarray, solved: bool, settings: GuidanceSettings,
                   rig_frames: int, words: Sampling = WAND) -> tuple[str | None, float]:
    """Words for one camera, or None when it needs nothing, and how badly it needs them (for the
    worst-first order): a camera without frames or outside the solve first, then by the larger
    of its sigma over the target and the coverage goal over its coverage. ``rig_frames``: the
    frames in which any camera saw both wand ends (a camera is only suspect when the others saw
    the wand and it did not); for a points-only rig (``words`` :data:`POINTS`) the points."""
    cid, frames, shared = entry["id"], entry["frames"], entry["shared_frames"]
    sigma, fraction = entry["center_std_mm"], entry["coverage"]
    target, goal = settings.target_std_mm, settings.min_coverage
    if frames == 0:
        if rig_frames == 0:
            return f"{cid}: waiting for {words.thing}", float("inf")
        if rig_frames < SILENT_CAMERA_FRAMES:
            return f"{cid} has not seen {words.seen} yet; {words.act} in its view", float("inf")
        return (f"{cid} has not seen {words.seen} in any of the {rig_frames} {words.unit} the other cameras saw; "
                f"check that it is on and aimed at the volume, then {words.act} in its view"), float("inf")
    neighbours = sorted(entry["linked"], key=lambda d: -entry["linked"][d])[:2]
    near = f" and {' or '.join(neighbours)}" if neighbours else ""
    linking = (f"{cid} shares only {shared} {words.unit} with the others; {words.act} where {cid}{near} see {words.it} "
               "together")
    if not solved:
        if shared >= FEW_SHARED_FRAMES:  # enough frames, but they did not place it (left out of the solve)
            return (f"{cid} could not be placed from the {shared} {words.unit} it shares with the others; "
                    f"{words.act} where {cid}{near} see {words.it} together, near and far"), 1e6 - shared
        return linking, 1e6 - shared
    parts, severity = [], 0.0
    coverage_words = coverage_advice(grid, cid, goal, words)
    if coverage_words is not None:
        parts.append(coverage_words.removeprefix(f"{cid}: "))
        severity = max(severity, goal / max(fraction, 1e-3))
    if sigma is not None and sigma >= target:
        if shared < FEW_SHARED_FRAMES:
            parts.append(linking.removeprefix(f"{cid} "))
        else:
            parts.append(f"its centre is known to +-{sigma:.2f} mm (goal {target:g} mm); keep waving in its view "
                         "where other cameras see the wand too")
        severity = max(severity, sigma / target)
    if not parts:
        return None, 0.0
    return f"{cid}: " + "; ".join(parts), severity

