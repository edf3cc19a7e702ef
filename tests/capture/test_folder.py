"""Reading and writing capture folders, and the messages bad input gets."""

import json

import numpy as np
import pytest

from wandcal.calib.sim.simulate import simulate_capture
from wandcal.capture.folder import CaptureFormatError, read_capture, write_capture


@pytest.fixture
def folder(tmp_path):
    sim = simulate_capture(3, 40, 0.3, seed=1)
    write_capture(tmp_path, sim.rig, sim.wand, sim.static)
    return tmp_path


def test_round_trip(folder):
    cap = read_capture(folder)
    sim = simulate_capture(3, 40, 0.3, seed=1)
    assert cap.rig.ids == sim.rig.ids
    assert np.allclose(cap.wand.uv, sim.wand.uv, atol=1e-4)
    assert np.array_equal(cap.wand.frame, sim.wand.frame)
    assert np.allclose(cap.static.uv, sim.static.uv, atol=1e-4)
    assert np.allclose(cap.rig.cameras[1].K, sim.rig.cameras[1].K)


def _edit_rig(folder, change):
    doc = json.loads((folder / "rig.json").read_text())
    change(doc)
    (folder / "rig.json").write_text(json.dumps(doc))


@pytest.mark.parametrize(
    "change,message",
    [
        (lambda d: d.update(format="other/2"), "'format' must be 'wandcal-capture/1'"),
        (lambda d: d["cameras"][1].pop("K"), r"cameras\[1\] has no 'K'"),
        (lambda d: d["cameras"][0].update(K=[[1, 0], [0, 1]]), r"cameras\[0\].K must be 3x3"),
        (lambda d: d["cameras"][2].update(dist=[0, 0, 0]), "camera 'cam3': 'dist' must hold 5"),
        (lambda d: d["wand"].update(length_m=0), "'wand.length_m' must be a positive number"),
        (lambda d: d["wand"].update(length_m=-0.5), "'wand.length_m' must be a positive number"),
        (lambda d: d.update(cameras=d["cameras"][:1]), "needs at least two cameras"),
        (lambda d: d["cameras"][1].update(id="cam1"), "camera id 'cam1' appears more than once"),
        (lambda d: d["cameras"][0].update(width=-3), r"cameras\[0\].width must be a positive"),
        (lambda d: d["static_object"].update(markers_m=[[0, 0, 0]]), "at least 4"),
    ],
)
def test_malformed_rig_names_the_field(folder, change, message):
    _edit_rig(folder, change)
    with pytest.raises(CaptureFormatError, match=message):
        read_capture(folder)


def test_invalid_json(folder):
    (folder / "rig.json").write_text("{not json")
    with pytest.raises(CaptureFormatError, match="rig.json: not valid JSON"):
        read_capture(folder)


def test_missing_columns(folder):
    (folder / "wand.csv").write_text("frame,camera,u\n0,cam1,3\n")
    with pytest.raises(CaptureFormatError, match="missing column"):
        read_capture(folder)


def test_nan_cell_names_line_and_frame(folder):
    lines = (folder / "wand.csv").read_text().splitlines()
    parts = lines[3].split(",")
    parts[3] = "nan"
    lines[3] = ",".join(parts)
    (folder / "wand.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(CaptureFormatError, match=rf"line 4 \(frame {parts[0]}\), column 'v'.*not finite"):
        read_capture(folder)


def test_unknown_camera_id(folder):
    with open(folder / "wand.csv", "a") as fh:
        fh.write("3,cam9,1.0,2.0\n")
    with pytest.raises(CaptureFormatError, match="unknown camera id 'cam9'; rig.json lists cam1, cam2, cam3"):
        read_capture(folder)


def test_static_without_markers(folder):
    _edit_rig(folder, lambda d: d.pop("static_object"))
    with pytest.raises(CaptureFormatError, match="no 'static_object.markers_m'"):
        read_capture(folder)


def test_missing_folder_and_wand(tmp_path):
    with pytest.raises(CaptureFormatError, match="not a folder"):
        read_capture(tmp_path / "nope")
    sim = simulate_capture(2, 10, 0.3, seed=1)
    write_capture(tmp_path, sim.rig, sim.wand, None)
    (tmp_path / "wand.csv").unlink()
    with pytest.raises(CaptureFormatError, match="wandcal detect"):
        read_capture(tmp_path)


def test_fast_and_row_readers_agree(folder):
    """Well-formed files go through numpy's C reader; the row reader (used for anything that
    needs a message) must read them identically."""
    from wandcal.capture.csv_tables import _frame_table_fast, frame_table
    from wandcal.capture.folder import WAND_COLUMNS

    rig = read_capture(folder).rig
    text = (folder / "wand.csv").read_text()
    fast = _frame_table_fast(text, rig, WAND_COLUMNS)
    assert fast is not None
    quoted = text.replace("cam2", '"cam2"')  # quotes send it to the row reader
    assert _frame_table_fast(quoted, rig, WAND_COLUMNS) is None
    slow = frame_table(quoted, rig, WAND_COLUMNS, "wand.csv")
    for a, b in zip(fast, slow):
        assert np.array_equal(a, b)


def test_camera_ids_padded_with_spaces_are_the_cameras_the_row_reader_names(folder):
    """The fast reader strips each distinct id cell (a camera written " cam2" in some rows and "cam2 "
    in others is one camera), as the row reader does."""
    from wandcal.capture.csv_tables import _frame_table_fast, csv_rows, frame_rows
    from wandcal.capture.folder import WAND_COLUMNS

    rig = read_capture(folder).rig
    lines = (folder / "wand.csv").read_text().splitlines()
    padded = [lines[0]] + [line.replace(",cam2,", ", cam2," if k % 2 else ",cam2 ,") for k, line in enumerate(lines[1:])]
    text = "\n".join(padded) + "\n"
    fast = _frame_table_fast(text, rig, WAND_COLUMNS)
    assert fast is not None
    assert (fast[1] == 1).sum() == sum(",cam2," in line for line in lines[1:]) > 0
    slow = frame_rows(csv_rows(text, WAND_COLUMNS, "wand.csv"), rig, "wand.csv")
    for a, b in zip(fast, slow):
        assert np.array_equal(a, b)


@pytest.mark.parametrize("frame", ["99999999999999999999", "-3", "1.5"])
def test_frame_numbers_out_of_range_name_the_line(folder, frame):
    with open(folder / "wand.csv", "a") as fh:
        fh.write(f"{frame},cam1,1.0,2.0\n")
    with pytest.raises(CaptureFormatError, match=r"line \d+, column 'frame'"):
        read_capture(folder)
