"""points.csv, axis.csv and captures without a wand; garbage files give messages, not tracebacks."""

import json

import numpy as np
import pytest
import scipy.io

from wandcal.calib.rig import AxisObservations, PointObservations, Rig
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.capture.folder import (
    CaptureFormatError,
    read_capture,
    write_capture,
)
from wandcal.drivers.capture_files import AXIS_FILE, POINTS_FILE, RIG_FILE, WAND_FILE
from wandcal.service.cli import main


@pytest.fixture
def sim():
    return simulate_capture(3, 30, 0.3, seed=2)


def _points_and_axis(rig):
    rng = np.random.default_rng(0)
    points = PointObservations(frame=[1000, 1000, 1001, 1002, 1002], camera=[0, 2, 1, 0, 1],
                               uv=rng.uniform(0, 1000, (5, 2)))
    axis = AxisObservations(role=["origin", "origin", "+z", "+z"], camera=[0, 1, 0, 2], uv=rng.uniform(0, 1000, (4, 2)))
    return points, axis


def test_points_and_axis_round_trip(sim, tmp_path):
    points, axis = _points_and_axis(sim.rig)
    write_capture(tmp_path, sim.rig, sim.wand, None, points, axis)  # axis points set the world: no static.csv
    assert (tmp_path / POINTS_FILE).read_text().splitlines()[0] == "frame,camera,u,v"
    assert (tmp_path / AXIS_FILE).read_text().splitlines()[1].startswith("origin,cam1,")
    cap = read_capture(tmp_path)
    assert np.array_equal(cap.points.frame, points.frame) and np.array_equal(cap.points.camera, points.camera)
    assert np.allclose(cap.points.uv, points.uv, atol=1e-4)
    assert list(cap.axis.role) == list(axis.role) and np.array_equal(cap.axis.camera, axis.camera)
    assert np.allclose(cap.axis.uv, axis.uv, atol=1e-4)
    assert len(cap.wand) == len(sim.wand) and cap.rig.wand_length == sim.rig.wand_length


def test_old_captures_read_unchanged(sim, tmp_path):
    write_capture(tmp_path, sim.rig, sim.wand, sim.static)
    doc = json.loads((tmp_path / RIG_FILE).read_text())
    assert doc["format"] == "wandcal-capture/1" and doc["wand"] == {"length_m": 0.5}
    cap = read_capture(tmp_path)
    assert cap.points is None and cap.axis is None
    assert np.allclose(cap.wand.uv, sim.wand.uv, atol=1e-4)


def test_capture_without_a_wand(sim, tmp_path):
    points, _ = _points_and_axis(sim.rig)
    rig = Rig(sim.rig.cameras, None)
    empty = type(sim.wand)(np.zeros(0), np.zeros(0), np.zeros((0, 2)))
    write_capture(tmp_path, rig, empty, None, points)
    assert "wand" not in json.loads((tmp_path / RIG_FILE).read_text())
    assert read_capture(tmp_path).rig.wand_length is None
    (tmp_path / WAND_FILE).unlink()  # wand.csv may be absent
    cap = read_capture(tmp_path)
    assert len(cap.wand) == 0 and len(cap.points.frame) == 5
    doc = json.loads((tmp_path / RIG_FILE).read_text())
    doc["wand"] = {"length_m": None}  # an explicit null is the same
    (tmp_path / RIG_FILE).write_text(json.dumps(doc))
    assert read_capture(tmp_path).rig.wand_length is None
    # without points.csv a wand is required
    (tmp_path / POINTS_FILE).unlink()
    (tmp_path / WAND_FILE).write_text("frame,camera,u,v\n")
    with pytest.raises(CaptureFormatError, match=r"'wand.length_m' is missing.*only a capture with points.csv"):
        read_capture(tmp_path)


def test_wand_rows_need_a_wand_length(sim, tmp_path):
    points, _ = _points_and_axis(sim.rig)
    write_capture(tmp_path, sim.rig, sim.wand, None, points)
    doc = json.loads((tmp_path / RIG_FILE).read_text())
    del doc["wand"]
    (tmp_path / RIG_FILE).write_text(json.dumps(doc))
    with pytest.raises(CaptureFormatError, match=r"wand.csv: \d+ wand rows but .*rig.json gives no 'wand.length_m'"):
        read_capture(tmp_path)


@pytest.mark.parametrize("name,text,message", [
    (AXIS_FILE, "role,camera,u,v\norigin,cam1,1,2\n+w,cam2,3,4\n", r"axis.csv line 3, column 'role': '\+w' is not one of"),
    (AXIS_FILE, "role,camera,u,v\n+x,cam1,1,2\n", r"axis.csv: no 'origin' row"),
    (AXIS_FILE, "role,camera,u,v\norigin,cam1,1,2\norigin,cam1,3,4\n", r"line 3: camera 'cam1' already has the 'origin'"),
    (POINTS_FILE, "frame,camera,u,v\n5,cam1,nan,2\n", r"points.csv line 2 \(frame 5\), column 'u'.*not finite"),
    (POINTS_FILE, "frame,camera\n5,cam1\n", r"points.csv: missing column\(s\) u, v"),
    (POINTS_FILE, "frame,camera,u,v\n5,cam7,1,2\n", r"points.csv line 2: unknown camera id 'cam7'"),
])
def test_bad_points_and_axis_name_line_and_field(sim, tmp_path, name, text, message):
    write_capture(tmp_path, sim.rig, sim.wand, sim.static)
    (tmp_path / name).write_text(text)
    with pytest.raises(CaptureFormatError, match=message):
        read_capture(tmp_path)


@pytest.mark.parametrize("name", [WAND_FILE, POINTS_FILE, AXIS_FILE])
def test_binary_csv_names_the_file(sim, tmp_path, name):
    write_capture(tmp_path, sim.rig, sim.wand, sim.static)
    (tmp_path / name).write_bytes(bytes(range(256)))
    with pytest.raises(CaptureFormatError, match=rf"{name}: not a text file"):
        read_capture(tmp_path)
    (tmp_path / name).write_bytes(b"frame,camera,u,v\n\x00\x00\x00\n")
    with pytest.raises(CaptureFormatError, match=rf"{name}: holds binary data"):
        read_capture(tmp_path)


def test_cli_refuses_garbage_mat_files(tmp_path, capsys):
    junk = tmp_path / "junk_easyWandData.mat"
    junk.write_bytes(bytes(range(256)) * 8)
    assert main(["import", "easywand", str(junk), "--out", str(tmp_path / "a")]) == 2
    assert "junk_easyWandData.mat: not a MATLAB .mat file" in capsys.readouterr().err
    other = tmp_path / "other.mat"
    scipy.io.savemat(other, {"calib": {"f": 1.0}})
    assert main(["import", "easywand", str(other), "--out", str(tmp_path / "b")]) == 2
    assert "no 'easyWandData' struct (it holds calib)" in capsys.readouterr().err
    incomplete = tmp_path / "incomplete.mat"
    scipy.io.savemat(incomplete, {"easyWandData": {"nCams": 2, "wandLen": 0.5}})
    assert main(["import", "easywand", str(incomplete), "--out", str(tmp_path / "c")]) == 2
    assert "has no field 'focalLengths'" in capsys.readouterr().err
    assert main(["import", "easywand", str(tmp_path / "missing.mat"), "--out", str(tmp_path / "d")]) == 2
    assert "missing.mat: not found" in capsys.readouterr().err
    assert not any((tmp_path / d).exists() for d in "abcd")


@pytest.mark.parametrize("part, bad, message", [
    (RIG_FILE, {"markers_m": [[0, 0, 0], [0.2, 0, 0], [0.2, 0, 0]]}, "rig.json: wand.markers_m: markers 1 and 2 coincide"),
    (POINTS_FILE, "frame,camera,u,v,point\n0,cam1,1,2,nose\n0,cam2,3,4,\n",
     "points.csv line 3, column 'point': empty, but line 2 names point 'nose'"),
])
def test_calibrate_refuses_a_bad_wand_layout_or_mixed_point_column_naming_file_and_field(sim, tmp_path, capsys, part,
                                                                                           bad, message):
    """Exit 2 with the file and field named, and nothing written: the capture stays as it was."""
    folder = tmp_path / "cap"
    write_capture(folder, sim.rig, sim.wand, sim.static)
    if part == RIG_FILE:
        doc = json.loads((folder / RIG_FILE).read_text())
        doc["wand"] = bad
        (folder / RIG_FILE).write_text(json.dumps(doc))
    else:
        (folder / part).write_text(bad)
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    assert main(["calibrate", str(folder), "--quiet", "--out", str(tmp_path / "result.json")]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not (tmp_path / "result.json").exists()
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before
