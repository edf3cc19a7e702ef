"""A result as a person reads it on the terminal: ``wandcal calibrate``'s summary (a row a camera, the
wand, the verdict, the warnings) and ``wandcal demo``'s errors against the simulator's truth."""

from __future__ import annotations

import numpy as np

from wandcal.calib.geometry import kabsch, rotation_angle
from wandcal.calib.judge.limit_words import limit_lines
from wandcal.calib.judge.placement import NO_REFERENCE, NO_SCALE
from wandcal.calib.judge.verdict import at_limit_text
from wandcal.calib.rig import LISTED_CAMERAS, camera_list
from wandcal.calib.run.result import camera_observations


def format_summary(doc: dict) -> str:
    """The result as a person reads it: a row a camera, the wand, the rig's verdict with the camera
    or input at fault, the world's placement, what to do, and the warnings. ``obs`` counts all of a
    camera's observations (wand ends and single points, as the verdict counts them); ``pts`` the
    single points among them."""
    points = any("point_observations" in cam for cam in doc["cameras"])
    intrinsics = any("intrinsics" in cam for cam in doc["cameras"])
    scaled = doc["world"].get("scale", "wand") != "arbitrary"
    unit = "m" if scaled else "rig units"
    width = max(16, *(len(cam["id"]) + 1 for cam in doc["cameras"]))
    head = (f"{'camera':<{width}} {'centre x, y, z (' + unit + ')':>32}  {'geom +-mm':>9} {'world +-mm':>10} "
            f"{'rms px':>7} {'resid mm':>8} {'outl %':>6} {'obs':>6} {'verdict':>9}")
    head += f" {'pts rms':>7} {'pts':>6}" if points else ""
    head += f" {'focal px':>14}" if intrinsics else ""
    lines = [head]
    for cam in doc["cameras"]:
        c = cam["center"]
        share = cam.get("outlier_share")
        row = (f"{cam['id']:<{width}} {c[0]:10.4f} {c[1]:10.4f} {c[2]:10.4f}  "
               f"{_number(cam.get('geometry_std_mm'), '.2f', 9)} {_number(cam.get('center_std_mm'), '.2f', 10)} "
               f"{_number(cam.get('reprojection_rms_px'), '.3f', 7)} {_number(cam.get('residual_mm'), '.2f', 8)} "
               f"{_number(None if share is None else 100 * share, '.1f', 6)} {camera_observations(cam):6d} "
               f"{cam.get('verdict', {}).get('level', '-'):>9}")
        if points:
            row += f" {_number(cam.get('point_rms_px'), '.3f', 7)} {cam.get('point_observations', 0):6d}"
        if intrinsics and "focal_px" in cam.get("intrinsics", {}):
            row += f" {cam['intrinsics']['focal_px']:8.1f}+-{cam['intrinsics']['focal_std_px']:<4.1f}"
        lines.append(row)
    w, s = doc["wand"], doc["solver"]
    iterations = s["iterations"]
    solved = f"{s['method']}: {iterations} iteration{'' if iterations == 1 else 's'}, {s['seconds']:.2f} s ({s['status']})"
    if w is None:
        lines.append(f"no wand: calibrated up to scale (lengths in rig units); {solved}")
    else:
        frames = w["frames_used"]
        lines.append(
            f"wand {w['length_mean_m'] * 1000:.2f} +- {w['length_std_m'] * 1000:.2f} mm "
            f"({100 * w['length_std_m'] / w['length_mean_m']:.3f}%) over {frames} frame{'' if frames == 1 else 's'} "
            f"in the solve (both ends in 2+ cameras{_after_outliers(doc)}); {solved}"
        )
    lines += _verdict_lines(doc)
    lines += [f"warning: {text}" for text in doc["warnings"]]
    return "\n".join(lines)


def _after_outliers(doc: dict) -> str:
    """Why the solve's frames can be fewer than import's count of frames with both ends in 2+
    cameras: a frame whose second camera was a gross outlier is no longer seen by two."""
    dropped = (doc.get("dropped") or {}).get("outliers", 0)
    if not dropped:
        return ""
    return f" once {'its one gross-outlier camera-frame was' if dropped == 1 else f'the {dropped} gross-outlier camera-frames were'} dropped"


def _verdict_lines(doc: dict) -> list[str]:
    """The judgement: the rig's geometry, the faults it names, the world's placement, the advice."""
    verdict = doc.get("verdict")
    if not verdict:
        return []
    lines = [f"rig geometry: {verdict['level']}"]
    lines += _at_limit_lines(verdict.get("at_limit") or [])
    lines += _moved_lines(doc["cameras"])
    faults = verdict.get("faults") or []
    lines += [f"  fault ({fault['kind']}{', ' + fault['camera'] if fault.get('camera') else ''}): {fault['message']}"
              for fault in faults]
    shown = {fault["message"] for fault in faults}
    lines += [f"  {reason}" for reason in verdict["reasons"] if reason not in shown]
    rig_wide = {fault["message"] for fault in faults if not fault.get("camera")}  # a wrong scale makes every camera poor
    poor = [cam for cam in doc["cameras"] if cam.get("verdict", {}).get("level") == "poor"
            and any(reason not in shown for reason in cam["verdict"].get("reasons", []))
            and not rig_wide & set(cam["verdict"].get("reasons", [])[:1])]
    for cam in poor[:LISTED_CAMERAS]:  # the first few poor cameras' reasons; a big rig's others by name
        lines += [f"  {reason}" for reason in cam["verdict"]["reasons"] if reason not in shown]
    more = [cam["id"] for cam in poor[LISTED_CAMERAS:]]
    if more:
        lines.append(f"  {camera_list(more, len(doc['cameras']))} {'is' if len(more) == 1 else 'are'} poor too (each "
                     "camera's verdict in the result says why)")
    lines += _limit_lines(verdict.get("limits") or [], len(doc["cameras"]))
    placement = verdict.get("placement")
    world = doc["world"]
    if world.get("scale") == "arbitrary" or world.get("frame") == "wand_volume":
        # no object placed the world (older results graded it all the same): nothing to grade
        lines.append(f"world frame: {NO_SCALE if world.get('scale') == 'arbitrary' else NO_REFERENCE}")
        placement = None
    elif placement:
        where = world.get("placement") or {}
        figures = ""
        if where.get("axes_std_deg") is not None:
            origin = where.get("origin_std_mm")
            figures = (f" (origin +-{origin:.2f} mm, " if origin is not None else " (") + f"axes +-{where['axes_std_deg']:.3f} deg)"
        lines.append(f"world placement ({world.get('frame')}): {placement['level']}{figures}")
        lines += [f"  {reason}" for reason in placement["reasons"] if reason not in shown]
    advice = list(dict.fromkeys([*verdict.get("advice", []), *(placement or {}).get("advice", [])]))
    lines += [f"to do: {text}" for text in advice]
    return lines


def _at_limit_lines(entries: list[dict]) -> list[str]:
    """The criteria within their standard error of the limit of poor (the verdict's ``at_limit``,
    which has those at the limit of good too): each holds the better level, and could go either
    way on another take."""
    said = [f"{e['camera'] + ' ' if e.get('camera') else ''}{e['criterion']} {at_limit_text(e)}"
            for e in entries if e["levels"][1] == "poor"]
    if not said:
        return []
    more = f"; and {len(said) - LISTED_CAMERAS} more (the result's verdict.at_limit)" if len(said) > LISTED_CAMERAS else ""
    return [f"  within one standard error (the better level holds): {'; '.join(said[:LISTED_CAMERAS])}{more}"]


def _moved_lines(cameras: list[dict]) -> list[str]:
    """A line a camera that moved during the capture (its result entry's ``moved``): its pose is a
    compromise of the two, and what to do."""
    out = []
    for cam in cameras:
        m = cam.get("moved")
        if not m:
            continue
        centre = (f", its centre {m['centre_mm']:.0f} +- {m['centre_std_mm']:.0f} mm"
                  if m.get("centre_mm") is not None and m.get("centre_std_mm") is not None else "")
        out.append(f"  MOVED {cam['id']}: after frame {m['frame']}, turned {m['degrees']:.2f} +- {m['degrees_std']:.2f} "
                   f"degrees{centre}; its pose is neither: re-solve it from the frames after (--from RESULT "
                   f"--solve-only {cam['id']}) or calibrate again")
    return out


def _limit_lines(limits: list[dict], n_cameras: int) -> list[str]:
    """The cameras whose position hinges on an intrinsic that was given (the verdict's ``limits``):
    each group's dominant intrinsics and what to do (:func:`wandcal.calib.judge.limit_words.limit_lines`,
    the report's page says the same)."""
    return limit_lines(limits, n_cameras)


def _number(value, fmt: str, width: int) -> str:
    """A right-aligned figure, or '-' when the result has none (older results, no scale)."""
    return f"{'-' if value is None else format(value, fmt):>{width}}"


def truth_table(result, sim) -> str:
    """Per-camera errors against the simulator's truth, in the world frame and after the best
    rigid (similarity without a static object) alignment."""
    C, Ct = result.centers, sim.truth.centers
    static = sim.rig.static_markers is not None
    Ra, ta, s = kabsch(C, Ct, scale=not static)
    aligned = np.linalg.norm(s * C @ Ra.T + ta - Ct, axis=1) * 1000
    raw = np.linalg.norm(C - Ct, axis=1) * 1000 if static else None
    rot = np.degrees(rotation_angle(result.R @ Ra.T, sim.truth.R)) * 3600
    # without a static object the world is the wand volume's own frame: only aligned errors mean anything
    head = f"{'camera':<10}" + (f" {'centre err (mm)':>16}" if static else "")
    rows = [head + f" {'aligned (mm)':>13} {'rotation (arcsec)':>18}"]
    for i, cam in enumerate(sim.rig.cameras):
        raw_col = f" {raw[i]:16.3f}" if raw is not None else ""
        rows.append(f"{cam.id:<10}{raw_col} {aligned[i]:13.3f} {rot[i]:18.1f}")
    if raw is None:
        rows.append("(no static object: the world is the wand volume's frame, not the simulator's, so the errors "
                    "are after the best similarity alignment)")
    return "\n".join(rows)
