"""capture/formats/openptv.py: OpenPTV's ptv.par, .ori, .addpar and _targets read as cameras behind a
flat window. The real files are read in place from ../shared/data/openptv_test_cavity (skipped when
absent); bad files are written to a temporary folder."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from wandcal.calib.refraction import project_through_window
from wandcal.capture.formats.openptv import MM, PIXEL_CORNER, read_control_par, read_openptv_cameras, read_targets
from wandcal.capture.rig_file import CaptureFormatError

CAVITY = "openptv_test_cavity"
DOT_GATE_PX = 5.0  # the calibration dots lie ~50 px apart: a detection this near a projection is the dot's
# SOURCE.md: a pinhole model puts the dots a median 13-19 px from their detections; the refraction it
# leaves out is most of that, so the window model must take away at least four fifths of it
PINHOLE_MEDIAN_PX = 13.0
SEEN_SHARE = 0.5  # cameras 1 and 2 see half of the target (test_cavity's history: "does not see half of the target")
OPTV_TOL_PX = 0.01  # OpenPTV stops its projection's iteration at 1 um in the water: ~0.01 px at 0.1 mm a pixel


def _cameras(root):
    return read_openptv_cameras(root / "parameters" / "ptv.par", [root / f"cal/cam{i}.tif.ori" for i in range(1, 5)],
                                [root / f"cal/cam{i}.tif.addpar" for i in range(1, 5)])


def _projected_dots(cams, root, c):
    dots = np.loadtxt(root / "cal" / "target_on_a_side.txt")[:, 1:] * MM
    cam = cams.rig.cameras[c]
    return project_through_window(cams.windows[c], cams.R[c], cams.t[c], dots) * cam.focal + cam.K[:2, 2]


@pytest.mark.shared_data
def test_cavity_is_read_in_openptvs_order(shared_data):
    root = shared_data / CAVITY
    control = read_control_par(root / "parameters" / "ptv.par")
    assert (control.cameras, control.imx, control.imy) == (4, 1280, 1024)
    assert (control.n_air, control.n_glass, control.n_water, control.thickness_mm) == (1.0, 1.33, 1.46, 6.0)
    cams = _cameras(root)
    centre = -np.einsum("cji,cj->ci", cams.R, cams.t)
    np.testing.assert_allclose(centre[0] / MM, [78.11540017, 15.92351739, -570.78991501], atol=1e-8)
    np.testing.assert_allclose(cams.rig.cameras[0].focal, [70 / 0.012] * 2)
    assert cams.windows[0].normal @ centre[0] > cams.windows[0].distance  # the camera is on the window's air side
    uv, tnr = read_targets(root / "img" / "cam1.10000_targets")
    assert uv.shape == (1179, 2) and tnr.shape == (1179,)
    np.testing.assert_allclose(uv[0], [1036.0346 - PIXEL_CORNER, 18.4508 - PIXEL_CORNER])


@pytest.mark.shared_data
def test_calibration_dots_land_on_their_detections(shared_data):
    root = shared_data / CAVITY
    cams = _cameras(root)
    for c in range(4):
        d, _ = cKDTree(read_targets(root / "cal" / f"cam{c + 1}.tif_targets")[0]).query(_projected_dots(cams, root, c))
        found = d[d < DOT_GATE_PX]
        assert len(found) >= SEEN_SHARE * 73, f"camera {c + 1}: {len(found)} dots found"
        assert np.median(found) < PINHOLE_MEDIAN_PX / 5, f"camera {c + 1}: median {np.median(found):.2f} px"


@pytest.mark.shared_data
def test_projection_is_openptvs(shared_data):
    optv = pytest.importorskip("optv.imgcoord")
    from optv.calibration import Calibration
    from optv.parameters import ControlParams
    from optv.transforms import convert_arr_metric_to_pixel

    root = shared_data / CAVITY
    cams = _cameras(root)
    cpar = ControlParams(4)
    cpar.read_control_par(str(root / "parameters" / "ptv.par"))
    dots = np.loadtxt(root / "cal" / "target_on_a_side.txt")[:, 1:]
    for c in range(4):
        cal = Calibration()
        cal.from_file(str(root / "cal" / f"cam{c + 1}.tif.ori"), str(root / "cal" / f"cam{c + 1}.tif.addpar"))
        theirs = convert_arr_metric_to_pixel(optv.image_coordinates(dots, cal, cpar.get_multimedia_params()), cpar)
        np.testing.assert_allclose(_projected_dots(cams, root, c) + PIXEL_CORNER, theirs, atol=OPTV_TOL_PX)


ORI = "0 0 -570\n0 0 0\n-1 0 0\n0 1 0\n0 0 -1\n0 0\n70\n0 0 -125\n"
PTV = "1\na\nb\nc\nd\ne\nf\ng\nh\n1\n0\n1\n1280\n1024\n0.012\n0.012\n0\n1\n1.49\n1.33\n6\n"


def test_a_plain_cavity_file_set_reads(tmp_path):
    (tmp_path / "ptv.par").write_text(PTV)
    (tmp_path / "c.ori").write_text(ORI)
    (tmp_path / "c.addpar").write_text("0 0 0 0 0 1 0")
    cams = read_openptv_cameras(tmp_path / "ptv.par", [tmp_path / "c.ori"] * 2, [tmp_path / "c.addpar"] * 2)
    # the camera at z = -570 mm looks along +z: its optical axis (R's last row) is world +z
    np.testing.assert_allclose(cams.R[0][2], [0, 0, 1])
    assert cams.windows[0].distance == pytest.approx(0.125) and cams.windows[0].thickness == pytest.approx(0.006)


@pytest.mark.parametrize("name, text, words", [
    ("ptv.par", "4\na\nb\n", "ptv.par"),
    ("c.ori", "0 0 -570\n0 0 0\n", "21"),
    ("c.addpar", "0.1 0 0 0 0 1 0", "lens terms"),
    ("t_targets", "3\n 0 1 2 3 4 5 6 -1\n", "announces 3"),
])
def test_bad_files_are_named(tmp_path, name, text, words):
    (tmp_path / "ptv.par").write_text(PTV)
    (tmp_path / "c.ori").write_text(ORI)
    (tmp_path / "c.addpar").write_text("0 0 0 0 0 1 0")
    (tmp_path / name).write_text(text)
    with pytest.raises(CaptureFormatError, match=words) as err:
        if name == "t_targets":
            read_targets(tmp_path / name)
        else:
            read_openptv_cameras(tmp_path / "ptv.par", [tmp_path / "c.ori"] * 2, [tmp_path / "c.addpar"] * 2)
    assert name in str(err.value)
