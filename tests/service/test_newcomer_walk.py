"""A newcomer's mistakes beyond issue 35's list (docs/decisions/0046-a-newcomers-walk.md): each one
ends with the README's exit code and a message that names the file, option or camera and says what
to do. The interruption of the capture on a real terminal: tests/capture/test_capture_interrupt.py."""

from __future__ import annotations

import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from wandcal.service.cli import main
from wandcal.service.cli.support import exits

REPO = Path(__file__).resolve().parents[2]
SHORT = ["--frames", "10", "--images", "none", "--no-guidance", "--quiet"]
EMULATOR_START_S = 60.0  # a loaded 2-core machine: the child imports the package first


def run(argv: list[str], capsys) -> tuple[int, str]:
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own errors exit from inside the parse
        code = exc.code
    captured = capsys.readouterr()
    return code, captured.err + captured.out


@pytest.fixture(scope="module")
def sim(tmp_path_factory) -> Path:
    """A 4-camera points-level capture (and a 3-camera one beside it, of another rig)."""
    root = tmp_path_factory.mktemp("walk")
    assert main(["simulate", str(root / "sim"), "--cameras", "4", "--frames", "60"]) == 0
    assert main(["simulate", str(root / "three"), "--cameras", "3", "--frames", "60", "--seed", "5"]) == 0
    return root


def test_capture_out_naming_a_file(tmp_path, capsys):
    (tmp_path / "wand.csv").write_text("frame,camera,u,v\n")
    code, err = run(["capture", "--camera", "sim://?cameras=2", *SHORT, "--out", str(tmp_path / "wand.csv")], capsys)
    assert code == exits.BAD_INPUT and "is a file, not a folder" in err and "Errno" not in err, err


def test_a_mistyped_camera_url_option_is_not_ignored(tmp_path, capsys):
    code, err = run(["capture", "--camera", "sim://?cameras=3&sed=2", *SHORT, "--out", str(tmp_path / "c")], capsys)
    assert code == exits.BAD_INPUT and "unknown option 'sed'; did you mean seed?" in err, err
    assert not (tmp_path / "c").exists()


def test_a_rig_json_of_other_cameras_at_capture(sim, tmp_path, capsys):
    code, err = run(["capture", "--camera", "sim://?cameras=4", "--rig", str(sim / "three" / "rig.json"), *SHORT,
                     "--out", str(tmp_path / "c")], capsys)
    assert code == exits.BAD_INPUT and "do not match rig.json" in err and "--rig" in err, err


def test_a_rig_json_of_another_capture_in_the_folder(sim, tmp_path, capsys):
    folder = tmp_path / "mixed"
    shutil.copytree(sim / "sim", folder)
    shutil.copy(sim / "three" / "rig.json", folder / "rig.json")
    code, err = run(["calibrate", str(folder), "--quiet"], capsys)
    assert code == exits.BAD_INPUT and "unknown camera id 'cam4'" in err and "of another capture" in err, err


def test_a_file_given_for_the_capture_folder_names_its_folder(sim, capsys):
    code, err = run(["calibrate", str(sim / "sim" / "wand.csv")], capsys)
    assert code == exits.BAD_INPUT and f"the folder that holds it: {sim / 'sim'}" in err, err


def test_report_of_a_file_that_is_no_result(sim, tmp_path, capsys):
    code, err = run(["report", str(sim / "sim" / "wand.csv"), "--out", str(tmp_path / "rep")], capsys)
    assert code == exits.BAD_INPUT and "not a JSON result file" in err and "wandcal calibrate" in err, err


def test_a_data_directory_that_cannot_be_made(tmp_path, capsys):
    import socket

    (tmp_path / "taken").write_text("a file where the folder should go")
    with socket.socket() as probe:  # a port free now, so the port's own check passes
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    code, err = run(["serve", "--port", str(port), "--data-dir", str(tmp_path / "taken" / "data")], capsys)
    assert code == exits.BAD_INPUT and "--data-dir" in err and "Errno" not in err, err


def test_a_camera_folder_missing_from_the_image_level_is_named(tmp_path, capsys):
    out = tmp_path / "img"
    assert run(["capture", "--camera", "sim://?cameras=3&seed=2", "--frames", "10", "--no-guidance", "--quiet",
                "--out", str(out)], capsys)[0] == exits.OK
    shutil.rmtree(out / "frames" / "cam2")
    code, text = run(["detect", str(out), "--quiet"], capsys)
    assert code == exits.OK and "frames/cam2/ is missing or empty" in text, text


def test_end_of_input_at_the_pause_without_a_terminal_names_no_pause(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(sys, "stdin", open("/dev/null"))  # noqa: SIM115 - closed with the test's process
    code, err = run(["capture", "--camera", "sim://?cameras=2&seed=4", "--static-frames", "3", *SHORT,
                     "--out", str(tmp_path / "c")], capsys)
    assert code == exits.INTERRUPTED and "give --no-pause" in err and "kept 0 wand sets and 3 static sets" in err, err


def test_an_interrupted_calibrate_says_nothing_was_written(sim, capsys, monkeypatch):
    import wandcal.service.cli.calibrate as calibrate_command

    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(calibrate_command, "run_calibrate", interrupted)
    code, err = run(["calibrate", str(sim / "sim")], capsys)
    assert code == exits.INTERRUPTED and "no result was written" in err, err


def test_the_trigger_emulator_says_what_to_do_with_its_path():
    proc = subprocess.Popen([sys.executable, "-m", "wandcal.service.cli", "trigger-emulator"], cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        path = proc.stdout.readline().strip()  # alone on the first line, for scripts
        deadline = time.monotonic() + EMULATOR_START_S
        said = ""
        while "Ctrl-C" not in said and time.monotonic() < deadline:
            said += proc.stderr.readline()
    finally:
        proc.terminate()
        proc.wait(10)
    assert path.startswith("/dev/")
    assert f"--trigger {path}" in said and "wandcal capture" in said, said
