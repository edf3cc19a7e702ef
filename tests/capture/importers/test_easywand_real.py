"""Real third-party data: an easyWand session of 3 thermal cameras (Project Ushichka, 0.66 m wand),
read in place from ../shared/data (no licence: never copied here). Tolerances come from the
published easyWand figures in its SOURCE.md and easywand_result.json."""

import json

import numpy as np
import pytest

from wandcal.calib.geometry import undistort_points
from wandcal.calib.rig import Camera, Rig
from wandcal.calib.run.calibrate import calibrate
from wandcal.calib.run.options import CalibrationOptions
from wandcal.calib.triangulate import triangulate_points
from wandcal.capture.importers.easywand import read_easywand

SESSION = "easywand_ushichka_thermal_3cam"
HEIGHT = 512  # the profile says 320, a typo: the principal point is (320, 256) (SOURCE.md)
WAND_M = 0.66
THROW_HZ = 25.0


@pytest.fixture(scope="module")
def session(request):
    from tests.conftest import SHARED_DATA

    folder = SHARED_DATA / SESSION
    if not folder.is_dir():
        pytest.skip(f"third-party data not found at {folder}")
    ref = json.loads((folder / "easywand_result.json").read_text())
    cap = read_easywand(folder / "wandpts_raw.csv", folder / "round3_cameraprofiles_profile.txt", WAND_M, HEIGHT)
    # the intrinsics are known: easyWand's optimised k1 per camera
    k1 = [d[0] for d in ref["easywand_optimised"]["distortion_k1_k2_p1_p2_k3"]]
    cams = tuple(Camera(c.id, c.width, c.height, c.K, np.r_[k1[i], c.dist[1:]]) for i, c in enumerate(cap.rig.cameras))
    return folder, ref, Rig(cams, WAND_M), cap.wand


def _distances(C):
    return np.array([np.linalg.norm(C[i] - C[j]) for i, j in ((0, 1), (0, 2), (1, 2))])


@pytest.mark.parametrize("method", ["ba", "lp"])
def test_wand_only_calibration_matches_easywand(session, method):
    folder, ref, rig, wand = session
    result = calibrate(rig, wand, None, options=CalibrationOptions(method=method))
    published = ref["published_result"]
    score = 100 * result.wand_report.length_std_m / result.wand_report.length_mean_m
    # easyWand's wand score is 0.95% with refined intrinsics and extra background points; ours,
    # with its intrinsics held, is held to within 1.6x of it
    assert score < 1.6 * published["wandScore_percent"]
    assert abs(result.wand_report.length_mean_m - WAND_M) < 0.005 * WAND_M
    # the rig's shape: camera-to-camera distances against easyWand's cameras (3-5 m apart)
    C_ref = np.array([c["camera_centre_world_m"] for c in ref["reference_cameras_derived_from_dlt"]])
    assert np.allclose(_distances(result.centers), _distances(C_ref), rtol=0.005)
    # per-axis reprojection RMS near easyWand's per-camera DLT RMSE (0.34-0.41 px)
    for cam, rmse in zip(result.cameras, published["dltRMSE_px_per_camera"]):
        assert cam.reprojection_rms_px / np.sqrt(2) < 2 * rmse


def test_gravity_from_a_thrown_object(session):
    """An independent check of scale: a thrown object triangulated with our cameras falls at g."""
    folder, ref, rig, wand = session
    result = calibrate(rig, wand, None)
    rows = np.genfromtxt(folder / "axis_pts_raw.csv", delimiter=",", skip_header=1)[:, 1:]
    point, camera, xy = [], [], []
    for c, cam in enumerate(rig.cameras):
        uv = rows[:, 2 * c : 2 * c + 2].copy()
        seen = np.all(np.isfinite(uv), axis=1)
        uv[:, 1] = HEIGHT - uv[:, 1]  # easyWand's y-up pixels
        point.append(np.flatnonzero(seen))
        camera.append(np.full(seen.sum(), c))
        xy.append(undistort_points(cam, uv[seen]))
    X = triangulate_points(result.R, result.t, np.concatenate(point), np.concatenate(camera), np.concatenate(xy), len(rows))
    ok = np.all(np.isfinite(X), axis=1)
    time_s = np.arange(len(rows))[ok] / THROW_HZ
    accel = np.array([2 * np.polyfit(time_s, X[ok, k], 2)[0] for k in range(3)])
    # easyWand's own cameras give 10.04 m/s^2 on this throw (SOURCE.md); g is 9.81
    assert 9.5 < np.linalg.norm(accel) < 10.3
