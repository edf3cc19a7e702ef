"""An easyWand session with background points only (no wand points), made in a tmp dir from the
real Brown wind-tunnel session 1 by dropping its wand points (read in place from
../shared/data, never copied): both import routes take it, and it calibrates in one command to
the session's own DLT camera centres (easywand_result.json) within 1 mm, after the similarity
that a wand-less calibration leaves free (no metric scale)."""

import json

import numpy as np
import pytest
import scipy.io as sio

from wandcal.capture.folder import CaptureFormatError, read_capture
from wandcal.capture.importers.easywand import read_easywand_files, read_easywand_mat
from wandcal.service.cli import main

BROWN1 = "easywand_brown_windtunnel_4cam/calibration1"
MAT = "extrinsicCalib_20230228_easyWandData.mat"
BACKGROUND_ROWS = 419  # SOURCE.md, calibration 1
CENTRE_TOL_M = 0.001  # issue 23: within 1 mm of the session's own DLT centres


def _aligned_error(C, C_ref):
    """(N,) centre distances after the best similarity transform (Umeyama), metres."""
    a, b = C - C.mean(0), C_ref - C_ref.mean(0)
    U, S, Vt = np.linalg.svd(b.T @ a)
    D = np.diag([1, 1, np.sign(np.linalg.det(U @ Vt))])
    s = np.trace(np.diag(S) @ D) / (a ** 2).sum()
    return np.linalg.norm(s * a @ (U @ D @ Vt).T - b, axis=1)


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """(folder, tmp dir with the background-only .mat and a profile made from the .mat's
    optimised intrinsics)."""
    from tests.conftest import SHARED_DATA

    folder = SHARED_DATA / BROWN1
    if not folder.is_dir():
        pytest.skip(f"third-party data not found at {folder}")
    tmp = tmp_path_factory.mktemp("bg_only")
    ew = sio.loadmat(folder / MAT)["easyWandData"]
    n = int(ew["nCams"][0, 0].ravel()[0])
    ew["wandPts"][0, 0] = np.zeros((0, 4 * n))
    sio.savemat(tmp / "bg_only_easyWandData.mat", {"easyWandData": ew})
    f, pp = ew["focalLengths"][0, 0].ravel(), ew["principalPoints"][0, 0].ravel().reshape(n, 2)
    nlin = np.asarray(ew["nlin"][0, 0], dtype=float).reshape(n, 5).T  # [k1 k2 t1 t2 k3] per camera, camera by camera
    w, h = ew["imageWidth"][0, 0].ravel(), ew["imageHeight"][0, 0].ravel()
    rows = [f"{c + 1} {float(f[c])} {int(w[c])} {int(h[c])} {float(pp[c, 0])} {float(pp[c, 1])} 1 "
            + " ".join(str(float(v)) for v in nlin[:, c]) for c in range(n)]
    (tmp / "profile.txt").write_text("\n".join(rows) + "\n")
    return folder, tmp


def test_both_routes_import_a_background_only_session(session):
    folder, tmp = session
    mat = read_easywand_mat(tmp / "bg_only_easyWandData.mat").capture
    files = read_easywand_files(None, tmp / "profile.txt", None, folder / "background_pts_raw.csv").capture
    for cap in (mat, files):
        assert cap.rig.wand_length is None and len(cap.wand) == 0
        assert len(np.unique(cap.points.frame)) == BACKGROUND_ROWS
    # the same points and cameras either way (source_row = the .mat's row)
    assert np.array_equal(mat.points.frame, files.points.frame)
    assert np.allclose(mat.points.uv, files.points.uv, atol=1e-6)
    assert all(np.allclose(a.K, b.K) and np.allclose(a.dist, b.dist) for a, b in zip(mat.rig.cameras, files.rig.cameras))


@pytest.mark.parametrize("route", ["mat", "files"])
def test_background_only_calibrates_in_one_command_to_the_dlt_centres(session, tmp_path, route, capsys):
    folder, tmp = session
    out = tmp_path / "cap"
    args = [str(tmp / "bg_only_easyWandData.mat")] if route == "mat" else [
        "--profile", str(tmp / "profile.txt"), "--background", str(folder / "background_pts_raw.csv")]
    assert main(["import", "easywand", *args, "--out", str(out)]) == 0
    assert "no wand points: background points only" in capsys.readouterr().out
    assert read_capture(out).rig.wand_length is None
    assert main(["calibrate", str(out), "--quiet"]) == 0
    result = json.loads((out / "result.json").read_text())
    ref = json.loads((folder / "easywand_result.json").read_text())
    C_ref = np.array([c["camera_centre_world_m"] for c in ref["reference_cameras_derived_from_dlt"]])
    C = np.array([c["center"] for c in result["cameras"]])
    # measured 0.29-0.53 mm for the four cameras
    assert _aligned_error(C, C_ref).max() < CENTRE_TOL_M


def test_nothing_to_import_is_named(session, tmp_path):
    folder, tmp = session
    with pytest.raises(CaptureFormatError, match="give the wand points .* or the background points"):
        read_easywand_files(None, tmp / "profile.txt", None)
    assert main(["import", "easywand", "--profile", str(tmp / "profile.txt"), "--background",
                 str(folder / "background_pts_raw.csv"), "--wand-length", "0.3", "--out", str(tmp_path / "x")]) == 2
    assert not (tmp_path / "x").exists()
