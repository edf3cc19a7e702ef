"""calib.export against the readers of each format: tomllib, cv2.FileStorage, and projection."""

from __future__ import annotations

import tomllib

import cv2
import numpy as np
import pytest

from calib.errors import CalibrationError
from calib.export import dlt_coefficients, to_anipose_toml, to_dlt_csv, to_opencv_yaml
from calib.geometry import matrix_to_rotvec, project_pixels
from calib.rig import Camera, Rig
from calib.simulate import ring_cameras

# exporters print floats with repr(): they round-trip exactly
EXACT = 1e-12


@pytest.fixture(scope="module")
def solved():
    """A result document built from known poses (the simulator's ring), and its rig."""
    cams, R, t = ring_cameras(3, np.random.default_rng(7))
    fisheye = Camera(id="fish 4", width=800, height=600, K=cams[0].K, dist=np.array([0.01, 0.0, 0.0, 0.0]),
                     model="fisheye")
    cams.append(fisheye)
    R = np.concatenate([R, R[:1]])
    t = np.concatenate([t, t[:1] + 0.1])
    rig = Rig(cameras=tuple(cams), wand_length=0.5)
    result = {
        "format": "wandcal-result/1",
        "cameras": [
            {"id": c.id, "R": R[i].tolist(), "t": t[i].tolist(), "reprojection_rms_px": 0.1 * (i + 1)}
            for i, c in enumerate(cams)
        ],
    }
    return result, rig, R, t


def test_anipose_toml_round_trips(solved):
    result, rig, R, t = solved
    doc = tomllib.loads(to_anipose_toml(result, rig, unit="mm"))
    for i, cam in enumerate(rig.cameras):
        entry = doc[f"cam_{i}"]
        assert entry["name"] == cam.id and entry["size"] == [cam.width, cam.height]
        np.testing.assert_allclose(entry["matrix"], cam.K, atol=EXACT)
        np.testing.assert_allclose(entry["distortions"], cam.dist, atol=EXACT)
        np.testing.assert_allclose(cv2.Rodrigues(np.array(entry["rotation"]))[0], R[i], atol=1e-9)
        np.testing.assert_allclose(entry["translation"], t[i] * 1000, atol=1e-9)
        assert entry.get("fisheye", False) == (cam.model == "fisheye")
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
    X = np.random.default_rng(0).uniform([-1, -1, 0], [1, 1, 2], (20, 3))
    for i, cam in enumerate(rig.cameras):
        L = table[:, i]
        den = X @ L[8:11] + 1
        uv = np.stack([(X @ L[0:3] + L[3]) / den, (X @ L[4:7] + L[7]) / den], 1)
        pinhole = Camera(id="p", width=cam.width, height=cam.height, K=cam.K, dist=np.zeros(5))
        want = project_pixels(pinhole, R[i], t[i], X)
        if origin == "bottom-left":
            want[:, 1] = cam.height - want[:, 1]
        np.testing.assert_allclose(uv, want, atol=1e-6)


def test_missing_fields_are_named(solved):
    result, rig, _, _ = solved
    with pytest.raises(CalibrationError, match="no 'width' and no rig"):
        to_anipose_toml(result)
    with pytest.raises(CalibrationError, match="no 'cameras'"):
        to_opencv_yaml({"format": "wandcal-result/1"}, rig)
    with pytest.raises(CalibrationError, match="unit must be one of m, mm"):
        to_dlt_csv(result, rig, unit="in")
    with pytest.raises(CalibrationError, match="origin"):
        to_dlt_csv(result, rig, origin="centre")
    assert dlt_coefficients(rig.cameras[0].K, np.eye(3), np.array([0, 0, 2.0])).shape == (11,)
