"""``wandcal export`` as a user runs it: a real calibration, real files, real subprocesses."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.service.conftest import wandcal
from tests.service.test_cli_imports import NOT_FOR_CALIBRATE, loaded_packages
from wandcal.capture.formats.dlt import read_dlt_csv
from wandcal.capture.formats.export import FORMAT_NAMES, read_anipose_toml, read_opencv_yaml
from wandcal.capture.formats.qualisys_vicon import read_qca, read_xcp

READERS = {
    "anipose-toml": lambda text, doc: read_anipose_toml(text),
    "opencv-yaml": lambda text, doc: read_opencv_yaml(text),
    "dlt-csv": lambda text, doc: read_dlt_csv(text, [(c["width"], c["height"]) for c in doc["cameras"]]),
    "qca": lambda text, doc: read_qca(text),
    "xcp": lambda text, doc: read_xcp(text),
}



@pytest.fixture(scope="module")
def wand_only_result(tmp_path_factory):
    """A wand-only calibration (no L-frame): its world is the wand volume's."""
    folder = tmp_path_factory.mktemp("export")
    r = wandcal("simulate", str(folder / "cap"), "--cameras", "3", "--frames", "200", "--no-static", "--seed", "4")
    assert r.returncode == 0, r.stderr
    r = wandcal("calibrate", str(folder / "cap"), "--out", str(folder / "result.json"), "--quiet")
    assert r.returncode == 0, r.stderr
    return folder / "result.json"


def test_every_format_from_a_wand_only_result(wand_only_result, tmp_path):
    doc = json.loads(wand_only_result.read_text())
    assert doc["world"]["frame"] == "wand_volume"
    for fmt in FORMAT_NAMES:
        out = tmp_path / f"calibration.{fmt}"
        r = wandcal("export", str(wand_only_result), "--format", fmt, "--out", str(out))
        assert r.returncode == 0, (fmt, r.stderr)
        assert f"wrote {out}" in r.stdout
        back = READERS[fmt](out.read_text(), doc)
        for i, cam in enumerate(doc["cameras"]):
            np.testing.assert_allclose(back.R[i], cam["R"], atol=1e-9)
            np.testing.assert_allclose(back.t[i], cam["t"], atol=1e-9)
    r = wandcal("export", str(wand_only_result), "--format", "dlt-csv", "--origin", "top-left", "--unit", "mm")
    assert r.returncode == 0, r.stderr
    top = read_dlt_csv(r.stdout, [(c["width"], c["height"]) for c in doc["cameras"]], origin="top-left", unit="mm")
    np.testing.assert_allclose(top.t, [c["t"] for c in doc["cameras"]], atol=1e-9)
    assert r.stdout != (tmp_path / "calibration.dlt-csv").read_text()  # the origin is honoured


@pytest.mark.parametrize("args, words", [
    (["--format", "pdf"], "invalid choice: 'pdf'"),
    (["--format", "qca", "--unit", "m"], "qca writes lengths in mm only"),
    (["--format", "xcp", "--origin", "bottom-left"], "xcp has its pixel origin at the top-left only"),
    (["--format", "qca", "--out", "/proc/no/such/dir/calibration.qca.txt"], "cannot write the qca file"),
])
def test_bad_requests_exit_2_with_a_message(wand_only_result, args, words):
    r = wandcal("export", str(wand_only_result), *args)
    assert r.returncode == 2, r.stderr
    assert words in r.stderr and "Traceback" not in r.stderr


def test_a_bad_result_file_is_named(tmp_path):
    bad = tmp_path / "result.json"
    bad.write_text(json.dumps({"format": "wandcal-result/1", "cameras": [{"id": "cam1", "width": 640}]}))
    r = wandcal("export", str(bad), "--format", "anipose-toml")
    assert r.returncode == 2
    assert f"{bad}: camera 'cam1': 'height'" in r.stderr and "Traceback" not in r.stderr


def test_export_imports_no_web_framework(wand_only_result, tmp_path):
    loaded = loaded_packages("export", str(wand_only_result), "--format", "xcp", "--out", str(tmp_path / "c.xcp"))
    assert (tmp_path / "c.xcp").is_file()
    assert not loaded & set(NOT_FOR_CALIBRATE), sorted(loaded & set(NOT_FOR_CALIBRATE))
