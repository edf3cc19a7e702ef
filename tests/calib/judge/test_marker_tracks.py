"""Issue 31: a multi-marker wand's interior markers enter the judgement as point tracks, so that a
sparse capture's fault can be found where the wand's two ends alone are too few."""

from __future__ import annotations

import numpy as np
import pytest

from wandcal.calib.observations import PointTracks, WandPairs
from wandcal.calib.run import calibrate as pipeline
from wandcal.calib.sim.faults import knocked_camera
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.calib.start.markerlabels import MarkerLabels, interior_tracks

THREE_M = np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.5, 0.0, 0.0]])  # simulate --wand three


def test_each_frames_interior_marker_is_a_point_seen_by_the_cameras_that_see_it():
    # frame 0 seen by cameras 0, 1, 2; frame 1 by camera 2 only (its markers are one view: left out);
    # frame 2 by cameras 1 and 0, the second row reversed (its end 0 the layout's last marker)
    frame, camera = np.array([0, 0, 0, 1, 2, 2]), np.array([2, 0, 1, 2, 1, 0])
    P, K = len(frame), 4
    xy = np.arange(P * K * 2, dtype=float).reshape(P, K, 2)
    marker = np.tile([0, 1, 2, 3], (P, 1))
    marker[4:] = [3, 2, 1, 0]
    labels = MarkerLabels(marker, xy, xy + 1000, np.zeros((P, K)), np.zeros(3, bool))
    pairs = WandPairs(frame, camera, xy[:, [0, -1]], xy[:, [0, -1]] + 1000, np.array([10, 11, 12]))
    tracks = interior_tracks(labels, pairs)
    assert tracks.n_tracks == 4 and len(tracks) == 10  # frames 0 and 2, markers 1 and 2 each
    assert list(tracks.frames) == [10, 10, 12, 12] and list(tracks.labels) == ["wand marker 1", "wand marker 2"] * 2
    for q in range(len(tracks)):  # each observation is its row's blob of that marker, in normalised and raw pixels
        row = np.flatnonzero((camera == tracks.camera[q]) & (pairs.frames[frame] == tracks.frames[tracks.track[q]]))[0]
        k = int(np.flatnonzero(marker[row] == int(tracks.labels[tracks.track[q]][-1]))[0])
        assert np.array_equal(tracks.xy[q], xy[row, k]) and np.array_equal(tracks.uv[q], xy[row, k] + 1000)
    assert np.all(np.diff(tracks.track) >= 0)  # sorted by track, then camera (as point_tracks gives them)
    assert all(np.all(np.diff(tracks.camera[tracks.track == j]) > 0) for j in range(4))


def test_tracks_joined_keep_their_points_apart():
    a = PointTracks(np.array([0, 0]), np.array([0, 1]), np.zeros((2, 2)), np.zeros((2, 2)), np.array([5]), {"x": 1})
    b = PointTracks(np.array([0, 0, 1, 1]), np.array([0, 2, 1, 2]), np.ones((4, 2)), np.ones((4, 2)), np.array([7, 8]))
    both = a.joined(b)
    assert list(both.track) == [0, 0, 1, 1, 2, 2] and list(both.frames) == [5, 7, 8] and both.dropped == {"x": 1}
    assert both.labels is None and np.array_equal(both.xy[2:], b.xy)


def _faults(sim, ends_only: bool) -> set:
    """The faults ``calibrate`` names, as (kind, camera); ``ends_only``: the judgement given the
    wand's ends alone, as before issue 31 (the capture has no point tracks of its own)."""
    judge = pipeline.judge

    def without(*a, **k):
        return judge(*a[:8], None, *a[9:], **k)

    pipeline.judge = without if ends_only else judge
    try:
        doc = pipeline.calibrate(sim.rig, sim.wand, sim.static).to_json()
    finally:
        pipeline.judge = judge
    return {(f["kind"], f["camera"]) for f in doc["verdict"]["faults"]}


@pytest.mark.parametrize("seed, camera", [
    (300, 1),
    # decision 0076 (every camera's lens beside the step) costs this 4 x 40 capture its knock: on
    # bench_marker_judgement's 160 sparse cases, every marker 84 -> 83 right, one wrong-camera `moved` fewer
    pytest.param(302, 0, marks=pytest.mark.xfail(strict=True, reason="the knock missed since decision 0076 (issue 31)")),
])
def test_a_knock_on_a_sparse_three_marker_capture_is_found_by_its_interior_markers(seed, camera):
    # 4 cameras, 40 frames, each marker hidden from a camera one time in five: each camera sees the
    # whole wand with two others in ~10 frames, as the real hand-digitised sessions do (2-8)
    sim = simulate_capture(4, 40, 0.3, 0.0, True, seed, wand_markers=THREE_M, occlusion=0.2)
    sim = knocked_camera(sim, camera, 0.5, seed)
    cam = sim.rig.cameras[camera].id
    # the ends alone were too few to tell it a knock before decision 0076; they may tell more now (a fault
    # of some kind on the knocked camera), but never name another camera
    assert {camera for _, camera in _faults(sim, ends_only=True)} <= {cam}
    assert _faults(sim, ends_only=False) == {("moved", cam)}
