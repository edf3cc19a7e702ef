import json

import numpy as np
import pytest

from wandcal.calib.run.calibrate import calibrate
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.capture.folder import CaptureFormatError
from wandcal.capture.result_file import read_result


@pytest.fixture(scope="module")
def result_doc():
    sim = simulate_capture(4, 200, 0.3, 0.0, True, 3)
    return calibrate(sim.rig, sim.wand, sim.static).to_json()


def test_a_result_reads_back_with_its_poses_and_intrinsics(tmp_path, result_doc):
    path = tmp_path / "result.json"
    path.write_text(json.dumps(result_doc))
    r = read_result(path)
    assert r.rig.ids == [c["id"] for c in result_doc["cameras"]]
    assert r.rig.wand_length == result_doc["wand"]["length_m"]
    np.testing.assert_array_equal(r.R[1], result_doc["cameras"][1]["R"])
    np.testing.assert_array_equal(r.t[2], result_doc["cameras"][2]["t"])


@pytest.mark.parametrize("edit, words", [
    (lambda d: d.update(format="x"), "'format' must be"),
    (lambda d: d["cameras"][1].pop("R"), "camera 'cam2': 'R' must be 3x3"),
    (lambda d: d["cameras"][0].update(t=[1, 2]), "'t' must be 3 numbers"),
    (lambda d: d["cameras"][0].update(R=np.diag([1, 1, -1]).tolist()), "not a rotation"),
    (lambda d: d["cameras"][2].update(width=-3), "'width' must be a positive whole number"),
    (lambda d: d["cameras"][0].update(K=[[1, 0, 0], [0, 1, 0], [0, 0, 2]]), "last row"),
    (lambda d: d["wand"].update(length_m="long"), "wand.length_m"),
])
def test_a_damaged_result_is_refused_naming_the_camera_and_field(tmp_path, result_doc, edit, words):
    doc = json.loads(json.dumps(result_doc))
    edit(doc)
    path = tmp_path / "result.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(CaptureFormatError, match=words) as err:
        read_result(path)
    assert str(path) in str(err.value)


@pytest.mark.parametrize("content", [b"\xff\xfe\x00garbage", b'{"format": "wandcal-result/1", "cameras": [NaN]}',
                                     b"[" * 100000])
def test_garbage_is_refused_with_the_file_named(tmp_path, content):
    path = tmp_path / "result.json"
    path.write_bytes(content)
    with pytest.raises(CaptureFormatError, match="result.json"):
        read_result(path)
