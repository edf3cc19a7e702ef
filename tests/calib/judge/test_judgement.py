"""The judgement on cases whose truth is known (calib/run/judgement.py): good rigs are not called
poor, broken ones are, naming the camera or input at fault and only that one. The seeds here are
neither those the limits were set on (1-7) nor the benchmark's (100 on, bench/bench_judgement.py)."""

import numpy as np
import pytest

from wandcal.calib.run.calibrate import calibrate
from wandcal.calib.run.judgement import input_faults
from wandcal.calib.run.options import CalibrationOptions
from wandcal.calib.sim.faults import EXPECTED, broken_capture
from wandcal.calib.sim.simulate import simulate_capture

SEED = 200
# a timing offset is found to within this many frames: the goal of issue 24 for the offsets it
# estimates, and 20x the standard error the fit reports on these rigs (~0.002 frame)
OFFSET_TOLERANCE = 0.05


def _judged(case, seed=SEED, cameras=6):
    sim, c, size = broken_capture(case, seed, cameras, frames=800)
    doc = calibrate(sim.rig, sim.wand, sim.static).to_json()
    return doc, (sim.rig.cameras[c].id if c is not None else None), size


@pytest.mark.parametrize("case", ["good", "good_no_static"])
def test_a_good_rig_is_not_called_poor_and_names_no_fault(case):
    doc, _, _ = _judged(case)
    assert doc["verdict"]["level"] != "poor", doc["verdict"]["reasons"]
    assert doc["verdict"]["faults"] == []
    assert all(cam["verdict"]["level"] != "poor" for cam in doc["cameras"])
    # a flip the wand resolved leaves nothing to do: no warning (it was on two cameras in eight)
    assert not any("planar flip" in w for w in doc["warnings"])
    if case == "good_no_static":  # no world reference: said, and no grade for a placement nobody made
        assert doc["verdict"]["placement"]["level"] is None
        assert doc["verdict"]["placement"]["reasons"][0].startswith("no world reference")


@pytest.mark.parametrize("case", ["focal", "k1", "late", "early", "reflections", "noisy", "wand_length"])
def test_a_broken_rig_is_poor_and_names_the_fault_and_only_it(case):
    doc, camera, size = _judged(case)
    verdict = doc["verdict"]
    assert verdict["level"] == "poor"
    assert [(f["kind"], f["camera"]) for f in verdict["faults"]] == [(EXPECTED[case], camera)]
    fault = verdict["faults"][0]
    assert fault["message"] in verdict["reasons"]
    if camera is not None:  # the camera at fault is poor, and says why first
        entry = next(c for c in doc["cameras"] if c["id"] == camera)
        assert entry["verdict"]["level"] == "poor" and entry["verdict"]["reasons"][0] == fault["message"]
    if EXPECTED[case] == "timing":
        found = fault["evidence"]["timing"]
        assert abs(found["offset_frames"] - size) < OFFSET_TOLERANCE
        assert ("late" if size > 0 else "early") in fault["message"]
    if case == "wand_length":
        assert abs(1 / fault["evidence"]["marker_scale"] - size) < 0.005  # the ratio the user is told
        assert verdict["placement"]["level"] == "poor"
        # no camera is good beside the world sigma the wrong scale makes; the first to-do is the
        # fault's (which two numbers to measure), not more static frames
        assert all(cam["verdict"]["level"] == "poor" for cam in doc["cameras"])
        assert "wand.length_m" in verdict["advice"][0] and "markers_m" in verdict["advice"][0]
        assert verdict["placement"]["advice"] == [verdict["advice"][0]]


def test_every_method_is_judged_on_the_same_observations():
    """ba keeps only the frames it did not drop; the verdict judges them all, for every method."""
    sim, c, _ = broken_capture("reflections", SEED + 1, 5, frames=600)
    docs = {m: calibrate(sim.rig, sim.wand, sim.static, options=CalibrationOptions(method=m)).to_json() for m in ("ba", "lp")}
    judged = {m: ([(f["kind"], f["camera"]) for f in d["verdict"]["faults"]], d["verdict"]["level"]) for m, d in docs.items()}
    assert judged["ba"] == judged["lp"] == ([("outliers", sim.rig.cameras[c].id)], "poor")
    for a, b in zip(docs["ba"]["cameras"], docs["lp"]["cameras"]):
        assert a["observations"] == b["observations"] or a["verdict"]["level"] == b["verdict"]["level"]
        assert a["outlier_share"] == pytest.approx(b["outlier_share"], abs=0.01)


def test_an_unconverged_solve_is_never_good():
    sim = simulate_capture(4, 300, 0.3, 0.0, True, SEED)
    doc = calibrate(sim.rig, sim.wand, sim.static, options=CalibrationOptions(method="paper", max_rounds=1)).to_json()
    if doc["solver"]["status"] == "converged":
        pytest.skip("one round happened to converge")
    assert doc["verdict"]["level"] == "poor"
    assert [f["kind"] for f in doc["verdict"]["faults"]] == ["unconverged"]
    assert "--max-rounds" in doc["verdict"]["faults"][0]["message"]


def test_refined_intrinsics_the_data_do_not_determine_are_a_fault():
    rig = simulate_capture(2, 10, 0.3, 0.0, False, 1).rig
    cameras = [{"intrinsics": {"focal_px": 58.0, "focal_std_px": 385.0}}, {"intrinsics": {"focal_px": 1400.0, "focal_std_px": 3.0}}]
    faults = input_faults(rig, {"frame": "wand_volume"}, {"status": "converged"}, cameras)
    assert [(f["kind"], f["camera"]) for f in faults] == [("undetermined", "cam1")]
    assert "58 +- 385" in faults[0]["message"]


def test_a_static_object_whose_markers_are_off_is_a_placement_fault_not_the_rig():
    sim = simulate_capture(6, 800, 0.3, 0.0, True, SEED + 2)
    bent = sim.rig.static_markers.copy()
    bent[3] += [0.0, 0.0, 0.02]  # one marker 2 cm off its given coordinates: a bent L-frame
    rig = type(sim.rig)(sim.rig.cameras, sim.rig.wand_length, bent)
    doc = calibrate(rig, sim.wand, sim.static).to_json()
    kinds = [f["kind"] for f in doc["verdict"]["faults"]]
    assert kinds == ["static_markers"] and doc["verdict"]["placement"]["level"] == "poor"
    assert doc["verdict"]["level"] != "poor"  # the cameras' geometry is as good as ever
    assert np.all(np.array([c["geometry_std_mm"] for c in doc["cameras"]]) < 1.0)


@pytest.mark.shared_data
@pytest.mark.parametrize("session", ["brown1", "brown2", "ushichka", "svoboda"])
def test_real_sessions_published_as_good_are_not_called_poor(shared_data, session):
    from bench import real_sessions as rs

    result = {"brown1": lambda: rs.brown(1), "brown2": lambda: rs.brown(2), "ushichka": rs.ushichka,
              "svoboda": rs.svoboda}[session]()["result"]
    verdict = result.to_json()["verdict"]
    assert verdict["level"] != "poor", verdict["reasons"]
    assert verdict["faults"] == []


@pytest.mark.shared_data
def test_a_real_session_with_guessed_intrinsics_is_not_given_an_all_clear(shared_data):
    """MultiCamSelfCal reaches 0.62 px on DATA20100906; a focal length guessed and refined without
    distortion leaves 1.4-1.7 px, 2 mrad: poor, saying why."""
    from bench import real_sessions as rs

    doc = rs.svoboda_guessed_focal().to_json()
    assert doc["verdict"]["level"] == "poor"
    assert any("mrad" in r for cam in doc["cameras"] for r in cam["verdict"]["reasons"])
