"""Whole-frame offsets on a sparse rig (calib/run/sparse_offsets.py): each frame seen by 2-4 of 64
cameras, so no two share enough frames to time one against the other; all of them together do."""

import numpy as np
import pytest

from wandcal.calib.errors import CalibrationError
from wandcal.calib.rig import WandObservations
from wandcal.calib.run.sparse_offsets import offsets_by_triangulation
from wandcal.calib.sim.shapes import RigShape, default_size, simulate_shape
from wandcal.calib.start.labels import label_ends
from wandcal.calib.start.markerlabels import end_pairs
from wandcal.calib.start.offsets.whole_frames import TooFewShared, frame_offsets, shift_pairs
from wandcal.calib.start.static import solve_static


@pytest.fixture(scope="module")
def ring():
    return simulate_shape(RigShape("ring", 64, default_size("ring")), 1500, 0.3, 0.02, seed=3)


def _renumbered(wand: WandObservations, true: np.ndarray) -> WandObservations:
    """Each camera c's frames on its own clock: its frame k was exposed at the reference's k + true[c]."""
    return WandObservations(wand.frame - true[wand.camera], wand.camera, wand.uv)


def test_a_sparse_rig_in_time_is_timed_by_all_the_cameras_together(ring):
    pairs = end_pairs(ring.rig, ring.wand)
    with pytest.raises(TooFewShared):  # the pairwise search cannot time it
        frame_offsets(ring.rig, pairs)
    found, start = offsets_by_triangulation(ring.rig, pairs, 8, static_poses=solve_static(ring.rig, ring.static))
    assert not found.offsets.any()
    assert start is not None and np.isfinite(start.init.R).all()
    # calibrate's start takes the sync's labels: the pairs at the offsets found, labelled at its poses
    R, t, known = start.init.R, start.init.t, np.ones(len(ring.rig.cameras), bool)
    again = label_ends(R, t, shift_pairs(pairs, found.offsets), known, ring.rig.wand_length)[0]
    for field in ("frames", "frame", "camera", "xy"):
        assert np.array_equal(getattr(start.labelled, field), getattr(again, field))


def test_cameras_a_frame_or_two_out_of_time_are_found(ring):
    true = np.zeros(len(ring.rig.cameras), np.int64)
    true[[7, 29, 40, 54]] = [1, 2, -1, -2]
    pairs = end_pairs(ring.rig, _renumbered(ring.wand, true))
    found, _ = offsets_by_triangulation(ring.rig, pairs, 8, static_poses=solve_static(ring.rig, ring.static))
    assert np.array_equal(found.offsets, true)


def test_a_camera_of_another_session_is_refused_by_name(ring):
    # cam20 recorded another stretch of the session: its frames are 700 frames away from the others'
    true = np.zeros(len(ring.rig.cameras), np.int64)
    true[19] = 700
    pairs = end_pairs(ring.rig, _renumbered(ring.wand, true))
    with pytest.raises(CalibrationError, match="'cam20' does not move with the others"):
        offsets_by_triangulation(ring.rig, pairs, 8, static_poses=solve_static(ring.rig, ring.static))
