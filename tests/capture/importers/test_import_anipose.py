"""anipose sessions: a calibration.toml written by wandcal's own exporter from a seeded ring of
cameras, and DeepLabCut CSVs / an aniposelib array of labelled keypoints projected with known
noise. Calibrated in one command after the import."""

import json

import numpy as np
import pytest

from wandcal.calib.geometry import project_pixels
from wandcal.calib.sim.simulate import ring_cameras
from wandcal.capture.folder import CaptureFormatError, parse_points_csv, read_capture
from wandcal.capture.formats.anipose_opencv import to_anipose_toml
from wandcal.capture.formats.cameras_in import read_camera_file
from wandcal.capture.importers.anipose import read_anipose
from wandcal.capture.importers.deeplabcut import read_dlc_csv
from wandcal.service.cli import main

NOISE_PX = 0.5  # DeepLabCut keypoints are good to a pixel or so; the test's injected noise
PARTS = ("nose", "ear_l", "ear_r", "spine", "tail")
FRAMES = 150
LOW = 0.3  # likelihood of the keypoints the network lost; below DeepLabCut's pcutoff 0.6


def _scene(seed=0, cameras=4):
    """Ring cameras and a 'mouse' of five keypoints wandering through the volume: (cams, R, t,
    X (FRAMES, 5, 3) metres)."""
    rng = np.random.default_rng(seed)
    cams, R, t = ring_cameras(cameras, rng)
    body = rng.normal(0, 0.08, (len(PARTS), 3))
    centre = np.cumsum(rng.normal(0, 0.05, (FRAMES, 3)), axis=0)
    centre = 0.6 * centre / np.abs(centre).max() + [0, 0, 1.0]
    X = centre[:, None, :] + body[None]
    return cams, R, t, X


def _result_doc(cams, R, t):
    return {"format": "wandcal-result/1", "cameras": [
        {"id": c.id, "width": c.width, "height": c.height, "K": c.K.tolist(), "dist": c.dist.tolist(),
         "R": R[i].tolist(), "t": t[i].tolist()} for i, c in enumerate(cams)]}


def _uv(cams, R, t, X, seed=1):
    """(C, F, J, 2) noisy pixels, NaN outside the image."""
    rng = np.random.default_rng(seed)
    out = np.full((len(cams), *X.shape[:2], 2), np.nan)
    for c, cam in enumerate(cams):
        uv = project_pixels(cam, R[c], t[c], X.reshape(-1, 3)).reshape(*X.shape[:2], 2)
        uv = uv + rng.normal(0, NOISE_PX, uv.shape)
        inside = (uv[..., 0] > 0) & (uv[..., 0] < cam.width) & (uv[..., 1] > 0) & (uv[..., 1] < cam.height)
        out[c][inside] = uv[inside]
    return out


def _write_dlc(path, uv_cam, lost=(), individuals=False):
    """A DeepLabCut CSV of one camera's (F, J, 2) pixels; (frame, part) in ``lost`` get likelihood LOW."""
    scorer = "DLC_resnet50_mouseJan1shuffle1_100000"
    head = [["scorer"], ["bodyparts"], ["coords"]]
    if individuals:
        head.insert(1, ["individuals"])
    for part in PARTS:
        for coord in ("x", "y", "likelihood"):
            head[0].append(scorer)
            head[-2].append(part)
            head[-1].append(coord)
            if individuals:
                head[1].append("mouse1")
    lines = [",".join(r) for r in head]
    for f in range(uv_cam.shape[0]):
        cells = [str(f)]
        for j in range(len(PARTS)):
            x, y = uv_cam[f, j]
            p = LOW if (f, j) in lost else 0.99
            cells += ["", "", "0.01"] if np.isnan(x) else [f"{x:.3f}", f"{y:.3f}", f"{p}"]
        lines.append(",".join(cells))
    path.write_text("\n".join(lines) + "\n")


def _session(tmp_path, cameras=4):
    cams, R, t, X = _scene(cameras=cameras)
    toml = tmp_path / "calibration.toml"
    toml.write_text(to_anipose_toml(_result_doc(cams, R, t), unit="mm"))
    uv = _uv(cams, R, t, X)
    files = []
    for c in range(len(cams)):
        path = tmp_path / f"vid_01-cam{c + 1}DLC_resnet50.csv"  # DeepLabCut's: the video's name, then the scorer
        _write_dlc(path, uv[c], lost={(f, 1) for f in range(0, FRAMES, 7)})
        files.append(path)
    return cams, R, t, X, uv, toml, files


def _aligned_error(C, C_true):
    """(N,) distances after the best similarity transform (a wand-less calibration has no scale)."""
    a, b = C - C.mean(0), C_true - C_true.mean(0)
    U, S, Vt = np.linalg.svd(b.T @ a)
    D = np.diag([1, 1, np.sign(np.linalg.det(U @ Vt))])
    Rot = U @ D @ Vt
    s = np.trace(np.diag(S) @ D) / (a ** 2).sum()
    return np.linalg.norm(s * a @ Rot.T - b, axis=1)


def test_dlc_csv_reads_keypoints_and_drops_low_likelihood(tmp_path):
    cams, R, t, X, uv, toml, files = _session(tmp_path)
    kp = read_dlc_csv(files[0])
    seen = ~np.isnan(uv[0, ..., 0])
    lost = np.zeros_like(seen)
    lost[::7, 1] = True
    assert len(kp.frame) == int((seen & ~lost).sum())
    assert kp.left_out == int((~seen | lost).sum())
    sel = (kp.label == "nose") & (kp.frame == 3)
    assert np.allclose(kp.uv[sel], uv[0, 3, 0], atol=5e-4)  # written with 3 decimals


def test_multi_animal_csv_names_individual_and_part(tmp_path):
    cams, R, t, X = _scene()
    uv = _uv(cams, R, t, X)
    _write_dlc(tmp_path / "ma.csv", uv[0], individuals=True)
    assert set(read_dlc_csv(tmp_path / "ma.csv").label) == {f"mouse1/{p}" for p in PARTS}


def test_anipose_toml_and_dlc_csv_calibrate_in_one_command(tmp_path, capsys):
    cams, R, t, X, uv, toml, files = _session(tmp_path)
    out = tmp_path / "cap"
    assert main(["import", "anipose", str(toml), "--unit", "mm", *sum((["--points", str(f)] for f in files), []),
                 "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "5 keypoints" in printed and "wand: none" in printed
    cap = read_capture(out)
    assert cap.rig.ids == [c.id for c in cams] and cap.rig.wand_length is None
    assert set(cap.points.point) == set(PARTS)
    poses = json.loads((out / "poses.json").read_text())
    assert np.allclose([c["t"] for c in poses["cameras"]], t, atol=1e-9)  # mm in the TOML, metres here
    assert main(["calibrate", str(out), "--quiet"]) == 0
    result = json.loads((out / "result.json").read_text())
    C = np.array([c["center"] for c in result["cameras"]])
    C_true = -np.einsum("nji,nj->ni", R, t)
    # ~2,600 3D points at 0.5 px on a 3.2 m ring: the rig's shape (after a similarity, no scale) is good to a few mm
    print("aligned centre errors, m:", _aligned_error(C, C_true))
    assert _aligned_error(C, C_true).max() < 0.005
    for cam in result["cameras"]:
        # a 3D point absorbs 3 of its 2m coordinates' noise: between 2 views' and no absorption
        assert NOISE_PX * np.sqrt(2 * (1 - 3 / 4)) < cam["point_rms_px"] < NOISE_PX * np.sqrt(2)


def test_aniposelib_points_array(tmp_path):
    cams, R, t, X, uv, toml, files = _session(tmp_path)
    np.save(tmp_path / "points.npy", uv)
    imported, posed = read_anipose(toml, [str(tmp_path / "points.npy")], unit="mm")
    pts = imported.capture.points
    assert len(pts) == int(np.isfinite(uv[..., 0]).sum())
    assert set(pts.point) == {f"joint{j}" for j in range(len(PARTS))}
    k = np.flatnonzero((pts.camera == 2) & (pts.frame == 10) & (pts.point == "joint3"))[0]
    assert np.allclose(pts.uv[k], uv[2, 10, 3])
    with pytest.raises(CaptureFormatError, match=r"points.npy: 3 cameras .*calibration.toml has 4"):
        np.save(tmp_path / "points.npy", uv[:3])
        read_anipose(toml, [str(tmp_path / "points.npy")])


def test_a_camera_the_points_do_not_name_is_refused_naming_the_file_and_field(tmp_path, capsys):
    cams, R, t, X, uv, toml, files = _session(tmp_path)
    out = tmp_path / "cap"
    code = main(["import", "anipose", str(toml), "--points", str(files[0]), "--points", str(files[1]),
                 "--points", str(files[2]), "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2
    assert "calibration.toml: [cam_3] name = 'cam4': no --points file names this camera" in err
    assert not out.exists()
    # an explicit CAMERA=FILE names it
    other = tmp_path / "fourth.csv"
    other.write_text(files[3].read_text())
    imported, _ = read_anipose(toml, [*map(str, files[:3]), f"cam4={other}"], unit="mm")
    assert set(imported.capture.points.camera) == {0, 1, 2, 3}
    with pytest.raises(CaptureFormatError, match="fourth.csv: the file name names no camera"):
        read_anipose(toml, [*map(str, files[:3]), str(other)])
    with pytest.raises(CaptureFormatError, match="HDF5"):
        read_anipose(toml, [*map(str, files[:3]), f"cam4={tmp_path / 'x.h5'}"])


def test_point_column_round_trips_and_mixed_use_is_refused(tmp_path):
    cams, R, t, X, uv, toml, files = _session(tmp_path)
    imported, _ = read_anipose(toml, list(map(str, files)), unit="mm")
    main_out = tmp_path / "cap"
    from wandcal.capture.folder import save_capture

    save_capture(main_out, imported.capture)
    back = read_capture(main_out).points
    assert np.array_equal(back.point, imported.capture.points.point)
    assert np.array_equal(back.frame, imported.capture.points.frame)
    rig = imported.capture.rig
    text = "frame,camera,u,v,point\n0,cam1,1,2,nose\n0,cam2,3,4,\n"
    with pytest.raises(CaptureFormatError, match=r"points.csv line 3, column 'point': empty, but line 2 names point"):
        parse_points_csv(text, rig)
    # a column left empty on every row keeps today's meaning
    assert parse_points_csv("frame,camera,u,v,point\n0,cam1,1,2,\n", rig).point is None


def test_labelled_tracks_are_point_and_frame(tmp_path):
    from wandcal.calib.observations import point_tracks
    from wandcal.calib.rig import PointObservations

    cams, R, t, X = _scene()
    from wandcal.calib.rig import Rig

    rig = Rig(tuple(cams), None)
    # frame 5: nose in cams 0, 1; tail in cams 0, 1, 2; frame 9: nose in cam 0 only; tail twice in cam 1
    obs = PointObservations([5, 5, 5, 5, 5, 9, 9, 9, 9], [0, 1, 0, 1, 2, 0, 1, 1, 2], np.ones((9, 2)) * 100,
                            ["nose", "nose", "tail", "tail", "tail", "nose", "tail", "tail", "tail"])
    tracks = point_tracks(rig, obs)
    assert tracks.n_tracks == 2
    assert tracks.frames.tolist() == [5, 5] and tracks.labels.tolist() == ["nose", "tail"]
    assert np.bincount(tracks.track).tolist() == [2, 3]
    assert tracks.dropped == {"extra_points": 1, "single_view": 2}


def test_collected_data_csv_with_image_paths_and_no_likelihood(tmp_path):
    """DeepLabCut's hand-labelled CollectedData_*.csv: three index columns (the image path split),
    x and y only; the frame is the number in the image's name."""
    text = ("scorer,,,me,me,me,me\n"
            "bodyparts,,,nose,nose,tail,tail\n"
            "coords,,,x,y,x,y\n"
            "labeled-data,vid_camA,img0012.png,10.5,20.25,,\n"
            "labeled-data,vid_camA,img0040.png,11,21,30,40\n")
    (tmp_path / "CollectedData_me.csv").write_text(text)
    kp = read_dlc_csv(tmp_path / "CollectedData_me.csv")
    assert kp.frame.tolist() == [12, 40, 40] and kp.label.tolist() == ["nose", "nose", "tail"]
    assert np.allclose(kp.uv, [[10.5, 20.25], [11, 21], [30, 40]]) and kp.left_out == 1
    (tmp_path / "bad.csv").write_text(text.replace("img0040.png", "img0012.png"))
    with pytest.raises(CaptureFormatError, match=r"bad.csv line 5: frame 12 again \(first on line 4\)"):
        read_dlc_csv(tmp_path / "bad.csv")
    (tmp_path / "worse.csv").write_text(text.replace("11,21", "eleven,21"))
    with pytest.raises(CaptureFormatError, match=r"worse.csv line 5, column 4: 'eleven' is not a number"):
        read_dlc_csv(tmp_path / "worse.csv")


def test_pose2sim_toml_with_four_distortions(tmp_path):
    """Pose2Sim writes [cam_01] tables with OpenCV's four-coefficient lens [k1, k2, p1, p2]."""
    toml = tmp_path / "Calib.toml"
    toml.write_text('[cam_01]\nname = "cam_01"\nsize = [ 1920.0, 1080.0]\n'
                    'matrix = [ [ 1500.0, 0.0, 960.0], [ 0.0, 1500.0, 540.0], [ 0.0, 0.0, 1.0]]\n'
                    'distortions = [ -0.1, 0.02, 0.001, -0.002]\nrotation = [ 0.1, 0.2, 0.3]\n'
                    'translation = [ 0.5, -0.2, 3.0]\nfisheye = false\n\n'
                    '[cam_02]\nname = "cam_02"\nsize = [ 1920.0, 1080.0]\n'
                    'matrix = [ [ 1500.0, 0.0, 960.0], [ 0.0, 1500.0, 540.0], [ 0.0, 0.0, 1.0]]\n'
                    'distortions = [ 0.0, 0.0, 0.0, 0.0]\nrotation = [ 0.0, 0.0, 0.0]\n'
                    'translation = [ 0.0, 0.0, 0.0]\nfisheye = false\n\n[metadata]\nadjusted = false\nerror = 0.0\n')
    posed = read_camera_file(toml, "anipose-toml")
    cam = posed.cameras[0]
    assert cam.id == "cam_01" and (cam.width, cam.height) == (1920, 1080)
    assert np.allclose(cam.dist, [-0.1, 0.02, 0.001, -0.002, 0.0])
    assert np.allclose(posed.t[0], [0.5, -0.2, 3.0])


def test_an_anipose_import_without_points_says_what_to_give(tmp_path):
    toml = tmp_path / "calibration.toml"
    toml.write_text('[cam_0]\nname = "cam_0"\nsize = [640, 480]\nmatrix = [[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], '
                    '[0.0, 0.0, 1.0]]\ndistortions = [0.0, 0.0, 0.0, 0.0, 0.0]\nrotation = [0.0, 0.0, 0.0]\n'
                    'translation = [0.0, 0.0, 0.0]\n')
    with pytest.raises(CaptureFormatError, match="no --points given.*wandcal import cameras"):
        read_anipose(toml)
