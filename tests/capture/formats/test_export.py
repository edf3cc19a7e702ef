"""wandcal.capture.formats.export against the readers of each format: tomllib, cv2.FileStorage, projection, the
formats' own conventions decoded independently here, wandcal's readers (round trips), and the
real Qualisys file of the Pose2Sim demo (docs/formats.md)."""

from __future__ import annotations

import tomllib
import xml.etree.ElementTree as ET

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from wandcal.calib.errors import CalibrationError
from wandcal.calib.geometry import matrix_to_rotvec, project_pixels
from wandcal.calib.rig import Camera, Rig
from wandcal.calib.sim.simulate import ring_cameras
from wandcal.capture.formats.dlt import dlt_coefficients, read_dlt_csv, to_dlt_csv
from wandcal.capture.formats.export import (
    FORMAT_NAMES,
    export,
    formats,
    read_anipose_toml,
    read_opencv_yaml,
    to_anipose_toml,
    to_opencv_yaml,
)
from wandcal.capture.formats.qualisys_vicon import read_qca, read_xcp, to_qca, to_xcp

# exporters print floats with repr(): they round-trip exactly; a conversion (quaternion, RQ
# decomposition, mm) costs a few units in the last place of numbers of order 1e3
EXACT = 1e-12
CONVERTED = 1e-9
QUALISYS_DEMO = "qualisys_pose2sim_demo/Calib.qca.txt"


def _result(cams, R, t, rms=None) -> dict:
    return {
        "format": "wandcal-result/1",
        "cameras": [{"id": c.id, "R": R[i].tolist(), "t": t[i].tolist(), "reprojection_rms_px": 0.1 * (i + 1) if rms is None else rms}
                    for i, c in enumerate(cams)],
        "wand": {"length_m": 0.5, "length_mean_m": 0.5001, "length_std_m": 0.0007, "frames_used": 300},
    }


@pytest.fixture(scope="module")
def solved():
    """A result document built from known poses (the simulator's ring, plus a fisheye), and its rig."""
    cams, R, t = ring_cameras(3, np.random.default_rng(7))
    fisheye = Camera(id="fish 4", width=800, height=600, K=cams[0].K, dist=np.array([0.01, 0.0, 0.0, 0.0]), model="fisheye")
    cams.append(fisheye)
    R = np.concatenate([R, R[:1]])
    t = np.concatenate([t, t[:1] + 0.1])
    rig = Rig(cameras=tuple(cams), wand_length=0.5)
    return _result(cams, R, t), rig, R, t


@pytest.fixture(scope="module")
def pinhole(solved):
    """The ring's pinhole cameras only (qca and xcp hold no fisheye lens)."""
    _, rig, R, t = solved
    cams = rig.cameras[:3]
    return _result(cams, R[:3], t[:3]), Rig(cams, 0.5), R[:3], t[:3]


def _points() -> np.ndarray:
    return np.random.default_rng(0).uniform([-1, -1, 0], [1, 1, 2], (20, 3))


def test_anipose_toml_reads_with_tomllib(solved):
    result, rig, R, t = solved
    doc = tomllib.loads(to_anipose_toml(result, rig, unit="mm"))
    for i, cam in enumerate(rig.cameras):
        entry = doc[f"cam_{i}"]
        assert entry["name"] == cam.id and entry["size"] == [cam.width, cam.height]
        np.testing.assert_allclose(entry["matrix"], cam.K, atol=EXACT)
        np.testing.assert_allclose(entry["distortions"], cam.dist, atol=EXACT)
        np.testing.assert_allclose(cv2.Rodrigues(np.array(entry["rotation"]))[0], R[i], atol=1e-9)
        np.testing.assert_allclose(entry["translation"], t[i] * 1000, atol=1e-9)
        assert entry["fisheye"] == (cam.model == "fisheye")
    assert doc["metadata"]["error"] == pytest.approx(0.25)


def test_opencv_yaml_reads_back_with_filestorage(solved):
    result, rig, R, t = solved
    fs = cv2.FileStorage(to_opencv_yaml(result, rig), cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    assert int(fs.getNode("camera_count").real()) == len(rig.cameras)
    cams = fs.getNode("cameras")
    for i, cam in enumerate(rig.cameras):
        node = cams.at(i)
        assert node.getNode("id").string() == cam.id
        assert int(node.getNode("image_width").real()) == cam.width
        np.testing.assert_allclose(node.getNode("camera_matrix").mat(), cam.K, atol=EXACT)
        np.testing.assert_allclose(node.getNode("distortion_coefficients").mat().ravel(), cam.dist, atol=EXACT)
        np.testing.assert_allclose(node.getNode("R").mat(), R[i], atol=EXACT)
        np.testing.assert_allclose(node.getNode("rvec").mat().ravel(), matrix_to_rotvec(R[i]), atol=EXACT)
        np.testing.assert_allclose(node.getNode("t").mat().ravel(), t[i], atol=EXACT)
    fs.release()


@pytest.mark.parametrize("origin", ["top-left", "bottom-left"])
def test_dlt_coefficients_reproject_like_the_pinhole(solved, origin):
    result, rig, R, t = solved
    table = np.loadtxt(to_dlt_csv(result, rig, origin=origin).splitlines(), delimiter=",")
    assert table.shape == (11, len(rig.cameras))
    X = _points()
    for i, cam in enumerate(rig.cameras):
        L = table[:, i]
        den = X @ L[8:11] + 1
        uv = np.stack([(X @ L[0:3] + L[3]) / den, (X @ L[4:7] + L[7]) / den], 1)
        pinhole = Camera(id="p", width=cam.width, height=cam.height, K=cam.K, dist=np.zeros(5))
        want = project_pixels(pinhole, R[i], t[i], X)
        if origin == "bottom-left":
            want[:, 1] = cam.height - want[:, 1]
        np.testing.assert_allclose(uv, want, atol=1e-6)


def test_qca_decodes_as_pose2sim_does(pinhole):
    """Pose2Sim's reading (SOURCE.md of the demo): R = diag(1, -1, -1) M, t = -R (x, y, z) / 1000,
    intrinsics / 64 from the fov_video corner, written out here without wandcal's reader."""
    result, rig, R, t = pinhole
    root = ET.fromstring(to_qca(result, rig))
    X = _points()
    for i, (cam, node) in enumerate(zip(rig.cameras, root.findall("cameras/camera"))):
        tr, intr, fov = node.find("transform").attrib, node.find("intrinsic").attrib, node.find("fov_video").attrib
        M = np.array([[float(tr[f"r{r}{c}"]) for c in (1, 2, 3)] for r in (1, 2, 3)])
        Rq = np.diag([1.0, -1.0, -1.0]) @ M
        tq = -Rq @ np.array([float(tr[k]) for k in "xyz"]) / 1000
        K = np.array([[float(intr["focalLengthU"]) / 64, 0, float(intr["centerPointU"]) / 64 - float(fov["left"])],
                      [0, float(intr["focalLengthV"]) / 64, float(intr["centerPointV"]) / 64 - float(fov["top"])], [0, 0, 1]])
        assert (int(fov["right"]) + 1, int(fov["bottom"]) + 1) == (cam.width, cam.height)
        dist = np.array([float(intr[k]) / 64 for k in ("radialDistortion1", "radialDistortion2", "tangentalDistortion1",
                                                        "tangentalDistortion2", "radialDistortion3")])
        got = project_pixels(Camera("q", cam.width, cam.height, K, dist), Rq, tq, X)
        np.testing.assert_allclose(got, project_pixels(cam, R[i], t[i], X), atol=1e-6)


def test_xcp_decodes_by_vicons_definition(pinhole):
    """Vicon: ORIENTATION a quaternion, real part last, world->camera; POSITION the centre in mm;
    FOCAL_LENGTH fx and PIXEL_ASPECT_RATIO fx/fy; decoded here with scipy, not wandcal's reader."""
    result, rig, R, t = pinhole
    root = ET.fromstring(to_xcp(result, rig))
    X = _points()
    for i, (cam, node) in enumerate(zip(rig.cameras, root.findall("Camera"))):
        key = node.find("KeyFrames/KeyFrame").attrib
        Rv = Rotation.from_quat([float(v) for v in key["ORIENTATION"].split()]).as_matrix()
        tv = -Rv @ np.array([float(v) for v in key["POSITION"].split()]) / 1000
        f, (cx, cy) = float(key["FOCAL_LENGTH"]), [float(v) for v in key["PRINCIPAL_POINT"].split()]
        K = np.array([[f, 0, cx], [0, f / float(node.attrib["PIXEL_ASPECT_RATIO"]), cy], [0, 0, 1]])
        model, dcx, dcy, k1, k2, k3 = key["VICON_RADIAL2"].split()
        assert model == "ThirdOrderRadial" and (float(dcx), float(dcy)) == (cx, cy)
        assert node.attrib["SENSOR_SIZE"] == f"{cam.width} {cam.height}" and node.attrib["DEVICEID"] == cam.id
        got = project_pixels(Camera("v", cam.width, cam.height, K, [float(k1), float(k2), 0, 0, float(k3)]), Rv, tv, X)
        np.testing.assert_allclose(got, project_pixels(cam, R[i], t[i], X), atol=1e-6)


ROUND_TRIPS = {
    "anipose-toml": lambda text, rig: read_anipose_toml(text),
    "opencv-yaml": lambda text, rig: read_opencv_yaml(text),
    "dlt-csv": lambda text, rig: read_dlt_csv(text, [(c.width, c.height) for c in rig.cameras], ids=rig.ids),
    "qca": lambda text, rig: read_qca(text),
    "xcp": lambda text, rig: read_xcp(text),
}


@pytest.mark.parametrize("fmt", FORMAT_NAMES)
def test_every_format_round_trips_through_its_reader(pinhole, fmt):
    result, rig, R, t = pinhole
    back = ROUND_TRIPS[fmt](export(result, fmt, rig), rig)
    assert [c.id for c in back.cameras] == rig.ids
    for i, cam in enumerate(rig.cameras):
        got = back.cameras[i]
        assert (got.width, got.height, got.model) == (cam.width, cam.height, cam.model)
        np.testing.assert_allclose(got.K, cam.K, rtol=CONVERTED, atol=CONVERTED)
        # DLT has no lens: its reader gives the undistorted camera
        np.testing.assert_allclose(got.dist, np.zeros(5) if fmt == "dlt-csv" else cam.dist, atol=EXACT)
        np.testing.assert_allclose(back.R[i], R[i], atol=CONVERTED)
        np.testing.assert_allclose(back.t[i], t[i], atol=CONVERTED)


@pytest.mark.parametrize("fmt", ["anipose-toml", "opencv-yaml"])
def test_fisheye_round_trips_where_the_format_holds_it(solved, fmt):
    result, rig, _, _ = solved
    back = ROUND_TRIPS[fmt](export(result, fmt, rig), rig)
    assert back.cameras[-1].model == "fisheye"
    np.testing.assert_allclose(back.cameras[-1].dist, rig.cameras[-1].dist, atol=EXACT)


def test_the_qualisys_demo_reads_with_the_convention_its_source_states(shared_data):
    """The real .qca of the Pose2Sim demo: camera centres, focal lengths, principal points and image
    size as its SOURCE.md gives them, every camera looking at the world origin; and written back
    by wandcal, the same numbers attribute by attribute."""
    text = (shared_data / QUALISYS_DEMO).read_text()
    pc = read_qca(text, QUALISYS_DEMO)
    assert [c.id for c in pc.cameras] == ["cam01", "cam02", "cam03", "cam04"]
    # SOURCE.md, to the 1 mm / 1 px it prints
    np.testing.assert_allclose(pc.centers, [[1.460, -1.909, 1.897], [2.582, 0.707, 1.691], [-3.217, 2.231, 2.088],
                                            [-3.759, -1.416, 1.882]], atol=0.0005 + 1e-9)
    np.testing.assert_allclose([c.K[0, 0] for c in pc.cameras], [1681, 1674, 1682, 1675], atol=0.5 + 0.25)
    np.testing.assert_allclose([c.K[:2, 2] for c in pc.cameras], [[533, 948], [535, 963], [513, 955], [540, 964]], atol=0.5 + 0.25)
    assert {(c.width, c.height) for c in pc.cameras} == {(1088, 1920)}
    towards_origin = -pc.centers / np.linalg.norm(pc.centers, axis=1, keepdims=True)
    cosine = np.einsum("ni,ni->n", pc.R[:, 2, :], towards_origin)  # optical axis . direction to the origin
    assert np.all((cosine > 0.94 - 0.005) & (cosine < 0.99 + 0.005))  # SOURCE.md: 0.94-0.99
    doc = _result(pc.cameras, pc.R, pc.t)
    ours, theirs = ET.fromstring(to_qca(doc, Rig(pc.cameras, None))), ET.fromstring(text)
    for a, b in zip(ours.findall("cameras/camera"), theirs.findall("cameras/camera")):
        for tag in ("transform", "intrinsic", "fov_video"):
            for key, value in b.find(tag).attrib.items():
                if key != "focallength":  # mm on the sensor: wandcal knows no pixel size
                    assert float(a.find(tag).attrib[key]) == pytest.approx(float(value), rel=1e-12, abs=1e-9), (tag, key)


def test_formats_refuse_what_they_cannot_hold(solved, pinhole):
    result, rig, _, _ = solved
    with pytest.raises(CalibrationError, match="camera 'fish 4' has a fisheye lens, which qca cannot hold"):
        export(result, "qca", rig)
    with pytest.raises(CalibrationError, match="fisheye lens, which xcp"):
        export(result, "xcp", rig)
    doc = _result([Camera("tan", 640, 480, rig.cameras[0].K, [0.1, 0, 1e-3, 0, 0])], np.eye(3)[None], np.array([[0, 0, 2.0]]))
    doc["cameras"][0] |= {"width": 640, "height": 480, "K": rig.cameras[0].K.tolist(), "dist": [0.1, 0, 1e-3, 0, 0]}
    with pytest.raises(CalibrationError, match="camera 'tan' has tangential distortion.*xcp"):
        export(doc, "xcp")
    assert read_qca(export(doc, "qca")).cameras[0].dist[2] == pytest.approx(1e-3)
    with pytest.raises(CalibrationError, match="qca writes lengths in mm only, not 'm'"):
        export(pinhole[0], "qca", pinhole[1], unit="m")
    with pytest.raises(CalibrationError, match="anipose-toml has its pixel origin at the top-left only"):
        export(result, "anipose-toml", rig, origin="bottom-left")
    with pytest.raises(CalibrationError, match="unknown format 'pdf'"):
        export(result, "pdf", rig)
    assert tuple(formats()) == FORMAT_NAMES


def test_dlt_refuses_an_origin_in_a_focal_plane_and_names_the_camera(pinhole):
    _, rig, R, t = pinhole
    doc = _result(rig.cameras, R, np.array([t[0], [0.3, -0.2, 0.0], t[2]]))
    with pytest.raises(CalibrationError, match="camera 'cam2': the world origin lies in its focal plane"):
        export(doc, "dlt-csv", rig)
    assert dlt_coefficients(rig.cameras[0].K, np.eye(3), np.array([0, 0, 2.0])).shape == (11,)


def test_missing_fields_and_bad_files_are_named(solved):
    result, rig, _, _ = solved
    with pytest.raises(CalibrationError, match="no 'width' and no rig"):
        to_anipose_toml(result)
    with pytest.raises(CalibrationError, match="no 'cameras'"):
        to_opencv_yaml({"format": "wandcal-result/1"}, rig)
    with pytest.raises(CalibrationError, match="unit must be one of m, mm"):
        to_dlt_csv(result, rig, unit="in")
    with pytest.raises(CalibrationError, match="origin"):
        to_dlt_csv(result, rig, origin="centre")
    with pytest.raises(CalibrationError, match=r"rig.qca: camera 'c1': no <transform>"):
        read_qca('<calibration><cameras><camera serial="c1"><fov_video left="0" top="0" right="9" bottom="9"/>'
                 '<intrinsic focalLengthU="640" focalLengthV="640" centerPointU="320" centerPointV="320"/>'
                 "</camera></cameras></calibration>", "rig.qca")
    with pytest.raises(CalibrationError, match="rig.xcp: not XML"):
        read_xcp("<Cameras>", "rig.xcp")
    with pytest.raises(CalibrationError, match=r"c.toml: \[cam_0\] has no 'rotation'"):
        read_anipose_toml('[cam_0]\nname = "a"\nsize = [4, 3]\nmatrix = [[1, 0, 2], [0, 1, 1], [0, 0, 1]]\n'
                          "distortions = [0, 0, 0, 0, 0]\n", source="c.toml")
    with pytest.raises(CalibrationError, match="d.csv: want 11 rows"):
        read_dlt_csv("1,2\n3,4\n", [(4, 3)] * 2, source="d.csv")
