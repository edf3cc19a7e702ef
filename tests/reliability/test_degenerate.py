"""Degenerate rigs, each answered with a specific message (calib/start/degenerate.py), and no false
alarm on sound captures."""

from __future__ import annotations

import re
import subprocess
import sys

import numpy as np
import pytest

from wandcal.calib.errors import CalibrationError
from wandcal.calib.geometry import camera_centers, kabsch
from wandcal.calib.observations import wand_pairs
from wandcal.calib.rig import Camera, Rig, StaticObservations, WandObservations
from wandcal.calib.run.calibrate import calibrate
from wandcal.calib.sim.simulate import (
    IMAGE_SIZE,
    L_FRAME_M,
    look_at,
    observe_static,
    observe_wand,
    simulate_capture,
    wand_path,
)
from wandcal.calib.start.degenerate import STILL_PX, check_capture

NOISE_PX, FOCAL_PX, RANGE_M = 0.3, 1100.0, 4.5
# One frame pins a camera's ray to NOISE_PX / FOCAL_PX * RANGE_M (1.2 mm); the fit averages
# hundreds of frames, so twice that bounds the rig's shape error (as in tests/service/test_http.py).
SHAPE_TOL_M = 2 * NOISE_PX / FOCAL_PX * RANGE_M
# The L-frame's PnP (blobs averaged to 0.03 px, 0.5 m arm at ~4 m) places the world frame to
# ~2 mm, and its tilt moves the far centres about as much again.
ABSOLUTE_TOL_M = 2 * SHAPE_TOL_M + 0.002
RING = [[3.2 * np.cos(a), 3.2 * np.sin(a), 2.6] for a in np.linspace(0, 2 * np.pi, 6)[:-1] + 0.3]


def rig_at(centres, target=(0.0, 0.0, 0.8)):
    """Cameras at ``centres`` (N, 3) aimed at ``target``: the cameras, R (N, 3, 3), t (N, 3)."""
    w, h = IMAGE_SIZE
    K = np.array([[FOCAL_PX, 0, w / 2], [0, FOCAL_PX, h / 2], [0, 0, 1]])
    poses = [look_at(np.asarray(c, float), np.asarray(target, float)) for c in centres]
    cams = [Camera(f"cam{i + 1}", w, h, K, np.zeros(5)) for i in range(len(centres))]
    return cams, np.array([p[0] for p in poses]), np.array([p[1] for p in poses])


def scene(centres, wand, static=True, seed=0):
    cams, R, t = rig_at(centres)
    rng = np.random.default_rng(seed)
    obs = observe_wand(cams, R, t, wand, NOISE_PX, 0.0, 0.0, rng)
    st = observe_static(cams, R, t, L_FRAME_M, NOISE_PX / 10, rng) if static else None
    return Rig(tuple(cams), 0.5, L_FRAME_M.copy() if static else None), obs, st, camera_centers(R, t)


def moving_wand(frames=300, seed=1):
    return wand_path(frames, 0.5, np.random.default_rng(seed))


def shape_error(centres, truth) -> float:
    R, t, _ = kabsch(centres, truth)
    return float(np.linalg.norm(centres @ R.T + t - truth, axis=1).max())


def test_collinear_cameras_are_not_degenerate_for_a_wand():
    """All camera centres on one line: the wand's 3D points still fix every pose, so the rig
    calibrates to the noise's accuracy and no message is due (docs/reliability.md)."""
    line = [[x, -3.5, 2.5] for x in (-2.0, -0.7, 0.6, 2.0)]
    rig, obs, st, truth = scene(line, moving_wand())
    result = calibrate(rig, obs, st)
    assert shape_error(result.centers, truth) < SHAPE_TOL_M
    assert np.linalg.norm(result.centers - truth, axis=1).max() < ABSOLUTE_TOL_M
    assert not any("linked" in w or "plane" in w or "moved" in w for w in result.warnings), result.warnings


def test_a_wand_that_never_moves():
    still = np.repeat(moving_wand()[150:151], 300, axis=0)
    rig, obs, st, _ = scene(RING, still)
    with pytest.raises(CalibrationError, match=r"the wand never moved: .*cam1 0\.\d px over 300 frames"):
        calibrate(rig, obs, st)


def test_a_camera_that_saw_the_wand_in_one_place_only():
    wand = moving_wand()
    rig, obs, st, _ = scene(RING, wand)
    _, still, _, _ = scene(RING, np.repeat(wand[150:151], 300, axis=0), seed=2)
    keep = obs.camera != 2
    take = still.camera == 2
    mixed = WandObservations(np.r_[obs.frame[keep], still.frame[take]], np.r_[obs.camera[keep], still.camera[take]],
                             np.r_[obs.uv[keep], still.uv[take]])
    with pytest.raises(CalibrationError, match=r"camera\(s\) cam3 saw the wand in one place only .*wave the wand "
                                               r"through cam3's view"):
        calibrate(rig, mixed, st)


@pytest.mark.parametrize("layout", ["horizontal plane, ring of cameras", "vertical plane, cameras on one side"])
def test_a_wand_seen_only_at_one_depth(layout):
    wand = moving_wand()
    if layout.startswith("horizontal"):
        centres = RING
        wand[..., 2] = 1.0
    else:
        centres = [[x, -3.5, z] for x, z in ((-1.5, 2.5), (1.5, 2.5), (-1.5, 1.0), (1.5, 1.0))]
        wand[..., 1] = 0.0  # a plane facing the cameras: the same depth from all of them
    rig, obs, st, _ = scene(centres, wand)
    with pytest.raises(CalibrationError, match=r"the wand stayed in one plane \(one depth\): (9\d|100)% of the frames"):
        calibrate(rig, obs, st)


def test_a_static_object_seen_by_only_some_cameras():
    rig, obs, st, truth = scene(RING, moving_wand())
    some = np.isin(st.camera, [0, 1, 3])
    result = calibrate(rig, obs, StaticObservations(st.camera[some], st.uv[some]))
    assert result.world.frame == "static_object"
    for cam in ("cam3", "cam5"):
        assert any(f"camera '{cam}' has no static-object blobs" in w and "placed from the wand" in w
                   for w in result.warnings), result.warnings
    assert np.linalg.norm(result.centers - truth, axis=1).max() < ABSOLUTE_TOL_M

    one = st.camera == 0
    result = calibrate(rig, obs, StaticObservations(st.camera[one], st.uv[one]))
    assert result.world.frame != "static_object"
    assert any("the static object was identified in cam1 only" in w for w in result.warnings), result.warnings


def test_a_camera_linked_to_the_others_only_through_one_camera():
    """cam5 shares wand frames with cam4 alone: it calibrates, with a warning naming both."""
    rig, obs, _, truth = scene(RING, moving_wand(400))
    second_half = obs.frame >= 200
    drop = (~second_half & (obs.camera == 4)) | (second_half & np.isin(obs.camera, [0, 1, 2]))
    bridged = WandObservations(obs.frame[~drop], obs.camera[~drop], obs.uv[~drop])
    result = calibrate(rig, bridged, None)
    assert [w for w in result.warnings if "linked" in w] == [
        "cam5 is linked to the other cameras only through cam4: an error in cam4's pose carries into it unchecked; "
        "wave the wand where cam5 and a camera other than cam4 see it at the same time"]
    # the link holds: the error stays within the noise's bound, a warning and not a failure
    assert shape_error(result.centers, truth) < SHAPE_TOL_M


def two_groups(seed: int = 3):
    """A 6-camera ring whose cam1-cam3 see the wand in its first 200 frames only and cam4-cam6 in
    its last 200 only: no wand frame ties the two groups, and every camera sees the L-frame."""
    centres = [[3.2 * np.cos(a), 3.2 * np.sin(a), 2.6] for a in np.linspace(0, 2 * np.pi, 7)[:-1]]
    rig, obs, st, _ = scene(centres, moving_wand(400, seed))
    keep = np.where(obs.frame < 200, obs.camera < 3, obs.camera >= 3)
    return rig, WandObservations(obs.frame[keep], obs.camera[keep], obs.uv[keep]), st


SPLIT = r"camera 'cam4' cannot be placed: no wand frame or point track ties it to the cameras cam1, cam2 and cam3 .*cam4, cam5 and cam6"


@pytest.mark.parametrize("with_static", [True, False])
def test_two_groups_that_share_no_wand_frame_are_refused(with_static):
    """Whether or not the L-frame places cameras of both groups, their poses relative to each other
    would rest on nothing the refinement can check: refused, naming a camera of the group apart."""
    rig, obs, st = two_groups()
    # without the L-frame the start finds it as it places cameras one by one: the same refusal, its own words
    expected = SPLIT if with_static else r"camera 'cam4' cannot be placed: of the placed cameras .* linked to none of them"
    with pytest.raises(CalibrationError, match=expected):
        calibrate(rig, obs, st if with_static else None)


def test_two_groups_exit_2_on_the_command_line(tmp_path):
    from wandcal.capture.folder import write_capture

    rig, obs, st = two_groups()
    write_capture(tmp_path / "cap", rig, obs, st)
    done = subprocess.run([sys.executable, "-m", "wandcal.service.cli", "calibrate", str(tmp_path / "cap"), "--quiet",
                           "--out", str(tmp_path / "result.json")], capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 2, done.stderr
    assert re.search(SPLIT, done.stderr) and "Traceback" not in done.stderr, done.stderr
    assert not (tmp_path / "result.json").exists()


@pytest.mark.parametrize("cameras, seed", [(3, 1), (4, 2), (8, 3), (16, 4)])
def test_sound_captures_raise_no_alarm(cameras, seed):
    sim = simulate_capture(cameras=cameras, frames=300, seed=seed)
    pairs = wand_pairs(sim.rig, sim.wand)
    assert check_capture(sim.rig, pairs, None, None) == []
    moved = np.sqrt(((pairs.uv.mean(1) - pairs.uv.mean(1).mean(0)) ** 2).sum(1).mean())
    assert moved > 10 * STILL_PX  # the threshold sits far below a waved wand's motion


def test_cut_cameras_are_the_cameras_whose_removal_splits_the_rig():
    """The one-pass search (calib/start/degenerate.py) against removing each camera in turn, on
    random linked graphs."""
    from wandcal.calib.start.chain import camera_groups
    from wandcal.calib.start.degenerate import _cut_cameras

    rng = np.random.default_rng(0)
    checked = 0
    for _ in range(400):
        n = int(rng.integers(3, 12))
        linked = rng.random((n, n)) < rng.uniform(0.15, 0.6)
        linked = linked | linked.T
        np.fill_diagonal(linked, False)
        if len(camera_groups(linked)) != 1:
            continue
        checked += 1
        assert _cut_cameras(linked) == [v for v in range(n) if len(camera_groups(linked, np.arange(n) != v)) > 1]
    assert checked > 100
