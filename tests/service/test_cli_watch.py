"""``wandcal simulate --take`` and ``wandcal watch RESULT TAKE`` as a user runs them: exit 1 and the
moved camera named, 0 for a clean take, 2 with a clear message for a take that cannot be watched."""

import functools
import json
import shutil

import pytest

from tests.service.conftest import wandcal as run_wandcal
from wandcal.drivers.capture_files import TAKE_FILE

wandcal = functools.partial(run_wandcal, timeout=900)  # a take's watch: the slowest command these tests run


@pytest.fixture(scope="module")
def root(tmp_path_factory, watch_standing, watch_knock_take):
    root = tmp_path_factory.mktemp("watch")
    shutil.copyfile(watch_standing, root / "result.json")  # 6 cameras, seed 7, calibrated (tests/service/conftest.py)
    shutil.copytree(watch_knock_take, root / "knock")  # cam2 knocked at 300 (tests/service/conftest.py)
    for args in (("simulate", root / "clean", "--take", "--cameras", 6, "--frames", 400, "--seed", 7),
                 ("simulate", root / "after", "--take", "--cameras", 6, "--frames", 300, "--seed", 7,
                  "--move", "cam2:0:0.3:2")):
        r = wandcal(*args)
        assert r.returncode == 0, r.stderr
    return root


@pytest.mark.long  # decision 0111: a shorter test of the same path stays in the default suite
def test_a_knocked_camera_is_named_and_resolved(root, watch_knock):
    r = wandcal("watch", root / "result.json", root / "knock", "--write", root / "updated.json")
    assert r.returncode == 1, r.stderr
    assert "cam2: knocked at frame 3" in r.stdout
    doc = json.loads((root / "updated.json").read_text())
    assert doc["watch"]["resolved"] == ["cam2"] and doc["watch"]["standing"] == str(root / "result.json")
    entry = next(c for c in doc["cameras"] if c["id"] == "cam2")
    assert entry["verdict"]["level"] == "good" and entry["center_std_mm"] > 0
    r = wandcal("watch", root / "updated.json", root / "after", "--json")  # it reads back, and explains the moved rig
    assert r.returncode == 0, r.stdout + r.stderr
    assert json.loads(r.stdout)["moved"] == []
    knock, r = watch_knock  # the same result and take, --json --write (tests/service/conftest.py)
    assert r.returncode == 1 and json.loads(r.stdout)["moved"], r.stderr  # stdout stays the JSON report alone
    assert f"wrote {knock.parent / 'knock_updated.json'}" in r.stderr


def test_a_clean_take_exits_0(root):
    r = wandcal("watch", root / "result.json", root / "clean", "--json")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert doc["moved"] == [] and all(c["status"] == "ok" for c in doc["cameras"])


def test_bad_takes_exit_2_with_a_clear_message(root, tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "rig.json").write_text((root / "clean" / "rig.json").read_text())
    (empty / TAKE_FILE).write_text("frame,camera,u,v\n")
    r = wandcal("watch", root / "result.json", empty)
    assert r.returncode == 2 and "holds no blobs" in r.stderr
    lines = (root / "clean" / TAKE_FILE).read_text().splitlines()
    one = tmp_path / "one"
    one.mkdir()
    (one / "rig.json").write_text((root / "clean" / "rig.json").read_text())
    (one / TAKE_FILE).write_text("\n".join([lines[0], *[x for x in lines[1:] if ",cam1," in x]]) + "\n")
    r = wandcal("watch", root / "result.json", one)
    assert r.returncode == 2 and "blobs in only 1 camera(s) (cam1)" in r.stderr
    other = tmp_path / "other"  # cameras of the same ids and lenses, placed elsewhere
    r = wandcal("simulate", other, "--take", "--cameras", 6, "--frames", 200, "--seed", 8)
    assert r.returncode == 0
    r = wandcal("watch", root / "result.json", other)
    assert r.returncode == 2 and "does not fit" in r.stderr, r.stdout + r.stderr
    renamed = tmp_path / "renamed"  # a camera the result does not have
    renamed.mkdir()
    (renamed / "rig.json").write_text((root / "clean" / "rig.json").read_text().replace('"cam6"', '"cam9"'))
    (renamed / TAKE_FILE).write_text((root / "clean" / TAKE_FILE).read_text().replace(",cam6,", ",cam9,"))
    r = wandcal("watch", root / "result.json", renamed)
    assert r.returncode == 2 and "not of this result's rig" in r.stderr and "cam9" in r.stderr
    r = wandcal("watch", root / "result.json", tmp_path / "missing")
    assert r.returncode == 2 and "not a folder" in r.stderr
