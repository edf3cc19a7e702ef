"""``wandcal import cameras``: every camera format ``wandcal export`` writes reads back, through the
command line, as the same rig (rig.json) and poses (poses.json) within the format's printed
precision; the poses document exports again."""

import json

import numpy as np
import pytest

from wandcal.calib.rig import Camera
from wandcal.calib.sim.simulate import ring_cameras
from wandcal.capture.folder import read_rig
from wandcal.capture.formats.export import FORMAT_NAMES
from wandcal.capture.rig_file import rig_from_json
from wandcal.service.cli import main

# exporters print floats with repr(): a conversion on the way (quaternion, RQ decomposition, mm)
# costs a few units in the last place of numbers of order 1e3 (tests/capture/formats/test_export.py)
CONVERTED = 1e-9
SUFFIX = {"anipose-toml": ".toml", "opencv-yaml": ".yaml", "dlt-csv": ".csv", "qca": ".qca.txt", "xcp": ".xcp"}
UNIT_CHOICES = {"anipose-toml": ("m", "mm"), "opencv-yaml": ("m", "mm"), "dlt-csv": ("m", "mm"), "qca": (None,),
                "xcp": (None,)}


@pytest.fixture(scope="module")
def rig_doc():
    """A result document of a ring of three cameras with lenses (k1, k2, k3; xcp holds no tangential)."""
    cams, R, t = ring_cameras(3, np.random.default_rng(3))
    cams = [Camera(c.id, c.width, c.height, c.K, np.array([-0.2 + 0.05 * i, 0.08, 0.0, 0.0, -0.01]))
            for i, c in enumerate(cams)]
    return {"format": "wandcal-result/1", "cameras": [
        {"id": c.id, "width": c.width, "height": c.height, "K": c.K.tolist(), "dist": c.dist.tolist(),
         "R": R[i].tolist(), "t": t[i].tolist()} for i, c in enumerate(cams)]}, cams, R, t


@pytest.mark.parametrize("fmt,unit", [(f, u) for f in FORMAT_NAMES for u in UNIT_CHOICES[f]])
def test_every_exported_format_reads_back_as_the_same_rig(tmp_path, rig_doc, fmt, unit, capsys):
    doc, cams, R, t = rig_doc
    (tmp_path / "result.json").write_text(json.dumps(doc))
    exported = tmp_path / f"cams{SUFFIX[fmt]}"
    unit_args = ["--unit", unit] if unit else []
    assert main(["export", str(tmp_path / "result.json"), "--format", fmt, *unit_args, "--out", str(exported)]) == 0
    size_args = ["--size", f"{cams[0].width}x{cams[0].height}"] if fmt == "dlt-csv" else []
    out = tmp_path / "back"
    # the format from the extension; the unit where the file does not say it
    read_unit = ["--unit", unit] if unit and fmt in ("anipose-toml", "dlt-csv") else []
    assert main(["import", "cameras", str(exported), *read_unit, *size_args, "--wand-length", "0.5",
                 "--out", str(out)]) == 0
    assert "wrote" in capsys.readouterr().out
    rig = read_rig(out)
    poses = json.loads((out / "poses.json").read_text())
    assert rig.wand_length == 0.5 and len(rig.cameras) == len(cams)
    for i, cam in enumerate(cams):
        got = rig.cameras[i]
        if fmt != "dlt-csv":  # DLT holds no names: its cameras read back as cam1, cam2, ...
            assert got.id == cam.id
        assert (got.width, got.height) == (cam.width, cam.height)
        np.testing.assert_allclose(got.K, cam.K, rtol=CONVERTED, atol=CONVERTED)
        # DLT has no lens: it reads back as the undistorted camera
        np.testing.assert_allclose(got.dist, np.zeros(5) if fmt == "dlt-csv" else cam.dist, atol=CONVERTED)
        np.testing.assert_allclose(poses["cameras"][i]["R"], R[i], atol=CONVERTED)
        np.testing.assert_allclose(poses["cameras"][i]["t"], t[i], atol=CONVERTED)
    # the poses document is a result that exports again, to the same cameras
    again = tmp_path / "again.toml"
    assert main(["export", str(out / "poses.json"), "--format", "anipose-toml", "--out", str(again)]) == 0
    assert main(["import", "cameras", str(again), "--out", str(tmp_path / "again")]) == 0
    np.testing.assert_allclose(json.loads((tmp_path / "again" / "poses.json").read_text())["cameras"][0]["t"], t[0],
                               atol=CONVERTED)


def test_bad_camera_files_are_named(tmp_path, rig_doc, capsys):
    doc, cams, R, t = rig_doc
    (tmp_path / "result.json").write_text(json.dumps(doc))
    dlt = tmp_path / "coefs.csv"
    assert main(["export", str(tmp_path / "result.json"), "--format", "dlt-csv", "--out", str(dlt)]) == 0
    capsys.readouterr()
    assert main(["import", "cameras", str(dlt), "--out", str(tmp_path / "a")]) == 2
    assert "coefs.csv: DLT coefficients hold no image size; give --size" in capsys.readouterr().err
    assert main(["import", "cameras", str(dlt), "--size", "10x10", "--size", "20x20", "--out", str(tmp_path / "a")]) == 2
    assert "3 cameras (columns) but 2 --size values" in capsys.readouterr().err
    odd = tmp_path / "cams.dat"
    odd.write_text("x")
    assert main(["import", "cameras", str(odd), "--out", str(tmp_path / "a")]) == 2
    assert "cams.dat: cannot tell its format from the extension; give --format" in capsys.readouterr().err
    assert not (tmp_path / "a").exists()
    # rig.json without a wand is a rig (the wand goes in when the capture has one)
    assert main(["import", "cameras", str(dlt), "--size", "1280x1024", "--out", str(tmp_path / "b")]) == 0
    assert rig_from_json(json.loads((tmp_path / "b" / "rig.json").read_text()), allow_no_wand=True).wand_length is None
