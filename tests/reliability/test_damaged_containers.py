"""Damaged containers (issue 20, class 7): a .mat whose compressed data is corrupted (before: a
zlib traceback), and a data directory whose parts are the wrong kind of file (before: ``serve``
with a database path that is a folder crashed with a traceback). Each is a refusal naming it."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.reliability.fuzzing import TRIED
from tests.service.conftest import REPO, free_port
from wandcal.calib.errors import CalibrationError
from wandcal.capture.folder import CaptureFormatError
from wandcal.capture.importers.easywand import read_easywand_mat
from wandcal.service.db import DataDirectoryError
from wandcal.service.main import create_app
from wandcal.service.settings import Settings

FUZZ = settings(max_examples=80, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
SESSION = "easywand_brown_windtunnel_4cam/calibration1/extrinsicCalib_20230228_easyWandData.mat"
MAT_HEADER = 128  # a .mat file's text header; the data elements (zlib-compressed in v7) follow


@pytest.fixture
def session_bytes(shared_data):
    return (shared_data / SESSION).read_bytes()


def test_a_mat_with_corrupted_compressed_data_is_refused_naming_it(session_bytes, tmp_path_factory):
    path = tmp_path_factory.mktemp("mat") / "session_easyWandData.mat"
    size = len(session_bytes)

    @FUZZ
    @given(flips=st.lists(st.tuples(st.integers(MAT_HEADER, size - 1), st.integers(0, 255)), min_size=1, max_size=8),
           cut=st.one_of(st.none(), st.integers(MAT_HEADER, size)))
    def fuzz(flips, cut):
        data = bytearray(session_bytes)
        for at, value in flips:
            data[at] = value
        path.write_bytes(bytes(data[:cut]))
        TRIED["easyWand sessions with corrupted compressed data"] += 1
        try:
            read_easywand_mat(path)
        except CaptureFormatError as exc:
            assert str(path) in str(exc), str(exc)

    fuzz()


KINDS = ("absent", "folder", "file", "garbage", "dangling link")


def _make(path, kind):
    if kind == "folder":
        path.mkdir(parents=True, exist_ok=True)
    elif kind in ("file", "garbage"):
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(b"" if kind == "file" else os.urandom(3000))
    elif kind == "dangling link":
        path.parent.mkdir(parents=True, exist_ok=True)
        path.symlink_to(path.parent / "nowhere")


@FUZZ
@given(db=st.sampled_from(KINDS), captures=st.sampled_from(KINDS), reports=st.sampled_from(KINDS),
       tmp=st.sampled_from(KINDS), data=st.sampled_from(("folder", "file")))
def test_a_data_directory_of_any_layout_starts_or_is_refused_naming_the_path(tmp_path_factory, db, captures,
                                                                             reports, tmp, data):
    root = tmp_path_factory.mktemp("layout")
    data_dir = root / "data"
    _make(data_dir, data)
    if data == "folder":
        for name, kind in (("wandcal.sqlite3", db), ("captures", captures), ("reports", reports), ("tmp", tmp)):
            _make(data_dir / name, kind)
    TRIED["data directories of every layout"] += 1
    try:
        create_app(Settings(data_dir=data_dir, workers=0))
    except CalibrationError as exc:
        assert str(data_dir) in str(exc), str(exc)


def test_serve_on_a_database_path_that_is_a_folder_exits_2_naming_it(tmp_path):
    data_dir = tmp_path / "data"
    (data_dir / "wandcal.sqlite3").mkdir(parents=True)
    env = {k: v for k, v in os.environ.items() if not k.startswith("WANDCAL_")}
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    run = subprocess.run([sys.executable, "-m", "wandcal.service.cli", "serve", "--data-dir", str(data_dir),
                          "--port", str(free_port()), "--workers", "0"], env=env, capture_output=True, text=True, timeout=120, check=False)
    assert run.returncode == 2, run.stderr
    assert "Traceback" not in run.stderr
    assert str(data_dir / "wandcal.sqlite3") in run.stderr and "is a folder" in run.stderr
    assert isinstance(DataDirectoryError("x"), CalibrationError)


@pytest.mark.parametrize("option", [["--port", "0"], ["--port", "70000"], ["--workers", "-1"]])
def test_serve_with_a_wrong_setting_exits_2_naming_it(tmp_path, option):
    env = {k: v for k, v in os.environ.items() if not k.startswith("WANDCAL_")}
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    run = subprocess.run([sys.executable, "-m", "wandcal.service.cli", "serve", "--data-dir", str(tmp_path), *option],
                         env=env, capture_output=True, text=True, timeout=120, check=False)
    assert run.returncode == 2 and "Traceback" not in run.stderr, run.stderr
    assert option[0].lstrip("-") in run.stderr, run.stderr
