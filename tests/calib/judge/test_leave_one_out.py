"""Each camera of a small rig against the points the others triangulate (calib/judge/faults/leave_one_out.py)."""

from __future__ import annotations

import numpy as np

from wandcal.calib.judge.faults.leave_one_out import camera_patterns, leave_one_out_faults
from wandcal.calib.observations import wand_pairs
from wandcal.calib.sim.faults import wrong_focal
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.calib.start.labels import label_ends


def _judged(sim, R, t):
    pairs = label_ends(R, t, wand_pairs(sim.rig, sim.wand), np.ones(len(sim.rig.cameras), bool), sim.rig.wand_length)[0]
    return leave_one_out_faults(list(sim.rig.ids), R, t, pairs, None), pairs


def test_a_clean_small_rig_names_no_camera():
    sim = simulate_capture(4, 400, 0.3, 0.0, False, 3)
    faults, pairs = _judged(sim, sim.truth.R, sim.truth.t)
    assert faults == []
    for c in range(4):  # 0.3 px of noise: no pattern near the limits
        p = camera_patterns(sim.truth.R, sim.truth.t, pairs, None, c)
        assert p.lens.f_stat < 25 and p.knock.f_stat < 25


def test_a_focal_length_8_percent_off_is_named_on_its_camera():
    sim = wrong_focal(simulate_capture(4, 400, 0.3, 0.0, False, 3), 2, 1.08)
    faults, _ = _judged(sim, sim.truth.R, sim.truth.t)
    assert [(f["kind"], f["camera"]) for f in faults] == [("intrinsics", sim.rig.cameras[2].id)]
    # rig.json's focal length is 8% above the images': the data suggest 1/1.08 of it, -7.4%
    assert abs(faults[0]["evidence"]["intrinsics"]["focal_error"] - (1 - 1 / 1.08)) < 0.02


def test_fy_alone_off_is_named_on_its_camera_with_its_aspect_error():
    """rig.json's fy 3% off on one camera (fx right): a stretch along y its pose cannot take up,
    fitted by the lens pattern's fy column where that is significant (decision 0058)."""
    from dataclasses import replace

    sim = simulate_capture(4, 400, 0.3, 0.0, False, 3)
    cam = sim.rig.cameras[2]
    K = cam.K.copy()
    K[1, 1] *= 1.03
    sim = replace(sim, rig=replace(sim.rig, cameras=tuple(replace(c, K=K) if c is cam else c for c in sim.rig.cameras)))
    faults, _ = _judged(sim, sim.truth.R, sim.truth.t)
    assert [(f["kind"], f["camera"]) for f in faults] == [("intrinsics", cam.id)]
    # its y normalised by 1.03 times the true fy: r_y = y (1 - 1/1.03) beyond any focal error common
    # to both axes; the common column takes none of it where x is right (0.3 px noise on 400 frames:
    # the coefficients are known to far better than the 1% allowed here)
    intr = faults[0]["evidence"]["intrinsics"]
    assert abs(intr["aspect_error"] + intr["focal_error"] - (1 - 1 / 1.03)) < 0.01
