"""The whole-frame search's fail-fast order (calib/start/offsets/whole_frames.py, ``fail_fast``, what
guidance asks for): the same offsets where the search succeeds, a failure where it fails, and on a
sparse rig the failure proved from one camera's pair without timing the cameras before it."""

import numpy as np
import pytest

from wandcal.calib.errors import CalibrationError
from wandcal.calib.observations import wand_pairs
from wandcal.calib.rig import WandObservations
from wandcal.calib.sim.shapes import RigShape, default_size, simulate_shape
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.calib.start.markerlabels import end_pairs
from wandcal.calib.start.offsets import pair_fit
from wandcal.calib.start.offsets import shift_search as ss
from wandcal.calib.start.offsets import whole_frames as fo

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
    real = pair_fit.pose_share
    monkeypatch.setattr(pair_fit, "pose_share", lambda *a: calls.append(a[2:5]) or real(*a))
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


@pytest.fixture(scope="module")
def sparse_ring():
    ring = simulate_shape(RigShape("ring", 64, default_size("ring")), 1500, 0.3, 0.02, seed=3)
    return ring.rig, end_pairs(ring.rig, ring.wand)


def test_prove_sparse_refuses_as_the_default_does_with_few_ransacs(sparse_ring, monkeypatch):
    """calibrate's sync (``prove_sparse``): the default search refuses this ring with TooFewShared
    (tests/calib/test_sparse_offsets.py), and so does the proof, from one pair's 4 x 8 - 1 = 31 lags
    at calibrate's +-8 frames, without timing the cameras planned before it."""
    rig, pairs = sparse_ring
    calls = []
    real = pair_fit.pose_share
    monkeypatch.setattr(pair_fit, "pose_share", lambda *a: calls.append(a[2:5]) or real(*a))
    with pytest.raises(fo.TooFewShared, match="cannot be timed against"):
        fo.frame_offsets(rig, pairs, 8, prove_sparse=True)
    pairs_tried = {(a, b) for a, b, _ in calls}
    assert len(pairs_tried) <= 3 and len(calls) <= 31 * len(pairs_tried)


def _proved(rig, pairs, window: int) -> tuple[ss.ShiftSearch, int, int]:
    """The search over ``pairs`` (which the proof refuses) and the first planned (camera, first
    partner) that :meth:`ShiftSearch.cannot_time` proves (cam57 against cam1, with 8 frames at an
    edge lag; the proof itself names the cheapest it proves)."""
    table = fo.frame_table(pairs, len(rig.cameras))
    steps, _ = fo._plan(fo._links(table >= 0, window), 0)
    search = ss.ShiftSearch(rig, pairs, table, np.zeros(len(rig.cameras), np.int64), 0, window)
    with pytest.raises(fo.TooFewShared, match="cannot be timed against") as refused:
        fo._refuse_untimeable(search, steps, table)
    named = next(c for c, cam in enumerate(rig.cameras) if refused.value.args[0].startswith(f"camera {cam.id!r}"))
    b, a = next((b, p[0]) for b, p in steps if fo.shared_counts(table, p[0], b, np.zeros(1, np.int64))[0]
                < fo.MIN_TIMING_FRAMES and search.cannot_time(b, p[0]))
    # the camera named is one the search proves too, at no more RANSACs than the first planned
    assert search.cannot_time(named, dict(steps)[named][0])
    assert search.proof_cost(named, dict(steps)[named][0]) <= search.proof_cost(b, a)
    return search, b, a


def test_a_shift_accepted_at_the_edge_is_no_proof(sparse_ring, monkeypatch):
    """Where one offset of the partner would let the camera's best shift pass at the edge of its
    search, the search refuses it there with "at the edge of the search", not TooFewShared: the
    proof must not claim it (the caller falls back on TooFewShared, and refuses on the other)."""
    rig, pairs = sparse_ring
    search, b, a = _proved(rig, pairs, 8)
    assert search.cannot_time(b, a)
    offset_a = search.partner_offsets(a)[0]
    # an edge shift of b's where the pair shares enough frames to be judged (cam57's first, against cam1)
    edge_lag = max((offset_a - int(s) for s in search.shifts(b)[[0, -1]]),
                   key=lambda lag: fo.shared_counts(search.table, a, b, np.array([lag]))[0])
    assert fo.shared_counts(search.table, a, b, np.array([edge_lag]))[0] >= fo.MIN_TIMING_FRAMES
    # b's wand fits a's at that lag alone, by far: the default search accepts the shift, at the edge
    monkeypatch.setattr(ss, "lag_share", lambda pairs, table, a_, b_, lag, rig: 0.9 if lag == edge_lag else 0.0)
    best, score = ss.sparse_best_shift(pairs, search.table, (a, offset_a), b, search.shifts(b), rig)
    assert score >= ss.MIN_FIT_SHARE and abs(best) == search.max_offset
    assert not search.cannot_time(b, a)


def test_no_proof_while_a_camera_planned_before_is_not_sparse(sparse_ring, monkeypatch):
    """A camera planned before the one proved that shares ``FEW_FRAMES`` frames with its partner at
    some lag is judged by the midpoint scores, which may refuse it otherwise than TooFewShared: then
    the planned search decides, as by default."""
    rig, pairs = sparse_ring
    table = fo.frame_table(pairs, len(rig.cameras))
    steps, _ = fo._plan(fo._links(table >= 0, 8), 0)
    search = ss.ShiftSearch(rig, pairs, table, np.zeros(len(rig.cameras), np.int64), 0, 8)
    few = [i for i, (b, p) in enumerate(steps) if fo.shared_counts(table, p[0], b, np.zeros(1, np.int64))[0]
           < fo.MIN_TIMING_FRAMES]
    later = steps[few[1]][0]  # a camera the proof tries, planned after others
    monkeypatch.setattr(ss.ShiftSearch, "cannot_time", lambda self, b, a: b == later)
    with pytest.raises(fo.TooFewShared, match=f"'{rig.cameras[later].id}'"):
        fo._refuse_untimeable(search, steps, table)  # every camera before it sparse (the ring's are)
    earlier = steps[few[1] - 1][0]
    monkeypatch.setattr(ss.ShiftSearch, "sparse_everywhere", lambda self, c, a: c != earlier)
    fo._refuse_untimeable(search, steps, table)  # no proof: returns
