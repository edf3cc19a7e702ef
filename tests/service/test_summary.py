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


def test_the_cameras_a_focal_length_limits_are_said_on_one_line():
    from wandcal.service.cli.support.summary import _limit_lines

    def limit(cam: str, per: float, sigma: float) -> dict:
        return {"camera": cam, "parameter": "focal length", "message": f"{cam}'s ... run with --refine-intrinsics focal, ...",
                "evidence": {"along_axis_mm_per_percent": per, "focal_sigma_mm": sigma, "focal_std_percent": 2.0}}

    one = _limit_lines([limit("cam4", 3.1, 6.2)], 4)
    assert one == ["  limit (cam4): cam4's ... run with --refine-intrinsics focal, ..."]
    (line,) = _limit_lines([limit("cam1", 4.4, 9.1), limit("cam2", 5.6, 11.5)], 4)
    assert "cam1 and cam2 move 4.4-5.6 mm" in line and "+-9.1-11.5 mm" in line and "--refine-intrinsics focal" in line
    assert _limit_lines([], 4) == []


def test_a_cameras_other_limiting_intrinsics_are_said_on_one_line_after_the_focal_lengths():
    """One form for one limit and for several: a lab user reads the same words for each camera."""
    from wandcal.service.cli.support.summary import _limit_lines

    focal = {"camera": "cam3", "parameter": "focal length", "message": "cam3's focal ...",
             "evidence": {"along_axis_mm_per_percent": 4.3, "focal_sigma_mm": 8.8, "focal_std_percent": 2.0}}

    def lens(name: str, mm: float, sigma: float, unit: str, todo: str) -> dict:
        return {"camera": "cam3", "parameter": name, "message": f"cam3's position moves ... {todo}",
                "evidence": {"parameter_sigma_mm": mm, "sigma": sigma, "unit": unit}}

    cy = lens("cy", 1.2, 21.0, "px", "run with --refine-intrinsics principal, or ...")
    k2 = lens("k2", 1.3, 0.038, "", "give it from a lens calibration (wandcal does not refine it)")
    lines = _limit_lines([focal, cy, k2], 4)
    assert lines[0] == "  limit (cam3): cam3's focal ..."
    assert lines[1] == ("  limit (cam3): cam3's k2 cannot be determined from this capture: it moves the camera up to 1.3 mm "
                        "(for 0.038, its assumed uncertainty); give it from a lens calibration; cam3's cy is determined by "
                        "this capture (cy 1.2 mm for 21 px): refine it (--refine-intrinsics principal) or give it from a "
                        "lens calibration")
    assert len(lines) == 2
    assert _limit_lines([k2], 4) == ["  limit (cam3): cam3's k2 cannot be determined from this capture: it moves the camera "
                                     "up to 1.3 mm (for 0.038, its assumed uncertainty); give it from a lens calibration"]


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



def test_several_cameras_lens_limits_fold_into_one_line_with_each_parameters_range():
    """Sixteen cameras' lens limits are one line, not sixteen: each parameter with its range and, where
    not every camera has it, the cameras that do."""
    from wandcal.service.cli.support.summary import _limit_lines

    def lens(cam: str, name: str, mm: float) -> dict:
        todo = "run with --refine-intrinsics k1, or ..." if name == "k1" else "give it from a lens calibration"
        return {"camera": cam, "parameter": name, "message": f"{cam} ... {todo}",
                "evidence": {"parameter_sigma_mm": mm, "sigma": 0.02, "unit": ""}}

    lines = _limit_lines([lens("cam1", "k1", 1.6), lens("cam2", "k1", 1.9), lens("cam2", "k2", 1.0), lens("cam1", "p1", 0.5),
                          lens("cam2", "p1", 0.6)], 4)
    assert lines == ["  limit (cam1 and cam2): their k2 and p1 cannot be determined from this capture: they move the cameras "
                     "up to 1 mm (k2 1 mm for 0.02 (cam2), p1 0.5-0.6 mm for 0.02, each off by its assumed uncertainty); "
                     "give them from a lens calibration; their k1 is determined by this capture (k1 1.6-1.9 mm for 0.02): "
                     "refine it (--refine-intrinsics k1) or give it from a lens calibration (the result's verdict.limits "
                     "has each camera's figures)"]
