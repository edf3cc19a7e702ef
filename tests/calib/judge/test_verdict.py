"""Verdicts (excellent / good / poor, with reasons) and the checks every method's result passes."""

import numpy as np
import pytest

from wandcal.calib.errors import CalibrationError
from wandcal.calib.geometry import distort_points, project_normalized
from wandcal.calib.judge.sanity import sanity_check
from wandcal.calib.judge.verdict import (
    LISTED_CAMERAS,
    RESIDUAL_OF_VOLUME,
    camera_list,
    camera_verdict,
    rig_verdict,
)
from wandcal.calib.rig import AxisObservations, Rig
from wandcal.calib.run.calibrate import calibrate
from wandcal.calib.sim.simulate import simulate_capture


def test_a_clean_rig_is_not_poor_and_every_camera_has_its_figures_and_a_verdict():
    sim = simulate_capture(6, 1500, 0.3, 0.0, True, 3)
    doc = calibrate(sim.rig, sim.wand, sim.static).to_json()
    assert doc["verdict"]["level"] in ("excellent", "good") and doc["verdict"]["faults"] == []
    assert doc["verdict"]["placement"]["level"] in ("excellent", "good")
    for cam in doc["cameras"]:
        assert 0 < cam["coverage"] <= 1 and cam["verdict"]["level"] != "poor" and cam["verdict"]["advice"] == []
        # the L-frame's placement of the world is in the total, not in the rig's geometry
        assert 0 < cam["geometry_std_mm"] < cam["center_std_mm"]
        # 0.3 px blob noise: the residual is under the excellent limit, so no reason names it
        assert cam["residual_of_volume"] <= RESIDUAL_OF_VOLUME[0]
        assert not any("rays pass" in reason for reason in cam["verdict"]["reasons"])


def test_a_rig_noisy_for_its_volume_is_poor_and_says_why():
    # 3 px blob noise: a ray distance of ~1 cm in a 2.7 m volume, over 2.5 per mille
    sim = simulate_capture(4, 400, 3.0, 0.0, True, 3)
    doc = calibrate(sim.rig, sim.wand, sim.static).to_json()
    assert doc["verdict"]["level"] == "poor"
    cam = doc["cameras"][0]
    assert cam["residual_of_volume"] > RESIDUAL_OF_VOLUME[1]
    assert any("rays pass the points" in r and "poor" in r for r in cam["verdict"]["reasons"])
    assert any("intrinsics and focus" in a for a in cam["verdict"]["advice"])


def test_camera_verdict_grades_each_criterion_with_advice_only_where_it_falls_short():
    good = {"observations": 2000, "coverage": 0.3, "uncovered": ["the left third"], "geometry_std_mm": 0.1,
            "geometry_of_volume": 0.1 / 2000, "noise_px": 0.3, "outlier_share": 0.0, "residual_of_volume": 5e-4}
    v = camera_verdict(good, "cam2", 2.0, 0.3)
    assert v["level"] == "good" and len(v["reasons"]) == 1 and v["advice"] == []
    assert "cam2: samples cover 30% of its image, good" in v["reasons"][0]
    noisy = good | {"noise_px": 0.75}
    v = camera_verdict(noisy, "cam2", 2.0, 0.3)
    assert v["level"] == "poor" and any("2.5 times the median camera's 0.30 px" in r for r in v["reasons"])
    assert v["advice"] == ["check cam2's focus, exposure and blob detection"]
    # few observations that still place the camera well are not poor on their own ...
    few = good | {"observations": 120}
    assert camera_verdict(few, "cam5", 2.0, 0.3)["level"] == "good"
    # ... but are when its place is poorly known too
    v = camera_verdict(few | {"geometry_of_volume": 3e-3, "geometry_std_mm": 6.0}, "cam5", 2.0, 0.3)
    assert v["level"] == "poor" and any("120 observations, poor" in r for r in v["reasons"])


def test_wand_spread_over_one_percent_makes_the_rig_poor():
    ok = {"verdict": {"level": "excellent", "reasons": [], "advice": []}, "id": "cam1"}
    wand = {"length_m": 0.5, "length_mean_m": 0.5, "length_std_m": 0.006}
    v = rig_verdict([ok], wand, [], 20.0)
    assert v["level"] == "poor" and "1.20% of its length" in v["reasons"][0] and v["advice"]


RIG = Rig(tuple(simulate_capture(2, 20, 0.3, 0.0, False, 1).rig.cameras), 0.5)
CAMS = [{"id": "cam1", "observations": 100}, {"id": "cam2", "observations": 100}]
WAND = {"length_m": 0.5, "length_mean_m": 0.5, "length_std_m": 0.001}


@pytest.mark.parametrize("method", ["ba", "paper"])
def test_a_camera_left_without_observations_is_an_error_naming_it(method):
    cams = [CAMS[0], {"id": "cam2", "observations": 0}]
    with pytest.raises(CalibrationError, match="cam2 holding no observations") as err:
        sanity_check(method, RIG, cams, WAND, {"frame": "camera"}, np.zeros((2, 3)))
    # a ba run is not told to try ba
    assert ("try --method ba" in str(err.value)) == (method != "ba")


def test_a_wand_of_the_wrong_length_is_an_error():
    wand = {"length_m": 0.5, "length_mean_m": 0.4, "length_std_m": 0.05}
    with pytest.raises(CalibrationError, match=r"wand of 400.0 \+- 50.0 mm against the given 500.0 mm \(-20%\)"):
        sanity_check("paper", RIG, CAMS, wand, {"frame": "camera"}, np.zeros((2, 3)))


def test_cameras_under_the_floor_warn_of_a_flipped_world():
    centers = np.array([[0, 0, 2.5], [1, 0, -2.5]])
    warnings = sanity_check("ba", RIG, CAMS, WAND, {"frame": "static_object"}, centers)
    assert len(warnings) == 1 and warnings[0].startswith("cam2 is below the floor")
    assert sanity_check("ba", RIG, CAMS, WAND, {"frame": "camera"}, centers) == []


def test_axis_points_with_z_clicked_downwards_put_the_cameras_under_the_floor_and_say_so():
    """The operator marked the +z point below the origin: the reprojection error is as low as
    ever, but the cameras end under the floor, and the result says so."""
    sim = simulate_capture(5, 400, 0.3, static=False, seed=8)
    axis_xyz = {"origin": [0.0, 0.0, 0.0], "+z": [0.0, 0.0, -0.5], "+x": [0.5, 0.0, 0.0]}
    role, camera, uv = [], [], []
    for c, cam in enumerate(sim.rig.cameras):
        for name, X in axis_xyz.items():
            role.append(name), camera.append(c)
            uv.append(distort_points(cam, project_normalized(sim.truth.R[c], sim.truth.t[c], np.array([X])))[0])
    res = calibrate(sim.rig, sim.wand, None, axis=AxisObservations(role, camera, uv))
    assert res.world.frame == "axis" and np.all(res.centers[:, 2] < 0)
    assert any("below the floor" in w and "z must point up" in w for w in res.warnings)


def judged_camera(k: int, short: dict[str, str]) -> dict:
    """A rig_verdict input: camera k's entry, short of excellent in ``short`` ({criterion: level})."""
    level = "poor" if "poor" in short.values() else "good" if short else "excellent"
    return {"id": f"cam{k}", "verdict": {"level": level, "reasons": [f"cam{k}: {name}" for name in short], "advice": [],
                                          "short_of_excellent": short}}


@pytest.mark.parametrize("named, rig_cameras, text", [
    (3, 3, "cam1, cam2 and cam3"),  # a small rig's lists name every camera
    (LISTED_CAMERAS, 64, ", ".join(f"cam{k}" for k in range(1, LISTED_CAMERAS)) + f" and cam{LISTED_CAMERAS}"),
    (64, 64, "all 64 cameras"),
    (10, 64, ", ".join(f"cam{k}" for k in range(1, LISTED_CAMERAS + 1)) + f" and {10 - LISTED_CAMERAS} more"),
])
def test_camera_lists_are_compact_past_a_handful(named, rig_cameras, text):
    assert camera_list([f"cam{k}" for k in range(1, named + 1)], rig_cameras) == text


def test_a_64_camera_rigs_verdict_names_all_cameras_in_a_few_words():
    cams = [judged_camera(k, {"coverage": "good"} | ({"noise": "poor"} if k <= 10 else {})) for k in range(1, 65)]
    v = rig_verdict(cams, None, [], None)
    assert v["level"] == "poor"
    assert v["reasons"] == ["poor for noise in cam1, cam2, cam3, cam4, cam5, cam6 and 4 more (each camera's verdict says why)",
                            "good but not excellent for coverage in all 64 cameras (each camera's verdict says why)"]
    # the full list stays machine-readable, in each camera's own verdict
    assert [c["id"] for c in cams if c["verdict"]["short_of_excellent"].get("noise") == "poor"] == [
        f"cam{k}" for k in range(1, 11)]


def test_a_small_rigs_verdict_lists_its_cameras_as_before():
    cams = [judged_camera(k, {"coverage": "good"}) for k in range(1, 4)] + [judged_camera(4, {})]
    v = rig_verdict(cams, None, [], None)
    assert v["reasons"] == ["good but not excellent for coverage in cam1, cam2 and cam3 (each camera's verdict says why)"]


def test_advice_many_cameras_share_is_one_line_and_a_small_rigs_is_as_before():
    def advised(k: int) -> dict:
        cam = judged_camera(k, {"noise": "poor"})
        cam["verdict"]["advice"] = [f"check cam{k}'s focus, exposure and blob detection"]
        return cam

    big = [advised(k) for k in range(1, 65)]
    big[3]["verdict"]["advice"].append("wave the wand in the top left of cam4's image")  # its own words: kept
    assert rig_verdict(big, None, [], None)["advice"] == [
        "all 64 cameras: check their focus, exposure and blob detection", "wave the wand in the top left of cam4's image"]
    assert rig_verdict(big[:8] + [judged_camera(k, {}) for k in range(9, 65)], None, [], None)["advice"] == [
        "cam1, cam2, cam3, cam4, cam5, cam6 and 2 more: check their focus, exposure and blob detection",
        "wave the wand in the top left of cam4's image"]
    small = big[:3]
    assert rig_verdict(small, None, [], None)["advice"] == [a for c in small for a in c["verdict"]["advice"]]
