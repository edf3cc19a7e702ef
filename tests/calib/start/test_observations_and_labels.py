import numpy as np
import pytest

from wandcal.calib.errors import CalibrationError
from wandcal.calib.geometry import project_normalized
from wandcal.calib.observations import wand_pairs
from wandcal.calib.rig import WandObservations
from wandcal.calib.sim.scenes import prepared_scene as prepared
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.calib.start.labels import label_ends


def _agree_with_truth(pairs, truth):
    X = truth.wand[pairs.frames]
    proj = np.stack([project_normalized(truth.R[pairs.camera], truth.t[pairs.camera], X[pairs.frame, e]) for e in range(2)], 1)
    return np.linalg.norm(proj - pairs.xy, axis=2).sum(1) < np.linalg.norm(proj[:, ::-1] - pairs.xy, axis=2).sum(1)


def test_pairs_drop_and_count_garbage():
    sim = simulate_capture(3, 50, 0.2, seed=3)
    w = sim.wand
    # a third blob in camera 0, frame 10
    extra = WandObservations(np.r_[w.frame, 10], np.r_[w.camera, 0], np.vstack([w.uv, [[5.0, 5.0]]]))
    pairs = wand_pairs(sim.rig, extra)
    assert pairs.dropped["extra_blobs"] == 1
    assert not np.any((pairs.camera == 0) & (pairs.frames[pairs.frame] == 10))
    assert pairs.dropped["one_blob"] == int(np.sum(np.unique(w.frame * 3 + w.camera, return_counts=True)[1] == 1))


def test_nan_blob_names_camera_and_frame():
    sim = simulate_capture(3, 20, 0.2, seed=3)
    uv = sim.wand.uv.copy()
    uv[7, 0] = np.nan
    bad = WandObservations(sim.wand.frame, sim.wand.camera, uv)
    with pytest.raises(CalibrationError, match=rf"camera '{sim.rig.cameras[sim.wand.camera[7]].id}' in frame {sim.wand.frame[7]}"):
        wand_pairs(sim.rig, bad)


@pytest.mark.parametrize("static", [True, False])
def test_labels_consistent_with_truth_in_every_frame(static):
    sc = prepared(cameras=6, frames=300, noise_px=0.5, seed=4, static=static)
    sim, labelled = sc.sim, sc.labelled
    same = _agree_with_truth(labelled, sim.truth)
    for f in np.unique(labelled.frame):
        v = same[labelled.frame == f]
        assert v.all() or (~v).all(), f"frame {labelled.frames[f]} has inconsistent end labels"


def test_labels_consistent_for_random_wands_seen_by_few_cameras():
    """The seed paper's protocol: random wand positions and directions, many frames seen by only
    two or three cameras, wands near epipolar planes. With the true poses, every frame's ends
    must be matched consistently across its cameras."""
    from wandcal.calib.sim.simulate import simulate_paper_protocol

    bad = 0
    for seed in range(5011, 5015):
        sim, _, _ = simulate_paper_protocol(0.5, seed)
        pairs = wand_pairs(sim.rig, sim.wand)
        T = sim.truth
        labelled, _ = label_ends(T.R, T.t, pairs, np.ones(4, bool), sim.rig.wand_length)
        same = _agree_with_truth(labelled, T)
        for f in np.unique(labelled.frame):
            v = same[labelled.frame == f]
            bad += not (v.all() or (~v).all())
    assert bad == 0
