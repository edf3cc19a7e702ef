"""``wandcal check`` and ``wandcal calibrate --from --solve-only`` as a user runs them."""

import json

import pytest

from tests.service.conftest import wandcal
from wandcal.calib.sim.scenes import knocked_capture
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.capture.folder import write_capture


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    root = tmp_path_factory.mktemp("bump")
    sim = simulate_capture(5, 600, 0.3, 0.0, True, 4)
    write_capture(root / "base", sim.rig, sim.wand, sim.static)
    wand, _, _ = knocked_capture(sim, 1, 1.0, 0.03, 600, 8)
    write_capture(root / "fresh", sim.rig, wand, None)
    r = wandcal("calibrate", root / "base", "--quiet")
    assert r.returncode == 0, r.stderr
    return root


def test_check_exits_1_naming_the_moved_camera_then_solve_only_fixes_it(folders):
    base, fresh = folders / "base" / "result.json", folders / "fresh"
    r = wandcal("check", base, fresh, "--json")
    assert r.returncode == 1, r.stderr
    doc = json.loads(r.stdout)
    assert doc["moved"] == ["cam2"]
    assert {c["id"]: c["moved"] for c in doc["cameras"]} == {f"cam{k}": k == 2 for k in range(1, 6)}
    assert all({"id", "moved", "rms_px"} <= set(c) for c in doc["cameras"])

    r = wandcal("calibrate", fresh, "--from", base, "--solve-only", "cam2", "--out", folders / "new.json", "--quiet")
    assert r.returncode == 0, r.stderr
    old, new = json.loads(base.read_text()), json.loads((folders / "new.json").read_text())
    for a, b in zip(old["cameras"], new["cameras"]):
        if a["id"] != "cam2":
            assert a["R"] == b["R"] and a["t"] == b["t"]  # bit for bit, through JSON
    assert new["world"] == old["world"]
    r = wandcal("check", folders / "new.json", fresh)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "every camera agrees" in r.stdout


@pytest.mark.parametrize("args, words", [
    (["--solve-only", "cam2"], "--from RESULT and --solve-only"),
    (["--from", "{base}", "--solve-only", "cam9"], "unknown camera id 'cam9'"),
    (["--from", "{missing}", "--solve-only", "cam2"], "not found"),
])
def test_solve_only_bad_input_exits_2_with_a_message(folders, args, words):
    subs = {"base": folders / "base" / "result.json", "missing": folders / "nope.json"}
    r = wandcal("calibrate", folders / "fresh", *[a.format(**subs) for a in args], "--quiet")
    assert r.returncode == 2 and words in r.stderr and "Traceback" not in r.stderr


def test_check_on_a_garbage_result_exits_2(folders, tmp_path):
    bad = tmp_path / "r.json"
    bad.write_bytes(b"\x00\xff garbage")
    r = wandcal("check", bad, folders / "fresh")
    assert r.returncode == 2 and str(bad) in r.stderr and "Traceback" not in r.stderr


def test_check_with_too_few_frames_says_it_cannot_judge_and_exits_3(folders, tmp_path):
    """Five frames judge nothing: never 'agrees' (exit 0) nor 'moved' (exit 1)."""
    sim = simulate_capture(5, 5, 0.3, 0.0, False, 4)
    short = tmp_path / "short"
    write_capture(short, simulate_capture(5, 600, 0.3, 0.0, True, 4).rig, sim.wand, None)
    r = wandcal("check", folders / "base" / "result.json", short, "--json")
    assert r.returncode == 3, r.stdout + r.stderr
    doc = json.loads(r.stdout)
    assert doc["moved"] == [] and len(doc["unjudged"]) == 5
    r = wandcal("check", folders / "base" / "result.json", short)
    assert r.returncode == 3 and "could not judge" in r.stdout and "agrees" not in r.stdout


def test_check_refuses_a_capture_of_another_rig_naming_the_mismatch(folders, tmp_path):
    """Other image sizes and intrinsics: a refusal (exit 2), not 'cam1 moved'."""
    other = simulate_capture(5, 600, 0.3, 0.0, False, 9)
    cams = tuple(type(c)(c.id, c.width // 2, c.height // 2, c.K * [[0.5], [0.5], [1]], c.dist, c.model)
                 for c in other.rig.cameras)
    folder = tmp_path / "other"
    write_capture(folder, type(other.rig)(cams, other.rig.wand_length), other.wand, None)
    r = wandcal("check", folders / "base" / "result.json", folder)
    assert r.returncode == 2 and "not of this result's rig" in r.stderr and "640x512 px in the capture" in r.stderr
    assert "moved" not in r.stdout and "Traceback" not in r.stderr


def test_check_and_solve_only_take_a_three_marker_wand_and_tell_another_rig(tmp_path):
    """A 3-marker capture against its own result: exit 0; a camera knocked 0.5 degrees: exit 1 naming
    it, and --solve-only re-solves it; a capture of another rig with the same ids and sizes: exit 3."""
    import dataclasses

    import numpy as np

    layout = np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.5, 0.0, 0.0]])
    sim = simulate_capture(4, 400, 0.3, 0.0, False, 4, wand_markers=layout)
    write_capture(tmp_path / "base", sim.rig, sim.wand, None)
    assert wandcal("calibrate", tmp_path / "base", "--quiet").returncode == 0
    result = tmp_path / "base" / "result.json"
    r = wandcal("check", result, tmp_path / "base")
    assert r.returncode == 0 and "every camera agrees" in r.stdout, r.stdout + r.stderr
    wand, _, _ = knocked_capture(sim, 2, 0.5, 0.0, 400, 8)
    write_capture(tmp_path / "knocked", sim.rig, wand, None)
    r = wandcal("check", result, tmp_path / "knocked", "--json")
    assert r.returncode == 1 and json.loads(r.stdout)["moved"] == ["cam3"], r.stdout + r.stderr
    r = wandcal("calibrate", tmp_path / "knocked", "--from", result, "--solve-only", "cam3", "--out", tmp_path / "new.json",
                "--quiet")
    assert r.returncode == 0, r.stderr
    assert wandcal("check", tmp_path / "new.json", tmp_path / "knocked").returncode == 0
    other = simulate_capture(4, 400, 0.3, 0.0, False, 11, wand_markers=layout)
    cams = tuple(dataclasses.replace(c, K=c.K * [[1.03], [1.03], [1.0]]) for c in sim.rig.cameras)
    write_capture(tmp_path / "other", dataclasses.replace(sim.rig, cameras=cams), other.wand, None)
    r = wandcal("check", result, tmp_path / "other")
    assert r.returncode == 3 and "another one; calibrate afresh" in r.stdout and "--solve-only" not in r.stdout, r.stdout


def test_check_and_solve_only_take_a_points_only_capture(tmp_path):
    import dataclasses

    import numpy as np

    from wandcal.calib.sim.scenes import pairwise_points

    sim = simulate_capture(4, 300, 0.3, 0.0, False, 1)
    rig = dataclasses.replace(sim.rig, wand_length=None)
    points = pairwise_points(sim, 400, np.random.default_rng(5), third=0.8)
    empty = type(sim.wand)(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 2)))
    write_capture(tmp_path / "pts", rig, empty, None, points)
    r = wandcal("calibrate", tmp_path / "pts", "--quiet")
    assert r.returncode == 0, r.stderr
    result = tmp_path / "pts" / "result.json"
    r = wandcal("check", result, tmp_path / "pts")
    assert r.returncode == 0, r.stdout + r.stderr
    r = wandcal("calibrate", tmp_path / "pts", "--from", result, "--solve-only", "cam2", "--out", tmp_path / "n.json", "--quiet")
    assert r.returncode == 0, r.stderr
    r = wandcal("guidance", tmp_path / "pts", "--json")
    assert r.returncode == 0 and json.loads(r.stdout)["solve"]["points_only"], r.stderr
