"""Fuzz the readers added this round (issue 34's rule for every new reader): a take folder's
``take.csv`` (``wandcal watch``, POST /watch) and OpenPTV's ``ptv.par``, ``.ori``, ``.addpar`` and
``_targets`` files (capture/formats/openptv.py). As in test_fuzz_readers.py: a reader accepts a bad
input or refuses it with a message naming the file; what it accepts holds finite numbers only."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests.reliability.fuzzing import FUZZ, garbage_bytes, mutated_csv, mutated_text, refused_cleanly, truncated
from wandcal.calib.sim.takes import simulate_take
from wandcal.capture.formats.openptv import read_control_par, read_openptv_cameras, read_targets
from wandcal.capture.take_file import read_take, write_take
from wandcal.drivers.capture_files import TAKE_FILE

pytestmark = pytest.mark.slow

# OpenPTV's files as its tools write them (the layout of ../shared/data/openptv_test_cavity; these
# numbers are made up here, no file of that data is copied)
PTV_PAR = "2\n" + "".join(f"img/cam{i}\ncal/cam{i}.tif\n" for i in range(1, 5)) + "1\n0\n1\n1280\n1024\n0.012\n0.012\n0\n1\n1.33\n1.46\n6\n"
ORI = ("-250.0 -15.0 600.0\n0.2 -0.4 0.01\n\n0.92 -0.01 -0.39\n0.0 1.0 -0.02\n0.39 0.02 0.92\n\n"
       "0.01 -0.02\n60.0\n\n0.0 0.0 300.0\n")
ADDPAR = "0 0 0 0 0 1 0\n"
TARGETS = "3\n0 640.5 512.2 12 4 4 900 -1\n1 100.0 200.0 9 3 3 600 2\n2 1000.25 900.75 15 4 5 1200 7\n"


@pytest.fixture(scope="module")
def take_folder(tmp_path_factory) -> Path:
    sim = simulate_take(3, 20, markers=6, bodies=2, seed=3)
    folder = tmp_path_factory.mktemp("take")
    write_take(folder, sim.rig, sim.blobs)
    return folder


@FUZZ
@given(data=st.one_of(garbage_bytes(), st.sampled_from([b""])))
def test_take_csv_garbage(take_folder, tmp_path_factory, data):
    _take_with(take_folder, tmp_path_factory, data, "take.csv garbage")


@FUZZ
@given(st.data())
def test_take_csv_mutated_or_cut(take_folder, tmp_path_factory, data):
    text = (take_folder / TAKE_FILE).read_text()
    bad = data.draw(st.one_of(mutated_csv(text), truncated(text.encode())))
    _take_with(take_folder, tmp_path_factory, bad, "take.csv mutated or truncated")


def _take_with(good: Path, factory, data: bytes, kind: str) -> None:
    folder = factory.mktemp("bad_take")
    (folder / "rig.json").write_bytes((good / "rig.json").read_bytes())
    (folder / TAKE_FILE).write_bytes(data)
    take = refused_cleanly(lambda: read_take(folder), kind, TAKE_FILE)
    if take is not None:
        assert np.isfinite(take.blobs.uv).all() and len(take.blobs.frame)


def _openptv(folder: Path, par: str = PTV_PAR, ori: str = ORI, addpar: str = ADDPAR) -> tuple[Path, list, list]:
    (folder / "ptv.par").write_text(par)
    for name in ("cam1", "cam2"):
        (folder / f"{name}.tif.ori").write_text(ori)
        (folder / f"{name}.tif.addpar").write_text(addpar)
    return (folder / "ptv.par", [folder / f"cam{i}.tif.ori" for i in (1, 2)],
            [folder / f"cam{i}.tif.addpar" for i in (1, 2)])


def test_the_made_up_openptv_files_read(tmp_path):
    par, ori, addpar = _openptv(tmp_path)
    cams = read_openptv_cameras(par, ori, addpar)
    assert len(cams.rig.cameras) == 2 and np.isfinite(cams.t).all()
    (tmp_path / "t").write_text(TARGETS)
    uv, tnr = read_targets(tmp_path / "t")
    assert uv.shape == (3, 2) and tnr.tolist() == [-1, 2, 7]


@FUZZ
@given(st.data())
def test_openptv_camera_files_mutated(tmp_path_factory, data):
    which = data.draw(st.sampled_from(["ptv.par", ".ori", ".addpar"]))
    good = {"ptv.par": PTV_PAR, ".ori": ORI, ".addpar": ADDPAR}[which]
    bad = data.draw(st.one_of(mutated_text(good), truncated(good.encode()))).decode(errors="replace")
    texts = {"ptv.par": PTV_PAR, ".ori": ORI, ".addpar": ADDPAR} | {which: bad}
    par, ori, addpar = _openptv(tmp_path_factory.mktemp("optv"), texts["ptv.par"], texts[".ori"], texts[".addpar"])
    cams = refused_cleanly(lambda: read_openptv_cameras(par, ori, addpar), f"OpenPTV {which} mutated",
                           ("ptv.par", ".ori", ".addpar"))
    if cams is not None:
        assert np.isfinite(cams.R).all() and np.isfinite(cams.t).all()
        assert all(np.isfinite(c.K).all() for c in cams.rig.cameras)
        control = read_control_par(par)
        assert all(np.isfinite(v) for v in (control.n_air, control.n_glass, control.n_water, control.thickness_mm))


@FUZZ
@given(st.data())
def test_openptv_targets_mutated(tmp_path_factory, data):
    bad = data.draw(st.one_of(mutated_text(TARGETS), truncated(TARGETS.encode()), garbage_bytes()))
    path = tmp_path_factory.mktemp("targets") / "cam1.10000_targets"
    path.write_bytes(bad)
    got = refused_cleanly(lambda: read_targets(path), "OpenPTV _targets mutated", "_targets")
    if got is not None:
        assert np.isfinite(got[0]).all()
