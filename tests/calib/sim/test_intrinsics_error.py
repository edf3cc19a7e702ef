"""``simulate --intrinsics-error``: rig.json's intrinsics drawn off the truth by the stated sigmas,
the truth kept, the capture's blobs unchanged; and the honest sigma on such a rig."""

from __future__ import annotations

import json

import numpy as np

from wandcal.calib.sim.intrinsics import IntrinsicsError, off_intrinsics, with_intrinsics_error
from wandcal.calib.sim.simulate import ring_cameras, simulate_capture


def test_the_draws_have_the_stated_sigmas():
    """64 cameras' draws: each sigma estimated within 4 of its standard errors (sigma / sqrt(2 n))."""
    from wandcal.calib.rig import Rig

    cams = ring_cameras(64, np.random.default_rng(0))[0]
    rig = Rig(tuple(cams), 0.5)
    off = off_intrinsics(rig, IntrinsicsError(0.02, 5.0, 0.01, write_std=True), seed=3)
    K0, K1 = np.array([c.K for c in rig.cameras]), np.array([c.K for c in off.cameras])
    rel = K1[:, 0, 0] / K0[:, 0, 0] - 1
    np.testing.assert_allclose(K1[:, 1, 1] / K0[:, 1, 1] - 1, rel)  # fx and fy together, as a lens's focal length
    for got, sigma in [(rel, 0.02), ((K1 - K0)[:, :2, 2].ravel(), 5.0),
                       (np.array([c.dist[:4] - c0.dist[:4] for c, c0 in zip(off.cameras, rig.cameras)]).ravel(), 0.01)]:
        assert abs(np.sqrt(np.mean(got ** 2)) - sigma) < 4 * sigma / np.sqrt(2 * len(got))
    np.testing.assert_allclose([c.focal_std_px for c in off.cameras], 0.02 * K1[:, 0, 0])
    assert off_intrinsics(rig, IntrinsicsError(), seed=3) is rig


def test_the_truth_keeps_the_true_cameras_and_the_blobs_are_the_seeds():
    sim = simulate_capture(3, 20, seed=5)
    off = with_intrinsics_error(sim, IntrinsicsError(0.03), seed=5)
    assert off.wand is sim.wand and off.truth.cameras == sim.rig.cameras
    doc = off.truth.to_json(off.rig)
    np.testing.assert_allclose(doc["cameras"][0]["K"], sim.rig.cameras[0].K)
    assert off.rig.cameras[0].K[0, 0] != sim.rig.cameras[0].K[0, 0]
    assert "K" not in sim.truth.to_json(sim.rig)["cameras"][0]  # truth.json as before without the option


def test_simulate_writes_them_and_refuses_a_sigma_without_a_draw(tmp_path, capsys):
    from wandcal.service.cli import main

    assert main(["simulate", str(tmp_path / "a"), "--cameras", "3", "--frames", "20", "--intrinsics-error", "2%",
                 "--focal-std"]) == 0
    rig, truth = (json.loads((tmp_path / "a" / name).read_text()) for name in ("rig.json", "truth.json"))
    f, f_true = rig["cameras"][0]["K"][0][0], truth["cameras"][0]["K"][0][0]
    assert f != f_true and abs(rig["cameras"][0]["focal_std_px"] - 0.02 * f) < 1e-9
    assert main(["simulate", str(tmp_path / "b"), "--cameras", "3", "--frames", "20", "--focal-std"]) == 2
    assert "--intrinsics-error" in capsys.readouterr().err
    assert main(["simulate", str(tmp_path / "c"), "--take", "--frames", "20", "--intrinsics-error", "2"]) == 2
    assert "--take writes the rig's true intrinsics" in capsys.readouterr().err


def test_the_honest_sigma_covers_a_focal_length_off_by_its_stated_sigma():
    """Six cameras' focal lengths drawn 2% off, rig.json stating 2% (focal_std_px): each camera lies
    within 3 of its honest sigma of the truth (a Gaussian's 3 sigma: 99.7%), and the focal length
    is named as what limits every camera (its part is some 100 geometry sigmas)."""
    from bench.common import aligned_centres_mm
    from wandcal.calib.run.calibrate import calibrate

    sim = with_intrinsics_error(simulate_capture(6, 300, 0.3, 0.0, True, 2), IntrinsicsError(0.02, write_std=True), 2)
    doc = calibrate(sim.rig, sim.wand, sim.static).to_json()
    moved = aligned_centres_mm(np.array([c["center"] for c in doc["cameras"]]), sim.truth.centers)
    honest = np.array([c["geometry_std_honest_mm"] for c in doc["cameras"]])
    assert np.all(moved <= 3 * honest), (moved, honest)
    geometry = np.array([c["geometry_std_mm"] for c in doc["cameras"]])
    assert np.all(moved > 3 * geometry)  # the geometry sigma alone does not: the honest one is needed
    named = {lim["camera"] for lim in doc["verdict"]["limits"] if lim.get("parameter") == "focal length"}
    assert named == {c["id"] for c in doc["cameras"]}
