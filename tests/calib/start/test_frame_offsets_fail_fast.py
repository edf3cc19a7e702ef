"""The whole-frame search's fail-fast order (calib/start/frame_offsets.py, ``fail_fast``, what
guidance asks for): the same offsets where the search succeeds, a failure where it fails, and on a
sparse rig the failure proved from one camera's pair without timing the cameras before it."""

import numpy as np
import pytest

from wandcal.calib.errors import CalibrationError
from wandcal.calib.observations import wand_pairs
from wandcal.calib.rig import WandObservations
from wandcal.calib.sim.shapes import RigShape, default_size, simulate_shape
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.calib.start import frame_offsets as fo
from wandcal.calib.start.markerlabels import end_pairs

BROWN = "easywand_brown_windtunnel_4cam/calibration{}/extrinsicCalib_20230228_easyWandData.mat"


def _same(x: fo.FrameOffsets, y: fo.FrameOffsets) -> None:
    assert x.reference == y.reference
    for k in ("offsets", "timed_against", "share"):
        assert np.array_equal(getattr(x, k), getattr(y, k)), k


def test_fail_fast_finds_the_same_offsets_on_a_dense_rig():
    sim = simulate_capture(5, 600, 0.3, static=False, seed=4, offsets=np.array([0.0, 3.2, -4.4, 1.0, -0.6]))
    pairs = wand_pairs(sim.rig, sim.wand)
    _same(fo.frame_offsets(sim.rig, pairs, fail_fast=True), fo.frame_offsets(sim.rig, pairs))


def test_fail_fast_finds_the_same_offsets_on_a_digitised_session(shared_data):
    """Brown wind tunnel (easyWand, 4 cameras, 10-40 frames a pair: each shift its own RANSAC), cam3
    two frames out: the proof is tried (few frames shared) and must not refuse a camera it can time."""
    from wandcal.capture.importers.easywand import read_easywand_mat

    cap = read_easywand_mat(shared_data / BROWN.format(1)).capture
    w = cap.wand
    shifted = WandObservations(np.where(w.camera == 2, w.frame + 2, w.frame), w.camera, w.uv)
    pairs = end_pairs(cap.rig, shifted)
    plain = fo.frame_offsets(cap.rig, pairs)
    assert plain.offsets.tolist() == [0, 0, -2, 0]
    _same(fo.frame_offsets(cap.rig, pairs, fail_fast=True), plain)


def test_a_sparse_rig_fails_fast_with_few_ransacs(monkeypatch):
    """A 64-camera ring, each frame seen by 2-4 cameras: the default order fails (TooFewShared,
    tests/calib/test_sparse_offsets.py) after timing cameras one by one; the fail-fast order proves
    a camera untimeable from its partner's pair alone, at 4 x 3 - 1 = 11 lags of one pair each."""
    ring = simulate_shape(RigShape("ring", 64, default_size("ring")), 1500, 0.3, 0.02, seed=3)
    pairs = end_pairs(ring.rig, ring.wand)
    calls = []
    real = fo._pose_share
    monkeypatch.setattr(fo, "_pose_share", lambda *a: calls.append(a[2:5]) or real(*a))
    with pytest.raises(fo.TooFewShared, match="cannot be timed against"):
        fo.frame_offsets(ring.rig, pairs, 3, fail_fast=True)
    pairs_tried = {(a, b) for a, b, _ in calls}
    assert len(pairs_tried) <= 3 and len(calls) <= 11 * len(pairs_tried)


def test_fail_fast_raises_where_the_default_order_raises():
    # cam4 saw another session's wand: both orders refuse the search (CalibrationError)
    sim = simulate_capture(5, 600, 0.3, static=False, seed=4)
    other = simulate_capture(5, 600, 0.3, static=False, seed=99)
    keep, foreign = sim.wand.camera != 3, other.wand.camera == 3
    wand = WandObservations(*(np.concatenate([getattr(sim.wand, k)[keep], getattr(other.wand, k)[foreign]])
                              for k in ("frame", "camera", "uv")))
    pairs = wand_pairs(sim.rig, wand)
    with pytest.raises(CalibrationError, match="cam4"):
        fo.frame_offsets(sim.rig, pairs)
    with pytest.raises(CalibrationError, match="cam4"):
        fo.frame_offsets(sim.rig, pairs, fail_fast=True)
