"""Planar multi-marker wands (a five-marker T, Vicon Active Wand-like), simulated: the markers
labelled from the layout alone, and their known geometry inside ``ba`` against the Cramér–Rao
bound of the injected noise and against the two end markers alone on the same frames (as
tests/calib/solve/test_marker_wand.py does for collinear wands)."""

import numpy as np
import pytest

from tests.calib.solve.test_marker_wand import check_labels_and_accuracy
from wandcal.calib.errors import CalibrationError
from wandcal.calib.geometry import distort_points, project_normalized
from wandcal.calib.rig import Rig
from wandcal.calib.run.refine import build_problem
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.calib.solve import ba
from wandcal.calib.solve.markerwand import marker_model
from wandcal.calib.solve.wandmodel import WandModel
from wandcal.calib.start.initial import initial_poses
from wandcal.calib.start.markerlabels import label_interior, order_markers
from wandcal.calib.start.static import solve_static
from wandcal.calib.wandlayout import end_markers, plane_offsets

NOISE = 0.5  # px, the injected blob noise
# a T of five markers: a 420 mm bar with its joint 180 mm from one end, and two markers on a stem
# 120 and 300 mm from the joint. Vicon's exact spacing is not in our sources; an asymmetric bar is
# what tells its ends apart (a symmetric one is the same wand either way round)
T_WAND_M = np.array([[0.0, 0.0, 0.0], [0.18, 0.0, 0.0], [0.42, 0.0, 0.0], [0.18, 0.12, 0.0], [0.18, 0.30, 0.0]])


# a blob named for a marker whose true image lies farther than this is mislabelled: 8 sigma of the
# blob noise. Nearer, the two markers' images are within the noise of each other (a T's stem seen
# end on puts its three markers on one ray), and either name is right
MISLABEL_PX = 8 * NOISE


def _mislabelled(sim, blobs, labels):
    """(P,) rows with a blob named for a marker whose true image is more than ``MISLABEL_PX`` from it."""
    bad = np.zeros(len(blobs), bool)
    for c, cam in enumerate(sim.rig.cameras):
        sel = np.flatnonzero(blobs.camera == c)
        Xf = sim.truth.wand[blobs.frames[blobs.frame[sel]]]  # (p, K, 3) in layout order
        proj = distort_points(cam, project_normalized(sim.truth.R[c], sim.truth.t[c], Xf.reshape(-1, 3))).reshape(*Xf.shape[:2], 2)
        named = np.take_along_axis(proj, labels.marker[sel][..., None], axis=1)  # (p, K, 2) the image of each blob's marker
        bad[sel] = np.any(np.linalg.norm(labels.uv[sel] - named, axis=2) > MISLABEL_PX, axis=1)
    return bad


def _solve(seed, cameras=6, frames=400):
    """(sim, labels, mislabelled rows, rows' frames, ends-only poses, all-marker poses, the
    all-marker model at the truth)."""
    sim = simulate_capture(cameras, frames, NOISE, 0.0, True, seed, wand_markers=T_WAND_M)
    rig = sim.rig
    blobs = order_markers(rig, sim.wand)
    pairs = blobs.ends()  # labelled in each image: end 0 is the layout's own
    init = initial_poses(rig, pairs, solve_static(rig, sim.static))
    setup = build_problem(rig, pairs, init.R, init.t)
    x, info = ba.bundle_adjust(setup.model)
    assert info["status"] == "converged"
    R1, t1 = setup.model.poses(x)
    labels = label_interior(rig, blobs, pairs, R1, t1, (setup.frames, setup.model.wand(x)))
    model = marker_model(setup.problem, setup.pair_index, pairs.camera, labels.xy, labels.along, R1, t1,
                         setup.model.wand(x), setup.model.fixed, labels.across)[0]
    x2, info = ba.bundle_adjust(model)
    assert info["status"] == "converged"
    # the model at the truth (for the bound): the true ends and planes of the solved frames
    T = sim.truth
    a, b = end_markers(T_WAND_M)
    Xt = T.wand[setup.frames]
    ends = Xt[:, [a, b]]
    d = (ends[:, 1] - ends[:, 0]) / np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1, keepdims=True)
    off = plane_offsets(T_WAND_M)
    k = int(np.argmax(np.abs(off[:, 1])))
    v = Xt[:, k] - ends.mean(axis=1) - off[k, 0] * d
    truth_model = WandModel(model.p, T.R, T.t, ends, setup.model.fixed, v / off[k, 1])
    return sim, labels, _mislabelled(sim, blobs, labels), blobs.frame, setup.model.poses(x), model.poses(x2), truth_model


@pytest.mark.long
def test_t_wand_labels_and_accuracy_against_the_bound_and_the_ends_alone():
    def runs():
        for seed in range(6):
            sim, labels, bad_rows, row_frame, ends_pose, all_pose, truth_model = _solve(seed)
            yield sim, row_frame, bad_rows, ends_pose, all_pose, truth_model

    check_labels_and_accuracy(runs(), "T-wand")


@pytest.mark.parametrize("method", ["ba", "lp"])
def test_a_t_wand_capture_calibrates_in_one_command(tmp_path, capsys, method):
    """rig.json with a planar wand.markers_m round-trips and 'wandcal calibrate' solves it with
    every marker (ba; lp with the markers on the axis), one length error for each of the 10 pairs."""
    import json

    from wandcal.calib.geometry import camera_centers
    from wandcal.capture.folder import read_capture, write_capture
    from wandcal.service.cli import main

    sim = simulate_capture(5, 300, NOISE, 0.0, True, 1, wand_markers=T_WAND_M)
    write_capture(tmp_path, sim.rig, sim.wand, sim.static)
    assert np.allclose(read_capture(tmp_path).rig.wand_markers, T_WAND_M)
    out = tmp_path / "out.json"
    assert main(["calibrate", str(tmp_path), "--quiet", "--method", method, "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    C = np.array([c["center"] for c in doc["cameras"]])
    std = np.array([c["center_std_mm"] for c in doc["cameras"]]) / 1000
    # within 4 of the result's own 1-sigma centre uncertainty (the L-frame's placement included)
    assert np.all(np.linalg.norm(C - camera_centers(sim.truth.R, sim.truth.t), axis=1) < 4 * std)
    pairs = doc["wand"]["marker_pairs"]
    assert [p["markers"] for p in pairs] == [[i, j] for i in range(5) for j in range(i + 1, 5)]
    for p in pairs:
        # each pair's distance, both markers triangulated freely: unbiased within a few standard
        # errors of its mean, and spread like a two-marker wand's length (~1-2 mm at 0.5 px)
        assert abs(p["mean_error_m"]) < 4 * p["std_m"] / np.sqrt(p["frames"]) and p["std_m"] < 0.004


def test_planar_layouts_are_checked():
    cams = simulate_capture(2, 10, seed=0).rig.cameras
    assert Rig(cams, None, wand_markers=T_WAND_M).wand_length == pytest.approx(0.42)
    with pytest.raises(CalibrationError, match="a planar wand needs 4 or more markers"):
        Rig(cams, None, wand_markers=[[0, 0, 0], [0.5, 0, 0], [0.25, 0.1, 0]])
    with pytest.raises(CalibrationError, match=r"marker 3 is 8.0 mm off the plane through markers 0, 2 and 4"):
        Rig(cams, None, wand_markers=[[0, 0, 0], [0.18, 0, 0], [0.42, 0, 0], [0.18, 0.12, 0], [0.18, 0.3, 0.02]])
    with pytest.raises(CalibrationError, match="markers 3 and 4 coincide"):
        Rig(cams, None, wand_markers=[[0, 0, 0], [0.18, 0, 0], [0.42, 0, 0], [0.18, 0.12, 0], [0.18, 0.12, 0.0002]])
