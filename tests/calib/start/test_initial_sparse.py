"""First poses when cameras share only pairwise views: wand frames seen by two (now and then
three) cameras, single-point tracks, no wand at all, and real easyWand sessions.

Simulated tolerances (6 cameras on a 3.2 m ring, 0.5 px blob noise, f ~ 1075 px, ~100 frames
per ring pair): a pair's essential matrix from ~200 correspondences of 0.5 px fixes its relative
rotation to ~0.05-0.1 degree (0.5 px / 1075 px / sqrt(200) = 2e-3 degree, times the 20-50 by
which rotation and baseline direction trade off over a ~60 degree field of view). A wand end at
~3.5 m from a ~4 m baseline triangulates to ~1.5 mm, so one frame's 0.5 m wand is off by ~0.4 %
and the median of ~100 frames by ~0.05 %. Chained over up to three edges from the first pair
that is ~0.2 degree, i.e. ~1.5 cm at the rig's 4 m lever. CENTRE_TOL_M and ANGLE_TOL_DEG sit
~3-5 times above that and a factor two inside what the refinement is known to converge from
(0.1 m, 2 degrees: test_static_and_initial.py).
"""

import json

import numpy as np
import pytest

from wandcal.calib.errors import CalibrationError, Failure
from wandcal.calib.geometry import camera_centers, kabsch, rotation_angle
from wandcal.calib.observations import WandPairs, point_tracks, wand_pairs
from wandcal.calib.rig import Camera, PointObservations, Rig, WandObservations
from wandcal.calib.sim.scenes import pairwise_points, pairwise_wand
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.calib.start.initial import initial_poses
from wandcal.calib.start.static import solve_static

NOISE_PX = 0.5
CENTRE_TOL_M = 0.05
ANGLE_TOL_DEG = 1.0


def _aligned_errors(R, t, R_true, t_true, scale: bool = True):
    """Centre errors (N,) metres and rotation errors (N,) degrees after the similarity (or rigid)
    map that best aligns the estimate with the truth."""
    C, Ct = camera_centers(R, t), camera_centers(R_true, t_true)
    Ra, ta, s = kabsch(C, Ct, scale=scale)
    return np.linalg.norm(s * C @ Ra.T + ta - Ct, axis=1), np.degrees(rotation_angle(R @ Ra.T, R_true)), s


@pytest.mark.parametrize("seed", [3, 11])
def test_pairwise_wand_frames_place_every_camera(seed):
    sim = simulate_capture(6, 600, NOISE_PX, static=False, seed=seed)
    rng = np.random.default_rng(seed)
    pairs = wand_pairs(sim.rig, pairwise_wand(sim, rng))
    views = np.bincount(np.bincount(pairs.frame))
    assert views[2] > 5 * views[3:].sum()  # mostly two cameras per frame: the old start refuses this
    init = initial_poses(sim.rig, pairs)
    err, ang, s = _aligned_errors(init.R, init.t, sim.truth.R, sim.truth.t)
    assert err.max() < CENTRE_TOL_M and ang.max() < ANGLE_TOL_DEG, (err, ang)
    assert abs(s - 1) < 0.01  # the wand scales every pair: 0.05 % each, a few edges chained
    assert all(init.source)


def test_points_only_capture_is_placed_up_to_scale():
    sim = simulate_capture(6, 10, NOISE_PX, static=False, seed=4)
    rig = Rig(sim.rig.cameras, None)
    rng = np.random.default_rng(4)
    tracks = point_tracks(rig, pairwise_points(sim, 1500, rng))
    init = initial_poses(rig, WandPairs.empty(), points=tracks)
    err, ang, _ = _aligned_errors(init.R, init.t, sim.truth.R, sim.truth.t)
    assert err.max() < CENTRE_TOL_M and ang.max() < ANGLE_TOL_DEG, (err, ang)
    note = [n for n in init.notes if "baseline of 1 between" in n]
    assert len(note) == 1, init.notes
    a, b = (rig.index(word) for word in note[0].replace(",", " ").split() if word.startswith("cam"))
    C = camera_centers(init.R, init.t)
    assert np.linalg.norm(C[a] - C[b]) == pytest.approx(1.0)


def test_pair_without_wand_frames_is_scaled_by_placed_points():
    """Cameras 1-4 share the wand; camera 5 and 6 see only point tracks (shared with 4 and with
    each other), so their pairs take the scale from points cameras already placed triangulate."""
    sim = simulate_capture(6, 600, NOISE_PX, static=False, seed=8)
    rng = np.random.default_rng(8)
    wand = pairwise_wand(sim, rng)
    sel = (wand.camera < 4) & ~np.isin(wand.frame, wand.frame[wand.camera >= 4])
    pairs = wand_pairs(sim.rig, WandObservations(wand.frame[sel], wand.camera[sel], wand.uv[sel]))
    pts = pairwise_points(sim, 800, rng, third=0.3)
    keep = np.isin(pts.frame, pts.frame[pts.camera >= 4])  # tracks only where camera 5 or 6 look
    tracks = point_tracks(sim.rig, PointObservations(pts.frame[keep], pts.camera[keep], pts.uv[keep]))
    init = initial_poses(sim.rig, pairs, points=tracks)
    err, ang, s = _aligned_errors(init.R, init.t, sim.truth.R, sim.truth.t)
    assert err.max() < CENTRE_TOL_M and ang.max() < ANGLE_TOL_DEG, (err, ang)
    assert abs(s - 1) < 0.01


def test_camera_the_l_frame_misses_is_chained_from_the_others():
    sim = simulate_capture(6, 600, NOISE_PX, static=True, seed=5)
    rng = np.random.default_rng(5)
    pairs = wand_pairs(sim.rig, pairwise_wand(sim, rng))
    static = solve_static(sim.rig, sim.static)
    static[2] = Failure("camera 'cam3' has no static-object blobs")
    init = initial_poses(sim.rig, pairs, static)
    assert init.source[2] not in ("", "static PnP")
    # the L-frame fixes the world frame: compare without any alignment
    C, Ct = camera_centers(init.R, init.t), sim.truth.centers
    assert np.linalg.norm(C - Ct, axis=1).max() < CENTRE_TOL_M
    assert np.degrees(rotation_angle(init.R, sim.truth.R)).max() < ANGLE_TOL_DEG


def test_camera_that_cannot_be_placed_is_named_with_its_links():
    sim = simulate_capture(4, 400, NOISE_PX, static=False, seed=6)
    rng = np.random.default_rng(6)
    wand = pairwise_wand(sim, rng, third=0.0)
    # camera 4 keeps three frames with camera 3 and nothing else
    with_4 = np.unique(wand.frame[wand.camera == 3])
    pair_34 = [f for f in with_4 if set(wand.camera[wand.frame == f]) == {2, 3}][:3]
    sel = ~np.isin(wand.frame, np.setdiff1d(with_4, pair_34))
    pairs = wand_pairs(sim.rig, WandObservations(wand.frame[sel], wand.camera[sel], wand.uv[sel]))
    expected = r"'cam4' cannot be placed.*linked to cam3 \(3 wand frames.*needs 2 more wand frames shared with cam3"
    with pytest.raises(CalibrationError, match=expected):
        initial_poses(sim.rig, pairs)


# --- real data: two easyWand sessions at the Brown wind tunnel (no licence: read in place) ---

BROWN = "easywand_brown_windtunnel_4cam"
BROWN_WAND_M = 0.2896
BROWN_HEIGHT = 1600
# easyWand's own solution reprojects at 1.4-1.8 px (SOURCE.md); with ~1.5 px digitising noise at
# f ~ 1720 px, 300-400 background points and ~30 wand frames fix each pair's rotation to ~0.05
# degree and its scale (median of ~15 wand lengths that scatter by 0.6 %) to ~0.2 %: centres
# 1-2 m apart land within ~1 cm. 3 cm leaves room for the intrinsics we hold fixed and is well
# inside what the refinement converges from.
BROWN_TOL_M = 0.03


def _y_down(table: np.ndarray, n_cams: int, first_column: int = 0):
    """(frame, camera, uv) of the finite points in ``table`` columns camN_X, camN_Y (y-up pixels)
    starting at ``first_column``, with v flipped to y-down."""
    frame, camera, uv = [], [], []
    for c in range(n_cams):
        u, v = table[:, first_column + 2 * c], table[:, first_column + 2 * c + 1]
        ok = np.isfinite(u) & np.isfinite(v)
        frame.append(np.flatnonzero(ok))
        camera.append(np.full(ok.sum(), c))
        uv.append(np.stack([u[ok], BROWN_HEIGHT - v[ok]], 1))
    return np.concatenate(frame), np.concatenate(camera), np.concatenate(uv)


def _brown(folder):
    """The session's rig (easyWand's optimised intrinsics), wand blobs, background points and
    reference cameras. The CSVs are read here with numpy (SOURCE.md gives their layout), so the
    test depends on no importer."""
    ref = json.loads((folder / "easywand_result.json").read_text())
    opt = ref["easywand_optimised"]
    cams = []
    intrinsics = zip(opt["focal_px"], opt["principal_point_yup_px"], opt["distortion_k1_k2_p1_p2_k3"])
    for i, (f, (ppx, ppy), dist) in enumerate(intrinsics):
        K = np.array([[f, 0, ppx], [0, f, BROWN_HEIGHT - ppy], [0, 0, 1.0]])
        cams.append(Camera(f"cam{i + 1}", ref["image_width_px"][i], BROWN_HEIGHT, K, np.array(dist)))
    n = len(cams)
    rig = Rig(tuple(cams), BROWN_WAND_M)
    # wandpts_raw.csv: source_row, then pt1_cam1_X .. pt1_camN_Y, pt2_cam1_X .. pt2_camN_Y
    table = np.genfromtxt(folder / "wandpts_raw.csv", delimiter=",", skip_header=1)[:, 1:]
    ends = [_y_down(table, n, 2 * n * e) for e in range(2)]
    wand = WandObservations(*(np.concatenate([ends[0][k], ends[1][k]]) for k in range(3)))
    bg = np.genfromtxt(folder / "background_pts_raw.csv", delimiter=",", skip_header=1)[:, 1:]
    points = PointObservations(*_y_down(bg, n))
    ref_R = np.array([c["R_world_to_cam"] for c in ref["reference_cameras_derived_from_dlt"]])
    ref_t = np.array([c["t_world_to_cam_m"] for c in ref["reference_cameras_derived_from_dlt"]])
    return rig, wand, points, ref_R, ref_t


@pytest.mark.parametrize("session", ["calibration1", "calibration2"])
def test_brown_wind_tunnel_sessions_are_placed(shared_data, session):
    rig, wand, points, ref_R, ref_t = _brown(shared_data / BROWN / session)
    pairs = wand_pairs(rig, wand)
    init = initial_poses(rig, pairs, points=point_tracks(rig, points))
    err, ang, s = _aligned_errors(init.R, init.t, ref_R, ref_t)
    assert err.max() < BROWN_TOL_M, err
    assert ang.max() < ANGLE_TOL_DEG, ang
    assert abs(s - 1) < 0.02  # the wand sets the scale: ~0.2 %, plus easyWand's own


def _thin_wand(sim, rng, per_pair: int) -> WandObservations:
    """The pairwise wand with at most ``per_pair`` frames kept per pair of cameras (every frame
    seen by exactly two): no pair's own wand frames can scale it (3 needed)."""
    wand = pairwise_wand(sim, rng, third=0.0)
    pair: dict[tuple, list] = {}
    for f in np.unique(wand.frame):
        cams = tuple(sorted(set(wand.camera[wand.frame == f].tolist())))
        pair.setdefault(cams, []).append(f)
    kept = [f for fs in pair.values() for f in fs[:per_pair]]
    sel = np.isin(wand.frame, kept)
    return WandObservations(wand.frame[sel], wand.camera[sel], wand.uv[sel])


def test_a_wand_too_thin_for_any_pair_is_scaled_over_the_whole_rig():
    """Brown 1's 40% subsamples: 0-2 wand frames fit a pair, 130-145 point tracks shared. The
    cameras are placed from the tracks at a unit baseline and scaled by the median wand of every
    frame (2 x 6 ring pairs = 12 frames of ~0.4% each: ~0.15%, chained over the tracks)."""
    sim = simulate_capture(6, 600, NOISE_PX, static=False, seed=5)
    rng = np.random.default_rng(5)
    pairs = wand_pairs(sim.rig, _thin_wand(sim, rng, 2))
    tracks = point_tracks(sim.rig, pairwise_points(sim, 1500, rng))
    init = initial_poses(sim.rig, pairs, points=tracks)
    err, ang, s = _aligned_errors(init.R, init.t, sim.truth.R, sim.truth.t)
    assert err.max() < CENTRE_TOL_M and ang.max() < ANGLE_TOL_DEG, (err, ang)
    assert abs(s - 1) < 0.01
    assert any("scaled by the wand's median length in" in n for n in init.notes), init.notes


def test_a_wand_too_thin_for_the_scale_is_refused_saying_what_is_missing():
    sim = simulate_capture(6, 600, NOISE_PX, static=False, seed=5)
    rng = np.random.default_rng(5)
    wand = _thin_wand(sim, rng, 2)
    first_two = np.isin(wand.frame, np.unique(wand.frame)[:2])
    pairs = wand_pairs(sim.rig, WandObservations(wand.frame[first_two], wand.camera[first_two], wand.uv[first_two]))
    tracks = point_tracks(sim.rig, pairwise_points(sim, 1500, rng))
    with pytest.raises(CalibrationError, match="only 2 wand frames are seen by two or more cameras, 3 needed for the scale"):
        initial_poses(sim.rig, pairs, points=tracks)
