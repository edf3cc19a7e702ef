"""easyWand sessions imported from real third-party data, read in place from ../shared/data (no
licence: never copied here). Expected figures come from each folder's SOURCE.md."""

import numpy as np
import pytest

from wandcal.calib.geometry import undistort_points
from wandcal.capture.folder import CaptureFormatError, read_capture
from wandcal.capture.importers.easywand import read_easywand_files, read_easywand_mat
from wandcal.service.cli import main

BROWN = "easywand_brown_windtunnel_4cam/calibration{}/extrinsicCalib_20230228_easyWandData.mat"
USHICHKA = "easywand_ushichka_thermal_3cam"
USHICHKA_MAT = f"{USHICHKA}/round3_2018-07-28_easyWandData.mat"
USHICHKA_HEIGHT = 512  # the session says 320, a typo (SOURCE.md)
# SOURCE.md, Brown: rows with both ends seen per camera, background rows, easyWand's intrinsics
BROWN_FIGURES = {
    1: {"both_ends": [28, 40, 40, 30], "background": 419, "f_opt": [1711, 1740, 1732, 1719],
        "f_est": [1682, 1768, 1780, 1741], "pp_up": [(1292, 885), (1310, 775), (1278, 779), (1278, 840)],
        "k1k2": [(-0.1687, 0.1398), (-0.1288, 0.1084), (-0.1335, 0.1399), (-0.1327, 0.0799)], "z_m": 0.306},
    2: {"both_ends": [29, 38, 37, 32], "background": 312, "f_opt": [1689, 1736, 1717, 1671],
        "f_est": [1694, 1736, 1741, 1700], "pp_up": [(1281, 887), (1319, 782), (1276, 779), (1259, 826)],
        "k1k2": [(-0.1224, 0.0502), (-0.1519, 0.1234), (-0.1472, 0.1387), (-0.1503, 0.1077)], "z_m": 0.299},
}
# SOURCE.md: easyWand's undistorted points (ptMatu) match a Bouguet/OpenCV undistortion of the raw
# points within 0.01-0.02 px for Brown; ushichka's within 0.2 px (strong distortion, k1 = -0.29:
# easyWand stops iterating early near the corners)
BROWN_UNDISTORT_TOL_PX = 0.05
USHICHKA_UNDISTORT_TOL_PX = 0.25


def _frames_per_camera(obs, n):
    return [len(np.unique(obs.frame[obs.camera == c])) for c in range(n)]


@pytest.mark.parametrize("cal", [1, 2])
def test_brown_session(shared_data, cal):
    fig = BROWN_FIGURES[cal]
    imp = read_easywand_mat(shared_data / BROWN.format(cal))
    cap = imp.capture
    assert len(cap.rig.cameras) == 4 and cap.rig.wand_length == pytest.approx(0.2896)
    for c, cam in enumerate(cap.rig.cameras):
        assert (cam.width, cam.height) == (2560, 1600)
        assert cam.K[0, 0] == cam.K[1, 1] == fig["f_opt"][c]
        # the principal point flips with the pixels: v_down = H - v_up
        assert (cam.K[0, 2], cam.K[1, 2]) == (fig["pp_up"][c][0], 1600 - fig["pp_up"][c][1])
        assert np.allclose(cam.dist, [*fig["k1k2"][c], 0, 0, 0])
    assert _frames_per_camera(cap.wand, 4) == fig["both_ends"]
    # every wand camera-frame has exactly its two ends
    _, counts = np.unique(cap.wand.frame * 4 + cap.wand.camera, return_counts=True)
    assert np.all(counts == 2)
    assert len(np.unique(cap.points.frame)) == fig["background"]
    assert cap.points.frame.min() > cap.wand.frame.max()
    # axisPts: origin then +Z (SOURCE.md, axisXYZ5); origin seen by cameras 3 and 4
    assert list(dict.fromkeys(cap.axis.role)) == ["origin", "+z"]
    assert sorted(cap.axis.camera[cap.axis.role == "origin"]) == [2, 3]


def test_brown_profile_intrinsics(shared_data):
    fig = BROWN_FIGURES[1]
    cap = read_easywand_mat(shared_data / BROWN.format(1), intrinsics="profile").capture
    assert [c.K[0, 0] for c in cap.rig.cameras] == fig["f_est"]


@pytest.mark.parametrize("session,undistorted,height,tol", [
    (BROWN.format(1), "easywand_brown_windtunnel_4cam/calibration1/wandpts_undistorted_easywand.csv", None,
     BROWN_UNDISTORT_TOL_PX),
    (BROWN.format(2), "easywand_brown_windtunnel_4cam/calibration2/wandpts_undistorted_easywand.csv", None,
     BROWN_UNDISTORT_TOL_PX),
    (USHICHKA_MAT, f"{USHICHKA}/wandpts_undistorted_easywand.csv", USHICHKA_HEIGHT, USHICHKA_UNDISTORT_TOL_PX),
])
def test_y_flip_matches_easywands_undistortion(shared_data, session, undistorted, height, tol):
    """Undistort the imported (y-down) points with the imported cameras, return to easyWand's
    y-up pixels, and compare with easyWand's own undistorted points."""
    cap = read_easywand_mat(shared_data / session, height=height).capture
    n = len(cap.rig.cameras)
    ref = np.genfromtxt(shared_data / undistorted, delimiter=",", skip_header=1)
    ref_rows = {int(r[0]): r[1:].reshape(2, n, 2) for r in ref if r[0] >= 0}
    errors = []
    for c, cam in enumerate(cap.rig.cameras):
        for f in np.unique(cap.wand.frame[cap.wand.camera == c]):
            ends = ref_rows.get(int(f), np.full((2, n, 2), np.nan))[:, c]
            if not np.all(np.isfinite(ends)):
                continue  # easyWand dropped this camera-frame (rmpts) from its undistorted copy
            uv = cap.wand.uv[(cap.wand.frame == f) & (cap.wand.camera == c)]
            px = undistort_points(cam, uv) * cam.focal + cam.K[:2, 2]
            px[:, 1] = cam.height - px[:, 1]
            # the two ends are unlabelled: take the better of the two pairings
            errors.append(min(np.abs(px - ends).max(), np.abs(px[::-1] - ends).max()))
    assert len(errors) > 100
    assert max(errors) < tol


def test_ushichka_needs_the_right_height(shared_data):
    with pytest.raises(CaptureFormatError, match=r"v = .*outside its 320 px high image.*--height"):
        read_easywand_mat(shared_data / USHICHKA_MAT)
    imp = read_easywand_mat(shared_data / USHICHKA_MAT, height=USHICHKA_HEIGHT)
    cap = imp.capture
    assert [c.height for c in cap.rig.cameras] == [USHICHKA_HEIGHT] * 3
    assert [c.K[0, 0] for c in cap.rig.cameras] == [526] * 3
    # optimised k1 per camera (SOURCE.md)
    assert np.allclose([c.dist[0] for c in cap.rig.cameras], [-0.2788, -0.2914, -0.2880], atol=1e-4)
    # SOURCE.md: 53 rows with both ends in all 3 cameras, 88 in 2 or more
    frames, views = np.unique(np.unique(cap.wand.frame * 3 + cap.wand.camera) // 3, return_counts=True)
    assert (views == 3).sum() == 53 and (views >= 2).sum() == 88
    assert cap.axis is None  # a gravity throw, not axis points
    assert any("gravity" in n for n in imp.notes)
    assert len(np.unique(cap.points.frame)) == 58  # background_pts_raw.csv's 58 rows


def test_files_give_the_same_capture_as_the_mat(shared_data):
    folder = shared_data / USHICHKA
    mat = read_easywand_mat(shared_data / USHICHKA_MAT, intrinsics="profile", height=USHICHKA_HEIGHT).capture
    files = read_easywand_files(folder / "wandpts_raw.csv", folder / "round3_cameraprofiles_profile.txt", 0.66,
                                background=folder / "background_pts_raw.csv", height=USHICHKA_HEIGHT).capture
    assert files.rig.wand_length == mat.rig.wand_length
    for a, b in zip(files.rig.cameras, mat.rig.cameras):
        assert a.id == b.id and (a.width, a.height) == (b.width, b.height)
        assert np.allclose(a.K, b.K) and np.allclose(a.dist, b.dist)
    for x, y in ((files.wand, mat.wand), (files.points, mat.points)):
        assert np.array_equal(x.frame, y.frame) and np.array_equal(x.camera, y.camera)
        assert np.allclose(x.uv, y.uv, atol=1e-5)  # the CSVs carry 6 decimals


def test_cli_import_writes_a_capture(shared_data, tmp_path, capsys):
    out = tmp_path / "brown1"
    assert main(["import", "easywand", str(shared_data / BROWN.format(1)), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "cam1 28, cam2 40, cam3 40, cam4 30" in printed and "axis points: origin" in printed
    cap = read_capture(out)
    direct = read_easywand_mat(shared_data / BROWN.format(1)).capture
    assert np.array_equal(cap.wand.frame, direct.wand.frame)
    assert np.allclose(cap.wand.uv, direct.wand.uv, atol=1e-4)
    assert np.array_equal(cap.points.frame, direct.points.frame)
    assert list(cap.axis.role) == list(direct.axis.role)
    # an existing capture is not overwritten
    assert main(["import", "easywand", str(shared_data / BROWN.format(1)), "--out", str(out)]) == 2
    assert "already exists" in capsys.readouterr().err
