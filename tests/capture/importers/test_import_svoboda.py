"""MultiCamSelfCal folders: the real strawlab caldata (read in place from ../shared/data, never
copied) and a tiny synthetic folder written by the test."""

import numpy as np
import pytest

from wandcal.capture.folder import CaptureFormatError, read_capture
from wandcal.capture.importers.svoboda import read_svoboda
from wandcal.service.cli import main

CALDATA = "multicamselfcal_strawlab_testdata/caldata20130726_122220"


def test_real_caldata(shared_data):
    folder = shared_data / CALDATA
    cap = read_svoboda(folder).capture
    names = (folder / "camera_order.txt").read_text().split()
    ident = np.loadtxt(folder / "IdMat.dat")
    pts = np.loadtxt(folder / "points.dat").reshape(len(names), 3, -1)
    res = np.loadtxt(folder / "Res.dat")
    assert cap.rig.ids == names and cap.rig.wand_length is None and len(cap.wand) == 0
    assert [(c.width, c.height) for c in cap.rig.cameras] == [tuple(r) for r in res.astype(int)]
    # every seen point, and nothing else; SOURCE.md: seen per camera 459/376/320/444 of 464 frames
    per_cam = [int((cap.points.camera == c).sum()) for c in range(len(names))]
    assert per_cam == ident.sum(axis=1).astype(int).tolist() == [459, 376, 320, 444]
    assert len(np.unique(cap.points.frame)) == 464
    for c in range(len(names)):
        sel = cap.points.camera == c
        assert np.array_equal(cap.points.frame[sel], np.flatnonzero(ident[c]))
        assert np.array_equal(cap.points.uv[sel], pts[c, :2, ident[c] == 1].reshape(-1, 2))
    # basename1.rad: fx=422.2, fy=424.2, cx=330.1, cy=210.3, k1=-0.281, k2=0.075 (SOURCE.md)
    cam = cap.rig.cameras[0]
    assert np.allclose([cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2]], [422.2, 424.2, 330.1, 210.3], atol=0.05)
    assert np.allclose(cam.dist, [-0.280971, 0.074959, 0.000404, -0.000104, 0])


def _write_folder(folder, with_rad=True):
    folder.mkdir()
    uv = np.array([[[10.0, 20.0, np.nan, 40.0], [11.0, 21.0, np.nan, 41.0]],
                   [[50.0, 0.0, 70.0, 80.0], [51.0, 0.0, 71.0, 81.0]]])  # camera, (u, v), frame
    ident = np.array([[1, 1, 0, 1], [1, 0, 1, 1]])
    rows = []
    for c in range(2):
        rows += [uv[c, 0], uv[c, 1], np.ones(4)]
    (folder / "points.dat").write_text("\n".join(" ".join(f"{v:g}" for v in r) for r in rows) + "\n")
    (folder / "IdMat.dat").write_text("\n".join(" ".join(str(v) for v in r) for r in ident) + "\n")
    (folder / "Res.dat").write_text("640 480\n640 480\n")
    (folder / "camera_order.txt").write_text("left\nright\n")
    if with_rad:
        for c in (1, 2):
            (folder / f"basename{c}.rad").write_text(
                f"K11 = {500 + c}\nK12 = 0\nK13 = 320\nK21 = 0\nK22 = {500 + c}\nK23 = 240\nK31 = 0\nK32 = 0\nK33 = 1\n\n"
                "kc1 = -0.1\nkc2 = 0.01\nkc3 = 0.001\nkc4 = -0.002\n")
    return uv, ident


def test_synthetic_folder_via_cli(tmp_path, capsys):
    uv, ident = _write_folder(tmp_path / "msc")
    out = tmp_path / "cap"
    assert main(["import", "svoboda", str(tmp_path / "msc"), "--out", str(out)]) == 0
    assert "wand: none" in capsys.readouterr().out
    cap = read_capture(out)
    assert cap.rig.ids == ["left", "right"] and cap.rig.wand_length is None
    assert np.allclose(cap.rig.cameras[1].dist, [-0.1, 0.01, 0.001, -0.002, 0])
    assert cap.rig.cameras[1].K[0, 0] == 502
    # the unseen point (camera 'right', frame 1) is left out although points.dat holds 0 there
    assert list(zip(cap.points.frame, cap.points.camera)) == [(0, 0), (0, 1), (1, 0), (2, 1), (3, 0), (3, 1)]
    assert np.allclose(cap.points.uv[cap.points.camera == 0], uv[0][:, ident[0] == 1].T)


def test_missing_intrinsics_and_bad_files(tmp_path):
    _write_folder(tmp_path / "msc", with_rad=False)
    with pytest.raises(CaptureFormatError, match=r"basename1.rad: not found;.*--focal-px"):
        read_svoboda(tmp_path / "msc")
    imp = read_svoboda(tmp_path / "msc", focal_px=600)
    assert imp.capture.rig.cameras[0].K[0, 0] == 600 and any("--focal-px" in n for n in imp.notes)
    (tmp_path / "msc" / "IdMat.dat").write_text("1 1 1 1\n1 1 1 1\n")
    with pytest.raises(CaptureFormatError, match=r"points.dat: camera left frame 2 .*marked seen in IdMat.dat"):
        read_svoboda(tmp_path / "msc", focal_px=600)
    (tmp_path / "msc" / "Res.dat").write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\xff\xfe")
    with pytest.raises(CaptureFormatError, match=r"Res.dat: not a text file"):
        read_svoboda(tmp_path / "msc", focal_px=600)
