"""Each camera's own errors with the points eliminated (wandcal.calib.judge.faults.own_errors and
pose_steps, composed by wandcal.calib.run.own_error_faults.own_faults), on a
seeded four-camera rig tracking one marker (timed point tracks, as MultiCamSelfCal's): noise put
on one camera stays with it, a knocked camera is named with its frame and angle, a clean rig names
nothing. Tolerances come from the injected noise: the estimates' own standard errors."""

from __future__ import annotations

import numpy as np
import pytest

from wandcal.calib.geometry import rotvec_to_matrix
from wandcal.calib.judge.faults import own_errors as oe
from wandcal.calib.judge.faults.pose_steps import MAX_SPLITS
from wandcal.calib.observations import PointTracks, WandPairs
from wandcal.calib.rig import Camera, Rig
from wandcal.calib.run.own_error_faults import own_faults

FOCAL_PX = 1000.0
NOISE_PX = 0.5
FRAMES = 400


def _look_at(centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    z = -centre / np.linalg.norm(centre)
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    return R, -R @ centre


def _rig(n: int = 4):
    poses = [_look_at(np.array([3 * np.cos(a), 3 * np.sin(a), 1.0])) for a in np.linspace(0, 2 * np.pi, n, endpoint=False)]
    return np.stack([p[0] for p in poses]), np.stack([p[1] for p in poses])


def _tracks(R, t, rng, noise_px=None, knock=None) -> PointTracks:
    """A marker wandering through a 1.5 m volume, one position a frame, seen by every camera;
    noise_px: (N,) each camera's noise; knock: (camera, frame, rotation vector) turns that camera
    after that frame."""
    n = len(R)
    noise_px = np.full(n, NOISE_PX) if noise_px is None else np.asarray(noise_px)
    X = np.cumsum(rng.normal(0, 0.05, (FRAMES, 3)), axis=0)
    X = 0.75 * np.tanh(X / 0.75)  # kept inside the volume
    track, camera, xy = [], [], []
    for c in range(n):
        Xc = X @ R[c].T + t[c]
        if knock is not None and knock[0] == c:
            after = np.arange(FRAMES) > knock[1]
            Xc[after] = Xc[after] @ rotvec_to_matrix(knock[2]).T
        p = Xc[:, :2] / Xc[:, 2:] + rng.normal(0, noise_px[c] / FOCAL_PX, (FRAMES, 2))
        track.append(np.arange(FRAMES))
        camera.append(np.full(FRAMES, c))
        xy.append(p)
    track, camera, xy = np.concatenate(track), np.concatenate(camera), np.concatenate(xy)
    order = np.lexsort((camera, track))
    return PointTracks(track[order], camera[order], xy[order], xy[order] * FOCAL_PX, np.arange(FRAMES))


def _faults(tracks: PointTracks, R, t):
    K = np.array([[FOCAL_PX, 0, 640], [0, FOCAL_PX, 480], [0, 0, 1]])
    rig = Rig(tuple(Camera(f"cam{k}", 1280, 960, K, np.zeros(5)) for k in range(len(R))), None)
    return own_faults(rig, WandPairs.empty(), tracks, R, t)


def test_a_clean_rig_names_nothing_and_measures_its_noise():
    R, t = _rig()
    tracks = _tracks(R, t, np.random.default_rng(1))
    el = oe.eliminate(R, t, oe.views_of(WandPairs.empty(), tracks))
    noise = oe.camera_noise(el, np.full(len(R), FOCAL_PX))
    for n in noise:
        assert abs(n.sigma_px - NOISE_PX) < 4 * NOISE_PX / np.sqrt(FRAMES)  # sigma's standard error ~ sigma / sqrt(2 dof)
        assert abs(n.ratio - 1) < 4 * n.ratio_std
    assert _faults(tracks, R, t) == ([], [])


def test_noise_on_one_camera_stays_with_it():
    R, t = _rig()
    tracks = _tracks(R, t, np.random.default_rng(2), noise_px=[NOISE_PX, NOISE_PX, 3 * NOISE_PX, NOISE_PX])
    el = oe.eliminate(R, t, oe.views_of(WandPairs.empty(), tracks))
    noise = oe.camera_noise(el, np.full(len(R), FOCAL_PX))
    assert abs(noise[2].ratio - 3) < 4 * noise[2].ratio_std
    assert all(abs(n.ratio - 1) < 4 * n.ratio_std for c, n in enumerate(noise) if c != 2)
    moved, noisy = _faults(tracks, R, t)
    assert moved == [] and [f["camera"] for f in noisy] == ["cam2"]


@pytest.mark.parametrize("ratio, at_limit", [(1.0, False), (1.35, True), (1.5, True), (1.69, True), (1.71, False)])
def test_noise_within_two_standard_errors_of_its_limit_is_at_the_limit(ratio, at_limit):
    # NOISE_LIMIT 1.5, NOISE_Z 2: with a standard error of 0.1 the band is 1.3-1.7; beyond it a fault is named
    entry = oe.noise_at_limit("cam2", oe.Noise(ratio * 0.4, 0.4, ratio, 0.1, 500))
    assert (entry is not None) == at_limit
    if entry is not None:
        assert entry["camera"] == "cam2" and "noise" in entry["criterion"] and entry["levels"] == ["good", "poor"]
        assert entry["value"] == ratio and entry["limit"] == oe.NOISE_LIMIT and entry["std"] == 0.1


@pytest.mark.parametrize("camera, degrees", [(1, 0.3), (3, 0.8)])
def test_a_knocked_camera_is_named_with_its_frame_and_angle(camera, degrees):
    R, t = _rig()
    rng = np.random.default_rng(3 + camera)
    axis = rng.normal(size=3)
    w = np.radians(degrees) * axis / np.linalg.norm(axis)
    tracks = _tracks(R, t, rng, knock=(camera, 250, w))
    moved, noisy = _faults(tracks, R, t)
    assert [f["camera"] for f in moved] == [f"cam{camera}"] and noisy == []
    ev = moved[0]["evidence"]
    # the split is searched among MAX_SPLITS candidates: the frame within one candidate's spacing
    assert abs(ev["frame"] - 250) <= FRAMES / MAX_SPLITS + 1
    assert abs(ev["degrees"] - degrees) < 4 * ev["degrees_std"] + 0.02 * degrees


# -- point tracks in the wand's time (issue 31: every observation a camera has in time) ----------

WAND_FRAMES = 16  # a sparse wand, as Brown's: each frame seen by one ring pair of cameras


def _sparse_wand(R, t, rng, knock=None) -> WandPairs:
    """WAND_FRAMES frames of a 0.5 m wand spread through the tracks' FRAMES, each seen by one ring
    pair of cameras (2 of 4), with NOISE_PX; knock as in :func:`_tracks`."""
    n = len(R)
    frames = np.linspace(5, FRAMES - 5, WAND_FRAMES).astype(np.int64)
    mid = rng.uniform(-0.5, 0.5, (WAND_FRAMES, 3))
    d = rng.normal(size=(WAND_FRAMES, 3))
    ends = mid[:, None] + 0.25 * np.array([-1.0, 1.0])[None, :, None] * (d / np.linalg.norm(d, axis=1, keepdims=True))[:, None]
    frame, camera, xy = [], [], []
    for f in range(WAND_FRAMES):
        for c in (f % n, (f + 1) % n):
            Xc = ends[f] @ R[c].T + t[c]
            if knock is not None and knock[0] == c and frames[f] > knock[1]:
                Xc = Xc @ rotvec_to_matrix(knock[2]).T
            frame.append(f)
            camera.append(c)
            xy.append(Xc[:, :2] / Xc[:, 2:] + rng.normal(0, NOISE_PX / FOCAL_PX, (2, 2)))
    xy = np.array(xy)
    return WandPairs(np.array(frame), np.array(camera), xy, xy * FOCAL_PX, frames)


def _wand_faults(labelled: WandPairs, tracks: PointTracks, R, t):
    K = np.array([[FOCAL_PX, 0, 640], [0, FOCAL_PX, 480], [0, 0, 1]])
    rig = Rig(tuple(Camera(f"cam{k}", 1280, 960, K, np.zeros(5)) for k in range(len(R))), 0.5)
    return own_faults(rig, labelled, tracks, R, t)


def test_point_tracks_within_the_wands_frames_are_timed_and_those_of_another_recording_are_not():
    R, t = _rig()
    rng = np.random.default_rng(7)
    labelled, tracks = _sparse_wand(R, t, rng), _tracks(R, t, rng)
    views = oe.views_of(labelled, tracks)
    wand = np.arange(len(views.point)) < 2 * len(labelled)  # views_of puts the wand's ends first
    span = (views.time >= labelled.frames.min()) & (views.time <= labelled.frames.max())
    np.testing.assert_array_equal(views.timed, wand | span)
    assert (views.timed & ~wand).sum() > 0.9 * len(tracks)  # the tracks before the first and after the last wand frame are not
    # an importer numbers another recording's points from the power of ten above every wand frame
    other = PointTracks(tracks.track, tracks.camera, tracks.xy, tracks.uv, tracks.frames + 1000)
    views = oe.views_of(labelled, other)
    assert views.timed.sum() == 2 * len(labelled)  # the wand's ends only


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_a_sparse_wand_with_tracks_in_its_time_names_nothing_on_a_clean_rig(seed):
    R, t = _rig()
    rng = np.random.default_rng(seed)
    assert _wand_faults(_sparse_wand(R, t, rng), _tracks(R, t, rng), R, t) == ([], [])


@pytest.mark.parametrize("camera, degrees", [(0, 0.4), (2, 0.8)])
def test_a_camera_knocked_under_a_sparse_wand_is_named_from_its_point_tracks_in_time(camera, degrees):
    R, t = _rig()
    rng = np.random.default_rng(20 + camera)
    axis = rng.normal(size=3)
    knock = (camera, 250, np.radians(degrees) * axis / np.linalg.norm(axis))
    labelled, tracks = _sparse_wand(R, t, rng, knock), _tracks(R, t, rng, knock=knock)
    moved, noisy = _wand_faults(labelled, tracks, R, t)
    assert [f["camera"] for f in moved] == [f"cam{camera}"] and noisy == []
    ev = moved[0]["evidence"]
    assert abs(ev["frame"] - 250) <= FRAMES / MAX_SPLITS + 1
    assert abs(ev["degrees"] - degrees) < 4 * ev["degrees_std"] + 0.02 * degrees


def test_a_large_rigs_screen_times_the_tracks_in_the_wands_time():
    """More than five cameras: the step screen (moved.step_suspects) reads the point tracks
    in the wand's time as timed views, and the knocked camera is suspected and named."""
    from wandcal.calib.judge.faults.moved import step_suspects
    from wandcal.calib.judge.residuals import observation_residuals

    R, t = _rig(6)
    rng = np.random.default_rng(31)
    axis = rng.normal(size=3)
    knock = (4, 250, np.radians(0.5) * axis / np.linalg.norm(axis))
    labelled, tracks = _sparse_wand(R, t, rng, knock), _tracks(R, t, rng, knock=knock)
    res = observation_residuals(R, t, labelled, tracks, np.full((6, 2), FOCAL_PX))
    assert step_suspects(res, tracks.frames)[:1] == [4]
    # the same tracks from another recording (numbered above every wand frame) are not timed
    assert 4 not in step_suspects(res, tracks.frames + 1000)
    K = np.array([[FOCAL_PX, 0, 640], [0, FOCAL_PX, 480], [0, 0, 1]])
    rig = Rig(tuple(Camera(f"cam{k}", 1280, 960, K, np.zeros(5)) for k in range(6)), 0.5)
    moved, _ = own_faults(rig, labelled, tracks, R, t, [], res)
    assert [f["camera"] for f in moved] == ["cam4"]


def test_the_refits_written_out_products_are_the_dense_ones():
    # the elimination's refit (decision 0090): J, the normal matrices, their inverses and the
    # redundancies as the dense products give them, on random views of random points
    rng = np.random.default_rng(3)
    M, P = 200, 60
    R = np.stack([rotvec_to_matrix(rng.normal(0, 0.3, 3)) for _ in range(4)])
    camera, point = rng.integers(0, 4, M), rng.integers(0, P, M)
    Xc = rng.normal(0, 1, (M, 3)) + [0, 0, 5]
    proj, z, w = Xc[:, :2] / Xc[:, 2:], Xc[:, 2], rng.uniform(0.5, 2, M)
    D = np.zeros((M, 2, 3))
    D[:, 0, 0] = D[:, 1, 1] = 1 / z
    D[:, :, 2] = -proj / z[:, None]
    dense = np.einsum("mij,mjk->mik", D, R[camera]) * w[:, None, None]
    J = oe._whitened_jacobian(tuple(R[camera][:, i] for i in range(3)), proj, z, w)
    np.testing.assert_allclose(J, dense, rtol=1e-12, atol=1e-15)
    r = rng.normal(0, 1, (M, 2))
    A, b = oe._normal(J, r, point, P)
    np.testing.assert_allclose(A, np.stack([sum(J[m].T @ J[m] for m in np.flatnonzero(point == p)) if (point == p).any()
                                            else np.zeros((3, 3)) for p in range(P)]), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(b, np.stack([sum((J[m].T @ r[m] for m in np.flatnonzero(point == p)), np.zeros(3))
                                            for p in range(P)]), rtol=1e-12, atol=1e-14)
    A = A + 1e-9 * np.trace(A, axis1=1, axis2=2)[:, None, None] * np.eye(3) + np.eye(3) * (np.trace(A, axis1=1, axis2=2) == 0)[:, None, None]
    Ainv = oe._symmetric_inverse(A)
    # where two views or more meet at an angle to the rounding of either; one view's (the ridge's
    # condition number 1e9) to that times the machine's epsilon
    two = np.bincount(point, minlength=P) >= 2
    np.testing.assert_allclose(Ainv[two], np.linalg.inv(A[two]), rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(Ainv, np.linalg.inv(A), rtol=1e-6)
    rho, dense_rho = oe._redundancy(J, Ainv, point), 2 - np.einsum("mki,mij,mkj->m", J, Ainv[point], J)
    np.testing.assert_allclose(rho[two[point]], dense_rho[two[point]], rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(rho, dense_rho, atol=1e-6)  # a lone view's 0 less 1e9 times epsilon
