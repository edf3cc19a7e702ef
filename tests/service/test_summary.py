"""``wandcal calibrate``'s summary on a big rig: a row a camera, but the verdict's lists and the poor
cameras' reasons compact (the first few, then the others by name), a small rig's as before."""

import json
from pathlib import Path

import pytest

from wandcal.calib.judge.placement import NO_REFERENCE, NO_SCALE
from wandcal.calib.judge.verdict import rig_verdict
from wandcal.calib.rig import LISTED_CAMERAS
from wandcal.service.cli.support.summary import format_summary


def result(n: int, poor: int) -> dict:
    """A wandcal-result/1 document of ``n`` cameras, the first ``poor`` of them poor for their noise,
    every one short of excellent in coverage; its rig verdict by :func:`rig_verdict`."""
    cameras = []
    for k in range(1, n + 1):
        short = {"coverage": "good"} | ({"noise": "poor"} if k <= poor else {})
        reasons = [f"cam{k}: samples cover 30% of its image, good"] + (
            [f"cam{k}: its blob noise is 2.5 times the median camera's, poor"] if k <= poor else [])
        cameras.append({"id": f"cam{k}", "center": [0.0, 0.0, 2.0], "observations": 3000,
                        "verdict": {"level": "poor" if k <= poor else "good", "reasons": reasons, "advice": [],
                                    "short_of_excellent": short}})
    return {"cameras": cameras, "wand": None, "world": {"frame": "wand_volume", "scale": "arbitrary"},
            "solver": {"method": "ba", "iterations": 5, "seconds": 1.0, "status": "converged"},
            "verdict": rig_verdict(cameras, None, [], None), "warnings": []}


def verdict_lines(doc: dict) -> list[str]:
    """The rig verdict's indented lines (the world frame's line, unindented, after them)."""
    lines = format_summary(doc).splitlines()
    return [line for line in lines[lines.index(f"rig geometry: {doc['verdict']['level']}") + 1:] if line.startswith("  ")]


def test_a_64_camera_summary_names_the_cameras_compactly():
    doc = result(64, 10)
    lines = format_summary(doc).splitlines()
    assert sum(line.split()[0] == f"cam{k}" for k, line in enumerate(lines[1:65], 1)) == 64  # a row a camera
    first = [f"cam{k}" for k in range(1, LISTED_CAMERAS + 1)]
    assert verdict_lines(doc) == [
        f"  poor for noise in {', '.join(first)} and {10 - LISTED_CAMERAS} more (each camera's verdict says why)",
        "  good but not excellent for coverage in all 64 cameras (each camera's verdict says why)",
        *(f"  {reason}" for cam in doc["cameras"][:LISTED_CAMERAS] for reason in cam["verdict"]["reasons"]),
        "  cam7, cam8, cam9 and cam10 are poor too (each camera's verdict in the result says why)",
    ]


def test_a_small_rigs_summary_is_as_before():
    doc = result(4, 2)
    assert verdict_lines(doc) == [
        "  poor for noise in cam1 and cam2 (each camera's verdict says why)",
        "  good but not excellent for coverage in cam1, cam2, cam3 and cam4 (each camera's verdict says why)",
        *(f"  {reason}" for cam in doc["cameras"][:2] for reason in cam["verdict"]["reasons"]),
    ]


def _focal(cam: str, per: float, sigma: float, geo: float = 0.5, refine: bool = True) -> dict:
    todo = "run with --refine-intrinsics focal, ..." if refine else "give it from a lens calibration"
    return {"camera": cam, "parameter": "focal length",
            "message": f"{cam}'s ... (assumed, rig.json giving no focal_std_px for {cam}) ...; {todo}",
            "evidence": {"along_axis_mm_per_percent": per, "focal_sigma_mm": sigma, "focal_std_percent": 2.0,
                         "geometry_sigma_mm": geo}}


def _lens(cam: str, name: str, mm: float, sigma: float, unit: str = "", refine: bool = False, geo: float = 0.5) -> dict:
    todo = "run with --refine-intrinsics principal, or ..." if refine else "give it from a lens calibration"
    return {"camera": cam, "parameter": name, "message": f"{cam}'s ... {todo}",
            "evidence": {"parameter_sigma_mm": mm, "sigma": sigma, "unit": unit, "geometry_sigma_mm": geo}}


def test_a_cameras_dominant_limit_is_said_plainly_and_the_rest_in_one_clause():
    """The focal length's part (8.8 mm) dwarfs cy's and k2's (1.2, 1.3 mm: under 0.48 of it): it is
    what the user reads, with what to do; the others are one clause."""
    from wandcal.service.cli.support.summary import _limit_lines

    lines = _limit_lines([_focal("cam3", 4.3, 8.8), _lens("cam3", "cy", 1.2, 21.0, "px", refine=True),
                          _lens("cam3", "k2", 1.3, 0.038)], 4)
    assert lines == [
        "  limit (cam3): its position hinges on the focal length, +-8.8 mm (4.3 mm along the axis for each 1%; rig.json "
        "gives no focal_std_px: 2% assumed), against +-0.5 mm from the geometry alone",
        "    to do: refine it (--refine-intrinsics focal: this capture determines it) or give it from a lens calibration, "
        "with its focal_std_px; cy and k2 matter less (up to 1.3 mm: the result's verdict.limits)"]
    assert _limit_lines([], 4) == []


def test_intrinsics_of_comparable_parts_are_each_said_and_cameras_alike_share_a_line():
    """k2 (1.3 mm) and cy (0.9 mm, over 0.48 of it) both dominate on cam1 and cam2: one pair for both
    cameras, each intrinsic with its range and what to do (cy refined, k2 from a lens calibration);
    cam4's focal length (6 mm), the largest part, comes first."""
    from wandcal.service.cli.support.summary import _limit_lines

    lines = _limit_lines([_lens("cam1", "k2", 1.3, 0.038), _lens("cam1", "cy", 0.9, 21.0, "px", refine=True),
                          _lens("cam2", "k2", 1.1, 0.033), _lens("cam2", "cy", 0.8, 21.0, "px", refine=True),
                          _focal("cam4", 3.0, 6.0, refine=False)], 4)
    assert lines[2:] + lines[:2] == [
        "  limit (cam1 and cam2): their positions hinge on cy, +-0.8-0.9 mm (for 21 px, its assumed uncertainty) and k2, "
        "+-1.1-1.3 mm (for 0.033-0.038, its assumed uncertainty), against +-0.5 mm from the geometry alone",
        "    to do: refine cy (--refine-intrinsics principal: this capture determines it) or give it from a lens "
        "calibration; give k2 from a lens calibration (this capture does not determine it)",
        "  limit (cam4): its position hinges on the focal length, +-6 mm (3 mm along the axis for each 1%; rig.json gives "
        "no focal_std_px: 2% assumed), against +-0.5 mm from the geometry alone",
        "    to do: give it from a lens calibration, with its focal_std_px (this capture does not determine it)"]


def test_an_older_results_limits_without_figures_print_their_messages():
    from wandcal.service.cli.support.summary import _limit_lines

    old = {"camera": "cam2", "parameter": "cy", "evidence": {}, "message": "cam2's position moves 1.2 mm for 21 px"}
    assert _limit_lines([old], 4) == ["  limit (cam2): cam2's position moves 1.2 mm for 21 px"]


FIXTURES = Path(__file__).resolve().parents[1] / "fixtures" / "results"


@pytest.mark.parametrize("name", ["points_only.json", "before/points_only.json"])
def test_a_points_only_capture_prints_no_world_placement_grade(name):
    """Their stored verdicts graded the placement "excellent"; there was no world to place."""
    lines = format_summary(json.loads((FIXTURES / name).read_text())).splitlines()
    assert not any(line.startswith("world placement") for line in lines)
    assert f"world frame: {NO_SCALE}" in lines


@pytest.mark.parametrize("name", ["sync_auto.json", "before/sync_auto.json"])
def test_a_capture_without_a_world_reference_says_so(name):
    doc = json.loads((FIXTURES / name).read_text())
    assert doc["world"]["frame"] == "wand_volume" and doc["world"].get("scale") != "arbitrary"
    lines = format_summary(doc).splitlines()
    assert not any(line.startswith("world placement") for line in lines)
    assert f"world frame: {NO_REFERENCE}" in lines
    assert not any("place an L-frame" in line for line in lines if line.startswith("to do"))


def test_the_criteria_at_the_limit_of_poor_are_said_beside_the_rig_level():
    doc = result(4, 0)
    doc["verdict"]["at_limit"] = [
        {"criterion": "geometry", "camera": "cam1", "value": 0.75, "limit": 0.805, "std": 0.082, "unit": "mm",
         "levels": ["good", "poor"]},
        {"criterion": "outliers", "camera": "cam2", "value": 5.2, "limit": 5.0, "std": 1.2, "unit": "%",
         "levels": ["excellent", "good"]}]
    lines = verdict_lines(doc)
    assert lines[0] == ("  within one standard error (the better level holds): cam1 geometry at the limit of poor "
                        "(0.75 +- 0.082 mm against 0.805 mm)")
    assert not any("cam2 outliers" in line for line in lines)  # at the limit of good: in the result only


def test_a_moved_camera_is_named_under_the_verdict_with_its_frame_and_turn():
    doc = result(4, 0)
    doc["cameras"][2]["moved"] = {"frame": 51, "degrees": 0.82, "degrees_std": 0.2, "centre_mm": 9.0, "centre_std_mm": 5.0}
    assert verdict_lines(doc)[0] == ("  MOVED cam3: after frame 51, turned 0.82 +- 0.20 degrees, its centre 9 +- 5 mm; its "
                                     "pose is neither: re-solve it from the frames after (--from RESULT --solve-only cam3) "
                                     "or calibrate again")

