"""``wandcal-result/1`` written from typed values (calib/run/result.py) in the very bytes the code
before them wrote: each kept result (tests/fixtures/results/, written by that code) is made again
from the same inputs and compared byte for byte, and each reads back into typed values that write
the same bytes again."""

import json
import math
from pathlib import Path

import pytest

from tests.fixtures.results.cases import CASES, Case, run, written
from wandcal.calib.run.camera_figures import CameraFigures
from wandcal.calib.run.result import SolverReport, WorldFrame
from wandcal.capture.result_file import read_result

# A fresh install takes the newest numpy and SciPy, which move a float's last bits (the same with
# OpenCV 4.14 or 5.0); the uncertainty's inverse of the gauge-fixed normal matrix amplifies them (6e-8
# relative at worst over the kept cases, decision 0108). The format is still pinned exactly: every
# key in its order, every string, integer and flag.
RELATIVE = 1e-6


def _leaves(doc, path=""):
    if isinstance(doc, dict):
        for key, value in doc.items():
            yield from _leaves(value, f"{path}.{key}")
    elif isinstance(doc, list):
        for i, value in enumerate(doc):
            yield from _leaves(value, f"{path}[{i}]")
    else:
        yield path, doc


def _same_within_float_noise(got: bytes, kept: bytes) -> list[str]:
    """The leaves of two written results that differ: in place, type or value (floats to RELATIVE)."""
    ours, theirs = list(_leaves(json.loads(got))), list(_leaves(json.loads(kept)))
    if [k for k, _ in ours] != [k for k, _ in theirs]:
        return ["the keys or their order differ"]
    return [f"{k}: {a!r} != {b!r}" for (k, a), (_, b) in zip(ours, theirs)
            if type(a) is not type(b) or (a != b and not (isinstance(a, float)
                                                         and math.isclose(a, b, rel_tol=RELATIVE, abs_tol=1e-12)))]


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.name)
def test_the_same_inputs_write_the_same_bytes_as_before(case: Case):
    assert _same_within_float_noise(written(run(case).to_json()), case.path.read_bytes()) == []


def test_the_float_noise_allowance_still_catches_a_changed_figure():
    kept = CASES[0].path.read_bytes()
    doc = json.loads(kept)
    doc["cameras"][0]["center_std_mm"] *= 1 + 10 * RELATIVE
    assert _same_within_float_noise(written(doc), kept) == [
        f".cameras[0].center_std_mm: {doc['cameras'][0]['center_std_mm']!r} != "
        f"{json.loads(kept)['cameras'][0]['center_std_mm']!r}"]


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.name)
def test_an_old_result_reads_into_typed_values_that_write_it_again(case: Case):
    got = read_result(case.path)
    assert written(got.result.to_json()) == case.path.read_bytes()
    doc = json.loads(case.path.read_text())
    for cam, entry in zip(got.result.cameras, doc["cameras"]):
        assert cam.reprojection_rms_px == entry["reprojection_rms_px"]
        assert cam.judged is not None and cam.judged.coverage == entry["coverage"]
        assert (cam.points is not None) == ("point_rms_px" in entry)
        assert (cam.intrinsics is not None) == ("intrinsics" in entry)
    assert got.result.world.frame == doc["world"]["frame"] and got.result.solver.method == doc["solver"]["method"]


def test_a_result_of_older_code_lacking_the_newer_fields_reads_them_as_absent():
    entry = {"reprojection_rms_px": 0.4, "observations": 10, "frames_with_both_ends": 5,
             "worst_frames": [{"frame": 3, "error_px": 1.0}], "initial_pose": "static object", "center_std_mm": 0.2}
    cam = CameraFigures.from_json(entry)
    assert cam.uncertainty is not None and cam.uncertainty.center_std_mm == 0.2 and cam.uncertainty.rotation_std_deg is None
    assert cam.uncertainty.geometry is None and cam.judged is None and cam.points is None and cam.verdict is None
    assert cam.to_json() == entry | {"rotation_std_deg": None}
    assert WorldFrame.from_json({"frame": "axis"}).to_json() == {"frame": "axis", "description": None}
    solver = SolverReport.from_json({"method": "lp", "status": "converged", "iterations": 4})
    assert (solver.status, solver.iterations, solver.refined_intrinsics, solver.total_seconds) == ("converged", 4, (), None)


BEFORE = sorted((Path(__file__).resolve().parents[1] / "fixtures" / "results" / "before").glob("*.json"))


@pytest.mark.parametrize("path", BEFORE, ids=lambda p: p.stem)
def test_a_result_written_before_the_honest_sigma_reads_and_writes_the_same_bytes(path: Path):
    """tests/fixtures/results/before/: the same cases as written before each camera carried its
    focal-length limit (focal_limit, geometry_std_honest_mm) and the verdict its limits."""
    got = read_result(path)
    assert written(got.result.to_json()) == path.read_bytes()
    assert all(cam.focal_limit is None for cam in got.result.cameras)


def test_a_moved_entry_reads_back_typed_and_writes_the_same():
    from wandcal.calib.run.camera_figures import CameraFigures, Movement

    entry = {"reprojection_rms_px": 1.0, "observations": 10, "frames_with_both_ends": 5, "worst_frames": [],
             "initial_pose": "chain", "moved": {"frame": 51, "degrees": 0.82, "degrees_std": 0.2, "centre_mm": 9.0,
                                                 "centre_std_mm": 5.0}}
    cam = CameraFigures.from_json(entry)
    assert cam.moved == Movement(51, 0.82, 0.2, 9.0, 5.0)
    assert cam.to_json() == entry
    assert CameraFigures.from_json({k: v for k, v in entry.items() if k != "moved"}).moved is None


BEFORE_LENS = sorted((Path(__file__).resolve().parents[1] / "fixtures" / "results" / "before_lens").glob("*.json"))


@pytest.mark.parametrize("path", BEFORE_LENS, ids=lambda p: p.stem)
def test_a_result_written_before_the_lens_limits_reads_and_writes_the_same_bytes(path: Path):
    """tests/fixtures/results/before_lens/: the kept results as written before each camera carried
    its other given intrinsics' limits (lens_limits; the honest sigma of the focal length alone)."""
    got = read_result(path)
    assert written(got.result.to_json()) == path.read_bytes()
    assert all(cam.focal_limit is None or cam.focal_limit.lens_limits is None for cam in got.result.cameras)
