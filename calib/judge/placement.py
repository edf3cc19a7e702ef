"""The world frame's verdict: how well the object that set it (an L-frame, axis points, a floor, a
drop) places it against the volume, any fault of that object, and what a frame no object set
(the wand volume's own, a capture without a scale) means for the exported poses."""

from __future__ import annotations

import numpy as np

from wandcal.calib.judge.verdict import FAULT_ADVICE, LEVELS, PLACEMENT_FAULTS, SIGMA_REL_SE, Checks, at_limit_text

# the world's placement: its origin's 1-sigma, and half its axes' angle (the displacement they
# cause at the volume's edge), over the volume's size; the same limits as the geometry
PLACEMENT_OF_VOLUME = (2.5e-4, 1e-3)
PLACEMENT_ADVICE = {
    "static_object": "record more static frames with the L-frame seen by more cameras, or use a larger L-frame",
    "axis": "digitise the axis points in more cameras and frames, or space them further apart",
    "floor": "digitise more floor points in more cameras, spread wider over the floor",
    "gravity": "record a longer drop seen by two or more cameras (more frames, a higher start), or drop it again",
    "wand_volume": "place an L-frame (static object) in the volume, seen by several cameras, to fix the world frame",
}

NO_REFERENCE = ("no world reference (no static.csv with an L-frame, no axis points): the world is the wand volume's "
                "own frame, so the poses are exported in an arbitrary frame; add static.csv (an L-frame seen by several "
                "cameras) where a floor and axes are needed")
NO_SCALE = ("no world reference and no scale: a capture of point tracks only (no wand) is calibrated up to scale, in "
            "an arbitrary frame")


def placement_verdict(world: dict, extent_m: float | None, faults: list[dict]) -> dict:
    """The world frame's placement: its origin's and axes' 1-sigma against the volume, and any
    fault of the object that set it. A frame no object set (the wand volume's own, or a capture
    without a scale) has no placement to grade: ``level`` None, and the reason says so."""
    if world.get("scale") == "arbitrary":
        return {"level": None, "reasons": [NO_SCALE], "advice": []}
    if world.get("frame") == "wand_volume":
        return {"level": None, "reasons": [NO_REFERENCE], "advice": []}
    placement = world.get("placement") or {}
    origin, axes = placement.get("origin_std_mm"), placement.get("axes_std_deg")
    reasons, advice, level, at_limit = [], [], 0, []
    if extent_m and origin is not None and axes is not None:
        rel = max(origin / (1000 * extent_m), np.radians(axes) / 2)
        checks = Checks(None)
        level = checks.add("placement", rel, PLACEMENT_OF_VOLUME, "", "", std=SIGMA_REL_SE * rel,
                           shown=(1000.0 * extent_m, "mm"))
        at_limit = checks.at_limit
        near = f", {at_limit_text(at_limit[0])}" if at_limit else ""
        if level:
            reasons.append(f"the world frame ({world.get('frame')}) is placed to {origin:.2f} mm and {axes:.3f} degrees "
                           f"(1 sigma), {LEVELS[level]}{near} for a {extent_m:.2f} m volume (excellent <= "
                           f"{PLACEMENT_OF_VOLUME[0] * 1000 * extent_m:.2f} mm, good <= "
                           f"{PLACEMENT_OF_VOLUME[1] * 1000 * extent_m:.2f} mm at its edge)")
        if level == 2:
            advice.append(PLACEMENT_ADVICE.get(str(world.get("frame")), PLACEMENT_ADVICE["static_object"]))
    placement_faults = [fault for fault in faults if fault["kind"] in PLACEMENT_FAULTS]
    for fault in placement_faults:
        level = 2
        reasons.append(fault["message"])
    if placement_faults:  # the sigma is the fault's, not the static frames': what fixes it is the fault's
        advice = [FAULT_ADVICE[fault["kind"]] for fault in placement_faults]
    return {"level": LEVELS[level], "reasons": reasons, "advice": advice, "at_limit": at_limit}
