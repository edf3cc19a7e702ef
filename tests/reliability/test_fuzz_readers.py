"""Fuzz every reader of user files: rig.json, the CSVs, result files, the importers' files,
sync.csv and images. Random bytes, wrong encodings, huge and negative numbers, deep nesting,
missing and extra columns, truncated files: a reader accepts the input or refuses it with a
message naming the file; a traceback fails the test (:func:`fuzzing.refused_cleanly`)."""

from __future__ import annotations

import io
import json
import shutil
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
import scipy.io
from hypothesis import given
from hypothesis import strategies as st

from tests.reliability.fuzzing import (
    FUZZ,
    FUZZ_SLOW,
    TRIED,
    garbage_bytes,
    mutated_csv,
    mutated_json,
    refused_cleanly,
    truncated,
    wrong_encoding,
)
from wandcal.calib.rig import AxisObservations, Camera, PointObservations
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.capture.folder import (
    AXIS_FILE,
    POINTS_FILE,
    RIG_FILE,
    STATIC_FILE,
    WAND_FILE,
    read_capture,
    write_capture,
)
from wandcal.capture.importers.argus import read_argus
from wandcal.capture.importers.easywand import read_easywand_files, read_easywand_mat
from wandcal.capture.importers.svoboda import read_svoboda
from wandcal.capture.result_file import read_result
from wandcal.drivers.errors import DriverError

SIM = simulate_capture(3, 40, 0.3, seed=1)


def _capture_files(folder: Path) -> dict[str, bytes]:
    rng = np.random.default_rng(0)
    points = PointObservations(frame=[1000, 1000, 1001, 1001], camera=[0, 2, 0, 1], uv=rng.uniform(0, 1000, (4, 2)))
    axis = AxisObservations(role=["origin", "origin", "+z", "+z"], camera=[0, 1, 0, 2], uv=rng.uniform(0, 1000, (4, 2)))
    write_capture(folder, SIM.rig, SIM.wand, SIM.static, points, axis)
    return {p.name: p.read_bytes() for p in folder.iterdir()}


@pytest.fixture(scope="module")
def valid(tmp_path_factory) -> dict[str, bytes]:
    return _capture_files(tmp_path_factory.mktemp("valid"))


def _bad_file(valid_bytes: bytes, kind_text: bool = True):
    """The bad versions of one file: mutated, random bytes, another encoding, truncated."""
    text = valid_bytes.decode()
    structured = mutated_json(json.loads(text)) if text.lstrip().startswith("{") else mutated_csv(text)
    return st.one_of(structured, structured, garbage_bytes(), wrong_encoding(text), truncated(valid_bytes))


def _kind(data: bytes, valid_bytes: bytes) -> str:
    if valid_bytes.startswith(data):
        return "truncated"
    try:
        data.decode("utf-8")
    except UnicodeDecodeError:
        return "binary or wrong encoding"
    return "mutated"


def fuzz_one_file(folder: Path, files: dict[str, bytes], name: str, reads: dict, names) -> None:
    """Write ``files`` into ``folder`` with ``name`` replaced by its bad versions; each of
    ``reads`` ({label: read()}) must accept it or refuse it naming one of ``names``."""
    @FUZZ
    @given(data=_bad_file(files[name]))
    def fuzz(data):
        for n, content in files.items():
            (folder / n).write_bytes(data if n == name else content)
        for label, read in reads.items():
            refused_cleanly(read, f"{label}{name}: {_kind(data, files[name])}", names)

    fuzz()


@pytest.mark.parametrize("name", [RIG_FILE, WAND_FILE, STATIC_FILE, POINTS_FILE, AXIS_FILE])
def test_capture_folder_files(valid, tmp_path_factory, name):
    folder = tmp_path_factory.mktemp("fuzz")
    # static.csv and axis.csv both set the world frame, and a capture may hold one of them only
    left_out = STATIC_FILE if name == AXIS_FILE else AXIS_FILE
    files = {n: data for n, data in valid.items() if n != left_out}
    fuzz_one_file(folder, files, name, {"": lambda: read_capture(folder)}, name)


def test_calibrate_command_never_shows_a_traceback(valid, tmp_path_factory, capsys):
    """``wandcal calibrate`` end to end on a damaged wand.csv: exit 0, or exit 2 with a message."""
    from wandcal.service.cli import main

    folder = tmp_path_factory.mktemp("cli")

    @FUZZ_SLOW
    @given(data=_bad_file(valid[WAND_FILE]))
    def fuzz(data):
        for n in (RIG_FILE, STATIC_FILE):
            (folder / n).write_bytes(valid[n])
        (folder / WAND_FILE).write_bytes(data)
        TRIED[f"wandcal calibrate: {WAND_FILE} {_kind(data, valid[WAND_FILE])}"] += 1
        code = main(["calibrate", str(folder), "--out", str(folder / "result.json")])
        err = capsys.readouterr().err
        assert code in (0, 2) and "Traceback" not in err, err
        assert code == 0 or "wand.csv" in err or "camera" in err, err

    fuzz()


@pytest.fixture(scope="module")
def result_text() -> bytes:
    from wandcal.calib.run.calibrate import calibrate

    return json.dumps(calibrate(SIM.rig, SIM.wand, SIM.static).to_json()).encode()


def test_result_files(result_text, tmp_path_factory):
    path = tmp_path_factory.mktemp("result") / "result.json"

    @FUZZ
    @given(data=_bad_file(result_text))
    def fuzz(data):
        path.write_bytes(data)
        refused_cleanly(lambda: read_result(path), f"result.json: {_kind(data, result_text)}", "result.json")

    fuzz()


# -- importers --------------------------------------------------------------------------------
PROFILE = b"1 1000 1280 1024 640 512 1 -0.1 0.01 0 0 0\n2 1100 1280 1024 630 500 1 -0.12 0.02 0 0 0\n"


def _xypts(rows: int, tracks: int, seed: int) -> bytes:
    rng = np.random.default_rng(seed)
    header = ",".join(f"pt{t + 1}_cam_{c + 1}_{a}" for t in range(tracks) for c in range(2) for a in "xy")
    values = rng.uniform(10, 1000, (rows, 4 * tracks))
    values[rng.random(values.shape) < 0.1] = np.nan
    body = "\n".join(",".join("NaN" if np.isnan(v) else f"{v:.3f}" for v in row) for row in values)
    return (header + "\n" + body + "\n").encode()


ARGUS = {"wand-xypts.csv": _xypts(30, 2, 1), "profile.txt": PROFILE, "unpaired-xypts.csv": _xypts(20, 1, 2),
         "reference-xypts.csv": _xypts(3, 1, 3)}


@pytest.mark.parametrize("name", list(ARGUS))
def test_argus_and_easywand_files(tmp_path_factory, name):
    folder = tmp_path_factory.mktemp("argus")
    paths = [folder / n for n in ARGUS]  # wand, profile, unpaired, reference
    reads = {"argus ": lambda: read_argus(paths[0], paths[1], 0.5, paths[2], paths[3]),
             "easyWand ": lambda: read_easywand_files(paths[0], paths[1], 0.5, paths[2], paths[3])}
    fuzz_one_file(folder, ARGUS, name, reads, tuple(ARGUS))  # a short profile is named from the tables too


SVOBODA = {
    "points.dat": b"10 20 nan 40\n11 21 nan 41\n1 1 1 1\n50 0 70 80\n51 0 71 81\n1 1 1 1\n",
    "IdMat.dat": b"1 1 0 1\n1 0 1 1\n",
    "Res.dat": b"640 480\n640 480\n",
    "camera_order.txt": b"left\nright\n",
    "multicamselfcal.cfg": b"[Files]\nBasename: basename\n",
    "basename1.rad": b"K11 = 501\nK12 = 0\nK13 = 320\nK21 = 0\nK22 = 501\nK23 = 240\nK31 = 0\nK32 = 0\nK33 = 1\n"
                     b"kc1 = -0.1\nkc2 = 0.01\nkc3 = 0.001\nkc4 = -0.002\n",
}


@pytest.mark.parametrize("name", list(SVOBODA))
def test_multicamselfcal_folders(tmp_path_factory, name):
    folder = tmp_path_factory.mktemp("msc")
    fuzz_one_file(folder, SVOBODA, name, {"svoboda ": lambda: read_svoboda(folder, focal_px=600.0)},
                  (name, "basename", str(folder)))


EASYWAND_FIELDS = {
    "nCams": 2.0, "wandLen": 0.5, "focalLengths": [1000.0, 1100.0], "principalPoints": [640.0, 512.0, 630.0, 500.0],
    "nlin": [0.0] * 10, "imageWidth": [1280.0, 1280.0], "imageHeight": [1024.0, 1024.0],
    "wandPts": np.random.default_rng(4).uniform(10, 1000, (20, 8)), "backgroundPts": np.zeros((0, 4)),
    "axisPts": np.random.default_rng(5).uniform(10, 1000, (3, 4)), "version": "5.0",
}
MAT_VALUES = st.sampled_from(["text", -1.0, 0.0, 1e300, np.nan, np.inf, 3.5, 2**40, [], [[1.0]], np.zeros((0, 0)),
                              np.ones((3, 3, 3)), {"nested": 1.0}, np.array(["a", "b"]), True, np.ones(7)])


def test_easywand_sessions(tmp_path_factory):
    path = tmp_path_factory.mktemp("ew") / "session_easyWandData.mat"
    buffer = io.BytesIO()
    scipy.io.savemat(buffer, {"easyWandData": EASYWAND_FIELDS})
    whole = buffer.getvalue()
    edits = st.dictionaries(st.sampled_from(sorted(EASYWAND_FIELDS)), st.one_of(MAT_VALUES, st.just("DELETE")),
                            min_size=1, max_size=3)

    @FUZZ
    @given(case=st.one_of(edits, garbage_bytes(), truncated(whole)))
    def fuzz(case):
        if isinstance(case, dict):
            fields = {k: v for k, v in (EASYWAND_FIELDS | case).items() if not (isinstance(v, str) and v == "DELETE")}
            scipy.io.savemat(path, {"easyWandData": fields})
            kind = "easyWand .mat: fields of the wrong type or size"
        else:
            path.write_bytes(case)
            kind = "easyWand .mat: " + ("truncated" if whole.startswith(case) else "random bytes")
        refused_cleanly(lambda: read_easywand_mat(path), kind, path.name)

    fuzz()


# -- image level ------------------------------------------------------------------------------
def _png(width: int, height: int, data: bytes = b"") -> bytes:
    """A PNG whose header claims ``width`` x ``height`` 8-bit grey, with ``data`` as its IDAT."""
    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    header = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", data) + chunk(b"IEND", b"")


CAMERA = Camera("cam1", 64, 48, np.array([[50.0, 0, 32], [0, 50.0, 24], [0, 0, 1]]), np.zeros(5))
GOOD_PNG = cv2.imencode(".png", np.full((48, 64), 9, np.uint8))[1].tobytes()
IMAGES = st.one_of(
    garbage_bytes(), truncated(GOOD_PNG),
    st.tuples(st.integers(0, 2**31 - 1), st.integers(0, 2**31 - 1), st.binary(max_size=64)).map(lambda a: _png(*a)),
    st.sampled_from([_png(64, 48, zlib.compress(b"\0" * 10)), _png(64, 48, b"not zlib"),
                     cv2.imencode(".jpg", np.zeros((48, 64), np.uint8))[1].tobytes(),
                     cv2.imencode(".png", np.zeros((48, 64, 3), np.uint8))[1].tobytes(),
                     cv2.imencode(".png", np.zeros((48, 64), np.float32).view(np.uint8).reshape(48, 256))[1].tobytes(),
                     cv2.imencode(".tiff", np.zeros((48, 64), np.float32))[1].tobytes()]),
)


def test_uploaded_images():
    from wandcal.service.ingest import decode_image

    @FUZZ
    @given(data=IMAGES)
    def fuzz(data):
        image = refused_cleanly(lambda: decode_image(data, CAMERA), "image bytes", ("cam1",))
        assert image is None or image.shape == (48, 64)

    fuzz()


def test_replayed_image_folders(tmp_path_factory):
    """sync.csv and the PNGs of an image-level capture, replayed as cameras."""
    from wandcal.drivers.registry import open_cameras

    folder = tmp_path_factory.mktemp("replay")
    (folder / "frames" / "cam1").mkdir(parents=True)
    sync = b"frame,trigger_count,trigger_us,cam1_ts\n0,5,100,90\n1,6,10100,10090\n2,7,20100,\n"

    @FUZZ
    @given(sync_data=st.one_of(_bad_file(sync), st.just(sync)), image=IMAGES)
    def fuzz(sync_data, image):
        (folder / "sync.csv").write_bytes(sync_data)
        for k in (0, 1):
            (folder / "frames" / "cam1" / f"{k:06d}.png").write_bytes(image if k else GOOD_PNG)
        TRIED["replayed sync.csv and images"] += 1
        try:
            (camera,) = open_cameras(f"replay://{folder}")
            with camera:
                while camera.read(timeout=0.1) is not None:
                    pass
        except DriverError as exc:  # the driver's one error root; a bad frame is a FrameError
            assert "sync.csv" in str(exc) or "cam1" in str(exc), exc

    fuzz()
    shutil.rmtree(folder)


def _nasty_documents(doc: dict) -> list[bytes]:
    """Documents that each broke a reader once: deep nesting, integers past the digit limit and
    past float range, a non-string camera model, a CSV-sized field."""
    text = json.dumps(doc)
    big = "1" + "0" * 400
    cams = doc["cameras"]
    return [
        b"[" * 200_000, ("{\"format\": " + "1" + "0" * 5000 + "}").encode(),
        json.dumps(doc | {"cameras": [c | {"model": []} for c in cams]}).encode(),
        text.replace('"K": [[', f'"K": [[{big}, ', 1).encode(),
        text.replace('"width": 1280', '"width": ' + "1" + "0" * 30, 1).encode(),
        text.replace('"length_m": 0.5', f'"length_m": {big}', 1).encode(),
        text.replace('"length_m": 0.5', '"length_m": NaN', 1).encode(),
        text.encode("utf-16"), b"\xef\xbb\xbf" + text.encode(),
    ]


@pytest.mark.parametrize("name", [RIG_FILE, "result.json"])
def test_documents_that_once_crashed(valid, result_text, tmp_path, name):
    for n, content in valid.items():
        if n != AXIS_FILE:  # static.csv sets the world frame; a capture holds one of the two
            (tmp_path / n).write_bytes(content)
    doc = json.loads(valid[RIG_FILE] if name == RIG_FILE else result_text)
    for data in _nasty_documents(doc):
        (tmp_path / name).write_bytes(data)
        read = (lambda: read_capture(tmp_path)) if name == RIG_FILE else (lambda: read_result(tmp_path / name))
        refused_cleanly(read, f"{name}: known nasty", name)
    (tmp_path / WAND_FILE).write_text("frame,camera,u,v\n" + "1" * 140_000 + ",cam1,1,2\n")
    (tmp_path / RIG_FILE).write_bytes(valid[RIG_FILE])
    refused_cleanly(lambda: read_capture(tmp_path), f"{WAND_FILE}: known nasty", WAND_FILE)
