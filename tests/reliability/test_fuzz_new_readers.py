"""Fuzz the readers added since round two (issue 34): anipose ``calibration.toml`` and DeepLabCut
CSVs, multi-marker wands (collinear and planar ``wand.markers_m``) in rig.json, sync.csv's camera
timestamps and capture.json's frame rate, labelled points.csv with axis.csv, and every
``wandcal export`` format read back (``wandcal import cameras``). As in test_fuzz_readers.py: a
reader accepts a bad input or refuses it with a message naming the file
(:func:`fuzzing.refused_cleanly`); what it accepts must be a rig it could have been given (finite
numbers, rotations), and an unchanged export must read back as written."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests.reliability.fuzzing import (
    FUZZ,
    FUZZ_PIPELINE,
    TRIED,
    garbage_bytes,
    mutated_csv,
    mutated_json,
    mutated_text,
    refused_cleanly,
    truncated,
    wrong_encoding,
)
from tests.reliability.test_fuzz_readers import _kind
from wandcal.calib.rig import AxisObservations, PointObservations
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.capture.folder import AXIS_FILE, POINTS_FILE, RIG_FILE, STATIC_FILE, read_capture, write_capture
from wandcal.capture.formats.cameras import PosedCameras
from wandcal.capture.formats.cameras_in import read_camera_file
from wandcal.capture.formats.export import FORMAT_NAMES, export
from wandcal.capture.importers.anipose import read_anipose
from wandcal.capture.importers.deeplabcut import read_dlc_csv

SIM = simulate_capture(3, 40, 0.3, seed=1)
SUFFIX = {"anipose-toml": ".toml", "opencv-yaml": ".yaml", "dlt-csv": ".csv", "qca": ".qca.txt", "xcp": ".xcp"}
# Every writer prints floats by repr (17 significant digits); what the readers then compute
# (Rodrigues vectors, quaternions, DLT's RQ decomposition, mm to m) loses a few more ulps.
ROUND_TRIP_REL = 1e-9


def _bad(valid: bytes, structured):
    """The bad versions of a file: structured mutations (twice as often), random bytes, another
    encoding, truncation."""
    return st.one_of(structured, structured, garbage_bytes(), wrong_encoding(valid.decode()), truncated(valid))


def _sound(posed: PosedCameras) -> None:
    """What a reader accepted is a rig it could have been given: finite intrinsics and poses."""
    for cam in posed.cameras:
        assert np.all(np.isfinite(cam.K)) and np.all(np.isfinite(cam.dist)), cam
    assert np.all(np.isfinite(posed.R)) and np.all(np.isfinite(posed.t)), (posed.R, posed.t)


@pytest.fixture(scope="module")
def result() -> dict:
    from wandcal.calib.run.calibrate import calibrate

    return calibrate(SIM.rig, SIM.wand, SIM.static).to_json()


def _read_export(path: Path, fmt: str) -> PosedCameras:
    sizes = [(c.width, c.height) for c in SIM.rig.cameras] if fmt == "dlt-csv" else None
    return read_camera_file(path, fmt, sizes=sizes, ids=list(SIM.rig.ids) if fmt == "dlt-csv" else None)


# -- every export read back -------------------------------------------------------------------
@pytest.mark.parametrize("fmt", FORMAT_NAMES)
def test_an_export_reads_back_as_written(result, tmp_path, fmt):
    """``wandcal export`` then ``wandcal import cameras``: the same cameras, poses and lenses."""
    from wandcal.service.cli import main

    path = tmp_path / f"calibration{SUFFIX[fmt]}"
    path.write_text(export(result, fmt, SIM.rig))
    sizes = [arg for c in SIM.rig.cameras for arg in ("--size", f"{c.width}x{c.height}")] if fmt == "dlt-csv" else []
    assert main(["import", "cameras", str(path), "--format", fmt, "--out", str(tmp_path / "out"), *sizes]) == 0
    posed = _read_export(path, fmt)
    for k, (cam, entry) in enumerate(zip(posed.cameras, result["cameras"])):
        np.testing.assert_allclose(cam.K, entry["K"], rtol=ROUND_TRIP_REL, atol=ROUND_TRIP_REL)
        np.testing.assert_allclose(posed.R[k], entry["R"], rtol=0, atol=ROUND_TRIP_REL)
        np.testing.assert_allclose(posed.t[k], entry["t"], rtol=ROUND_TRIP_REL, atol=ROUND_TRIP_REL)
        assert (cam.width, cam.height) == (entry["width"], entry["height"])
    poses = json.loads((tmp_path / "out" / "poses.json").read_text())
    np.testing.assert_allclose([c["R"] for c in poses["cameras"]], posed.R, rtol=0, atol=1e-15)


@pytest.mark.parametrize("fmt", FORMAT_NAMES)
def test_export_files_damaged(result, tmp_path_factory, fmt):
    path = tmp_path_factory.mktemp("export") / f"calibration{SUFFIX[fmt]}"
    valid = export(result, fmt, SIM.rig).encode()
    structured = mutated_csv(valid.decode()) if fmt == "dlt-csv" else mutated_text(valid.decode())

    @FUZZ
    @given(data=_bad(valid, structured))
    def fuzz(data):
        path.write_bytes(data)
        posed = refused_cleanly(lambda: _read_export(path, fmt), f"{fmt} read back: {_kind(data, valid)}", str(path))
        if posed is not None:
            _sound(posed)

    fuzz()


# -- anipose sessions: calibration.toml and DeepLabCut CSVs ------------------------------------
def _dlc_csv(seed: int) -> bytes:
    """A DeepLabCut CSV of two keypoints over 12 frames (a network's output, with likelihoods)."""
    rng = np.random.default_rng(seed)
    lines = ["scorer" + ",DLC_resnet50_wandJan1shuffle1_1000" * 6, "bodyparts,nose,nose,nose,tail,tail,tail",
             "coords,x,y,likelihood,x,y,likelihood"]
    for f in range(12):
        (u1, v1), (u2, v2) = rng.uniform(100, 900, (2, 2))
        lines.append(f"{f},{u1:.3f},{v1:.3f},{rng.uniform(0.3, 1):.3f},{u2:.3f},{v2:.3f},{rng.uniform(0.3, 1):.3f}")
    return ("\n".join(lines) + "\n").encode()


@pytest.mark.parametrize("name", ["calibration.toml", "cam1DLC_resnet50.csv"])
def test_anipose_sessions(result, tmp_path_factory, name):
    folder = tmp_path_factory.mktemp("anipose")
    files = {"calibration.toml": export(result, "anipose-toml", SIM.rig).encode()}
    files |= {f"{cid}DLC_resnet50.csv": _dlc_csv(k) for k, cid in enumerate(SIM.rig.ids)}
    valid = files[name]
    structured = mutated_text(valid.decode()) if name.endswith(".toml") else mutated_csv(valid.decode())
    points = [f"{cid}={folder / f'{cid}DLC_resnet50.csv'}" for cid in SIM.rig.ids]

    @FUZZ
    @given(data=_bad(valid, structured))
    def fuzz(data):
        for n, content in files.items():
            (folder / n).write_bytes(data if n == name else content)
        kind = f"anipose {name}: {_kind(data, valid)}"
        got = refused_cleanly(lambda: read_anipose(folder / "calibration.toml", points), kind, (name, str(folder)))
        if got is not None:
            _sound(got[1])
        if name.endswith(".csv"):
            keypoints = refused_cleanly(lambda: read_dlc_csv(folder / name), f"DeepLabCut CSV: {_kind(data, valid)}",
                                        name)
            assert keypoints is None or np.all(np.isfinite(keypoints.uv))

    fuzz()


# -- rig.json with a multi-marker wand; labelled points and axis.csv --------------------------
WANDS = {
    "collinear": np.array([[0.0, 0, 0], [0.2, 0, 0], [0.5, 0, 0]]),
    "planar": np.array([[0.0, 0, 0], [0.25, 0, 0], [0.5, 0, 0], [0.25, 0.15, 0]]),
}


def _fuzz_folder(folder: Path, files: dict[str, bytes], name: str, structured) -> None:
    valid = files[name]

    @FUZZ
    @given(data=_bad(valid, structured))
    def fuzz(data):
        for n, content in files.items():
            (folder / n).write_bytes(data if n == name else content)
        capture = refused_cleanly(lambda: read_capture(folder), f"{name} ({folder.name}): {_kind(data, valid)}", name)
        if capture is not None and capture.rig.wand_markers is not None:
            assert np.all(np.isfinite(capture.rig.wand_markers)) and capture.rig.wand_length > 0

    fuzz()


@pytest.mark.parametrize("wand", list(WANDS))
def test_multi_marker_wands_in_rig_json(tmp_path_factory, wand):
    sim = simulate_capture(3, 30, 0.3, seed=2, wand_markers=WANDS[wand])
    folder = tmp_path_factory.mktemp(f"{wand}-wand")
    write_capture(folder, sim.rig, sim.wand, sim.static)
    files = {p.name: p.read_bytes() for p in folder.iterdir()}
    _fuzz_folder(folder, files, RIG_FILE, mutated_json(json.loads(files[RIG_FILE])))


@pytest.mark.parametrize("name", [POINTS_FILE, AXIS_FILE])
def test_labelled_points_and_axis(tmp_path_factory, name):
    folder = tmp_path_factory.mktemp("labelled")
    rng = np.random.default_rng(3)
    points = PointObservations(frame=[1000, 1000, 1000, 1000, 1001, 1001], camera=[0, 1, 0, 2, 0, 1],
                               uv=rng.uniform(0, 1000, (6, 2)), point=["nose", "nose", "tail", "tail", "nose", "nose"])
    axis = AxisObservations(role=["origin", "origin", "+x", "+x", "+y", "+y"], camera=[0, 1, 0, 2, 1, 2],
                            uv=rng.uniform(0, 1000, (6, 2)))
    write_capture(folder, SIM.rig, SIM.wand, None, points, axis)
    files = {p.name: p.read_bytes() for p in folder.iterdir() if p.name != STATIC_FILE}
    assert read_capture(folder).points.point is not None
    _fuzz_folder(folder, files, name, mutated_csv(files[name].decode()))


# -- sync.csv's camera timestamps and capture.json's frame rate (--sync auto) ------------------
def _timestamped(folder: Path) -> dict[str, bytes]:
    """A capture folder recorded without a trigger: sync.csv holds each camera's timestamps (us,
    camera k a frame late per k), capture.json the rate."""
    write_capture(folder, SIM.rig, SIM.wand, SIM.static)
    frames = np.unique(SIM.wand.frame)
    rows = ["frame,trigger_count,trigger_us," + ",".join(f"{cid}_ts" for cid in SIM.rig.ids)]
    rows += [f"{f},,," + ",".join(str(1_000_000 + 10_000 * (f + k)) for k in range(len(SIM.rig.ids))) for f in frames]
    (folder / "sync.csv").write_text("\n".join(rows) + "\n")
    (folder / "capture.json").write_text(json.dumps({"format": "wandcal-capture/1", "rate_hz": 100.0}))
    return {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file()}


@pytest.mark.parametrize("name", ["sync.csv", "capture.json"])
def test_timestamps_for_sync_auto(tmp_path_factory, name):
    from wandcal.capture.recording.stamps import capture_rate, timestamp_start

    folder = tmp_path_factory.mktemp("stamps")
    files = _timestamped(folder)
    rig = SIM.rig
    np.testing.assert_array_equal(timestamp_start(folder, rig, capture_rate(folder)), np.arange(len(rig.ids)))
    valid = files[name]
    structured = mutated_csv(valid.decode()) if name.endswith(".csv") else mutated_json(json.loads(valid))

    @FUZZ
    @given(data=_bad(valid, structured))
    def fuzz(data):
        (folder / name).write_bytes(data)
        kind = f"{name} timestamps: {_kind(data, valid)}"

        def read():
            rate = capture_rate(folder)
            assert rate is None or (np.isfinite(rate) and rate > 0), rate
            offsets = timestamp_start(folder, rig, rate)
            assert offsets is None or offsets.shape == (len(rig.ids),), offsets
            return offsets

        refused_cleanly(read, kind, name)

    fuzz()


@pytest.mark.parametrize("name", ["sync.csv", "capture.json"])
def test_calibrate_sync_auto_never_shows_a_traceback(tmp_path_factory, capsys, name):
    from wandcal.service.cli import main

    folder = tmp_path_factory.mktemp("sync-cli")
    files = _timestamped(folder)
    valid = files[name]
    structured = mutated_csv(valid.decode()) if name.endswith(".csv") else mutated_json(json.loads(valid))

    @FUZZ_PIPELINE
    @given(data=_bad(valid, structured))
    def fuzz(data):
        (folder / name).write_bytes(data)
        TRIED[f"wandcal calibrate --sync auto: {name} {_kind(data, valid)}"] += 1
        code = main(["calibrate", str(folder), "--sync", "auto", "--out", str(folder / "result.json")])
        err = capsys.readouterr().err
        assert code in (0, 2) and "Traceback" not in err, err
        assert code == 0 or name in err or "sync" in err, err

    fuzz()


def test_deeplabcut_frames_out_of_range_are_refused_naming_the_line(tmp_path):
    path = tmp_path / "cam1DLC.csv"
    for frame in ("99999999999999999999", "9" * 5000, "img" + "9" * 30 + ".png"):
        path.write_text("scorer,s,s\nbodyparts,nose,nose\ncoords,x,y\n" + frame + ",1,2\n")
        refused_cleanly(lambda: read_dlc_csv(path), "DeepLabCut CSV: known nasty", f"{path} line 4")
        with pytest.raises(ValueError, match="out of range"):
            read_dlc_csv(path)
