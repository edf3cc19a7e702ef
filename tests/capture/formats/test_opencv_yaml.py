"""wandcal.capture.formats.opencv_yaml and read_opencv_yaml: the exporter's output and files as
``cv2.FileStorage`` writes them read back; damaged files, including the pair that made OpenCV's
own parser overrun a heap block and abort the process, refused with a message naming the file,
the camera and the field; the bounds on the work."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from wandcal.calib.errors import CalibrationError
from wandcal.calib.rig import Camera, Rig
from wandcal.calib.sim.simulate import ring_cameras
from wandcal.capture.formats.anipose_opencv import MAX_YAML_CAMERAS, read_opencv_yaml, to_opencv_yaml
from wandcal.capture.formats.opencv_yaml import MAX_DEPTH, MAX_MATRIX_ELEMENTS, MAX_TEXT_CHARS, parse_opencv_yaml

ROUND_TRIP = 1e-9  # the writer prints repr(float): exact; the brief's bound for the round trip


@pytest.fixture(scope="module")
def rig_poses():
    cams, R, t = ring_cameras(3, np.random.default_rng(3))
    fisheye = Camera(id="fish 4", width=800, height=600, K=cams[0].K, dist=np.array([0.01, -0.002, 0.0, 0.0]),
                     model="fisheye")
    return Rig((*cams, fisheye), 0.5), np.concatenate([R, R[:1]]), np.concatenate([t, t[:1] + 0.1])


def _doc(rig, R, t) -> dict:
    return {"format": "wandcal-result/1",
            "cameras": [{"id": c.id, "R": R[i].tolist(), "t": t[i].tolist(), "reprojection_rms_px": 0.2 + i}
                        for i, c in enumerate(rig.cameras)]}


@pytest.mark.parametrize("unit", ["m", "mm"])
def test_the_exporters_output_reads_back(rig_poses, unit):
    rig, R, t = rig_poses
    back = read_opencv_yaml(to_opencv_yaml(_doc(rig, R, t), rig, unit=unit))
    assert [c.id for c in back.cameras] == list(rig.ids)
    for k, cam in enumerate(rig.cameras):
        got = back.cameras[k]
        assert (got.width, got.height, got.model) == (cam.width, cam.height, cam.model)
        np.testing.assert_allclose(got.K, cam.K, rtol=ROUND_TRIP, atol=ROUND_TRIP)
        np.testing.assert_allclose(got.dist, cam.dist, rtol=ROUND_TRIP, atol=ROUND_TRIP)
    np.testing.assert_allclose(back.R, R, rtol=0, atol=ROUND_TRIP)
    np.testing.assert_allclose(back.t, t, rtol=ROUND_TRIP, atol=ROUND_TRIP)
    np.testing.assert_allclose(back.rms_px, 0.2 + np.arange(4), rtol=0, atol=ROUND_TRIP)


def test_a_file_as_opencv_writes_it(rig_poses, tmp_path):
    """cv2.FileStorage's own layout: %YAML 1.2, unquoted ids with spaces, '0.' and 1.0000000000000000e+03,
    long data lists wrapped over lines; plus a comment and a quoted id that a person adds."""
    rig, R, t = rig_poses
    path = tmp_path / "cv.yaml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("unit", "mm")
    fs.startWriteStruct("cameras", cv2.FileNode_SEQ)
    for k, cam in enumerate(rig.cameras):
        fs.startWriteStruct("", cv2.FileNode_MAP)
        fs.write("id", cam.id)
        fs.write("model", cam.model)
        fs.write("image_width", cam.width)
        fs.write("image_height", cam.height)
        fs.write("camera_matrix", cam.K)
        fs.write("distortion_coefficients", cam.dist[None, :])
        fs.write("R", R[k])
        fs.write("t", t[k][:, None] * 1000)
        fs.write("reprojection_rms_px", 0.5)
        fs.endWriteStruct()
    fs.endWriteStruct()
    fs.release()
    text = path.read_text()
    assert any(line.rstrip().endswith(",") for line in text.splitlines())  # a data list wraps
    text = text.replace("cameras:", "# written by cv2.FileStorage\ncameras:  # one map per camera", 1)
    text = text.replace("id: cam1", 'id: "cam1"  # quoted', 1)
    back = read_opencv_yaml(text, "cv.yaml")
    assert [c.id for c in back.cameras] == list(rig.ids)
    for k, cam in enumerate(rig.cameras):
        np.testing.assert_allclose(back.cameras[k].K, cam.K, rtol=ROUND_TRIP, atol=ROUND_TRIP)
        np.testing.assert_allclose(back.cameras[k].dist, cam.dist, rtol=ROUND_TRIP, atol=ROUND_TRIP)
        assert back.cameras[k].model == cam.model
    np.testing.assert_allclose(back.R, R, rtol=0, atol=ROUND_TRIP)
    np.testing.assert_allclose(back.t, t, rtol=ROUND_TRIP, atol=ROUND_TRIP)


def test_the_inputs_that_aborted_opencv_are_refused(rig_poses):
    """Read one after the other, these two made cv2.FileStorage write 8 bytes past a 48-byte heap
    block (valgrind) and glibc abort pytest ("double free or corruption"): a file cut off after
    a matrix tag, then one whose matrices lost their 'cols' and 'dt' lines."""
    rig, R, t = rig_poses
    valid = to_opencv_yaml(_doc(rig, R, t), rig)
    lines = valid.splitlines()
    cut = valid[: valid.index("distortion_coefficients: !!opencv-matrix") + 41] + "\n       "
    with pytest.raises(CalibrationError, match=r"c.yaml: line 17: cameras\[0\].distortion_coefficients must be a map of rows, cols"):
        read_opencv_yaml(cut, "c.yaml")
    no_cols = "\n".join(line for k, line in enumerate(lines) if k != lines.index("         cols: 3"))
    with pytest.raises(CalibrationError, match=r"d.yaml: line 12: cameras\[0\].camera_matrix has no 'cols'"):
        read_opencv_yaml(no_cols, "d.yaml")
    no_dt = valid.replace("         dt: d\n", "", 1)
    with pytest.raises(CalibrationError, match=r"cameras\[0\].camera_matrix has no 'dt'"):
        read_opencv_yaml(no_dt, "d.yaml")


@pytest.mark.parametrize(("change", "message"), [
    (lambda v: v.replace("image_width: 1280", "image_width: 12.5", 1), r"cameras\[0\]: 'image_width' must be a whole"),
    (lambda v: v.replace("      image_height:", "      #", 1), r"cameras\[0\] has no 'image_height'"),
    (lambda v: v.replace("rows: 3", "rows: 4", 1), r"cameras\[0\].camera_matrix: data holds 9 numbers, rows x cols = 12"),
    (lambda v: v.replace(", 1.0 ]", ", 1_000 ]", 1), r"cameras\[0\].camera_matrix: '1_000' is not a number"),
    (lambda v: v.replace("dt: d", "dt: 3d", 1), r"dt must be one channel"),
    (lambda v: v.replace(" ]\n", "\n", 1), r"line 16: a '\[' or '\{' is never closed"),
    (lambda v: v.replace("unit: m", "unit: inch"), r"e.yaml: unit must be one of m, mm, not 'inch'"),
    (lambda v: v[: v.index("cameras:")] + "cameras: 3\n", r"no 'cameras' sequence"),
    (lambda v: v.replace('id: "cam1"', 'id: "cam1', 1), r"line 8: a quoted string is not closed"),
    (lambda v: v.replace("      model: pinhole", "      model: pinhole\n         extra: 1", 1), r"line 10: indented deeper"),
    (lambda v: v.replace("      model: pinhole", "      model: &a pinhole", 1), r"anchors, aliases"),
    (lambda v: v + "---\nunit: m\n", r"a second YAML document"),
    (lambda v: v[: v.index("cameras:")] + "cameras:\n   - 7\n", r"cameras\[0\] is not a map"),
])
def test_damaged_files_are_refused_naming_file_camera_and_field(rig_poses, change, message):
    rig, R, t = rig_poses
    with pytest.raises(CalibrationError, match=message) as exc:
        read_opencv_yaml(change(to_opencv_yaml(_doc(rig, R, t), rig)), "e.yaml")
    assert str(exc.value).startswith("e.yaml")


def test_the_work_is_bounded():
    head = "%YAML:1.0\n---\n"
    with pytest.raises(CalibrationError, match=f"more than {MAX_TEXT_CHARS}"):
        parse_opencv_yaml(head + "a: " + "1" * MAX_TEXT_CHARS, "big.yaml")
    huge = head + "m: !!opencv-matrix\n   rows: 100000\n   cols: 100000\n   dt: d\n   data: [ 1 ]\n"
    with pytest.raises(CalibrationError, match=f"rows x cols at most {MAX_MATRIX_ELEMENTS}"):
        parse_opencv_yaml(huge, "huge.yaml")
    with pytest.raises(CalibrationError, match=f"nested deeper than {MAX_DEPTH}"):
        parse_opencv_yaml(head + "a: " + "[" * 5000 + "]" * 5000 + "\n", "deep.yaml")
    many = head + "cameras:\n" + "   - { id: x }\n" * (MAX_YAML_CAMERAS + 1)
    with pytest.raises(CalibrationError, match=f"more than the {MAX_YAML_CAMERAS}"):
        read_opencv_yaml(many, "many.yaml")


def test_flow_maps_and_compact_sequences_parse():
    doc = parse_opencv_yaml("%YAML 1.2\n---\nlist:\n- a: 1\n  b: 'it''s'\n- { c: [ 1, 2,\n   3 ], d: \"x\\ty\" }\n", "f.yaml")
    assert doc == {"list": [{"a": "1", "b": "it's"}, {"c": ["1", "2", "3"], "d": "x\ty"}]}
