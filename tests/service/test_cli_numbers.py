"""Every numeric option of every subcommand refuses values out of its range: exit 2, a message
naming the option, no traceback. A second test walks the parser so that a new numeric option
without a row here fails."""

from __future__ import annotations

import argparse
import subprocess
import sys

import pytest

from wandcal.service.cli import build_parser, main

pytestmark = pytest.mark.usefixtures("patient_stall_limit")  # in-process recordings on a loaded box

# the arguments each command needs besides the option under test
BASE = {
    "simulate": ["simulate", "out"],
    "demo": ["demo"],
    "calibrate": ["calibrate", "cap"],
    "capture": ["capture", "--camera", "sim://?cameras=2", "--frames", "5", "--out", "o"],
    "detect": ["detect", "cap"],
    "import easywand": ["import", "easywand", "s.mat", "--out", "o"],
    "import argus": ["import", "argus", "p.csv", "--profile", "p.txt", "--wand-length", "0.5", "--out", "o"],
    "import svoboda": ["import", "svoboda", "folder", "--out", "o"],
    "import anipose": ["import", "anipose", "calibration.toml", "--out", "o"],
    "import cameras": ["import", "cameras", "cameras.toml", "--out", "o"],
    "guidance": ["guidance", "cap"],
    "trigger-emulator": ["trigger-emulator"],
    "serve": ["serve"],
}
NOT_NUMBERS = ("nan", "inf", "x")
# (command, option, values it must refuse); NOT_NUMBERS are refused by every float option too
CASES = [
    ("simulate", "--cameras", ["1", "0", "-3", "257", "2.5"]),
    ("simulate", "--size", ["2", "121", "-1", *NOT_NUMBERS]),
    ("simulate", "--max-k1", ["-0.01", "0.11", *NOT_NUMBERS]),
    ("simulate", "--frames", ["9", "0", "-1", "100001"]),
    ("simulate", "--noise", ["-0.1", "101", *NOT_NUMBERS]),
    ("simulate", "--outliers", ["-0.1", "1", "2", *NOT_NUMBERS]),
    ("simulate", "--seed", ["-1", "4294967296", "1.5"]),
    ("simulate", "--floor", ["2", "0", "10001", "1.5", *NOT_NUMBERS]),
    ("simulate", "--drop", ["4", "-1", "10001", "2.5", *NOT_NUMBERS]),
    ("simulate", "--markers", ["0", "201", "1.5"]),
    ("simulate", "--spurious", ["-0.1", "51", *NOT_NUMBERS]),
    ("simulate", "--dropped", ["-0.1", "1", *NOT_NUMBERS]),
    ("simulate", "--drift", ["-1", "100001", "1.5"]),
    ("simulate", "--intrinsics-error", ["-1", "21", "21%", "x%", *NOT_NUMBERS]),
    ("simulate", "--principal-error", ["-1", "201", *NOT_NUMBERS]),
    ("simulate", "--distortion-error", ["-0.1", "0.6", "0.01,0.6", "0.01,0.01,0.01", *NOT_NUMBERS]),
    ("simulate", "--intrinsics-seed", ["-1", "4294967296", "1.5"]),
    ("demo", "--cameras", ["1", "-3", "65"]),
    ("demo", "--frames", ["0", "-5", "100001"]),
    ("demo", "--noise", ["-1", *NOT_NUMBERS]),
    ("demo", "--outliers", ["1", "-0.5", *NOT_NUMBERS]),
    ("demo", "--seed", ["-1", "x"]),
    ("calibrate", "--max-rounds", ["0", "-3", "10001", "2.5"]),
    ("calibrate", "--lp-time-limit", ["0", "-1", "86401", *NOT_NUMBERS]),
    ("capture", "--frames", ["0", "-1", "10000001"]),
    ("capture", "--static-frames", ["-1", "100001"]),
    ("capture", "--rate", ["0", "-100", "2001", *NOT_NUMBERS]),
    ("capture", "--wand-length", ["0", "-0.5", "11", *NOT_NUMBERS]),
    ("capture", "--target-mm", ["0", "-1", *NOT_NUMBERS]),
    ("capture", "--min-coverage", ["-0.1", "1.5", *NOT_NUMBERS]),
    ("capture", "--threshold", ["-1", "65536", "x"]),
    ("capture", "--seed-ratio", ["0.5", "-1", *NOT_NUMBERS]),
    ("capture", "--min-area", ["0", "-4", "x"]),
    ("capture", "--max-area", ["0", "-4", "x"]),
    ("capture", "--min-roundness", ["-0.1", "1.1", *NOT_NUMBERS]),
    ("capture", "--connectivity", ["0", "6", "x"]),
    ("detect", "--workers", ["0", "-2", "257"]),
    ("detect", "--threshold", ["-1", "65536"]),
    ("detect", "--seed-ratio", ["0", *NOT_NUMBERS]),
    ("detect", "--min-area", ["0", "-1"]),
    ("detect", "--max-area", ["0", "-1"]),
    ("detect", "--min-roundness", ["-1", "2", *NOT_NUMBERS]),
    ("detect", "--connectivity", ["2", "x"]),
    ("import easywand", "--wand-length", ["0", "-1", *NOT_NUMBERS]),
    ("import easywand", "--height", ["0", "-1", "65536"]),
    ("import argus", "--wand-length", ["0", "-0.3", *NOT_NUMBERS]),
    ("import argus", "--height", ["0", "-1"]),
    ("import svoboda", "--focal-px", ["0", "-1", *NOT_NUMBERS]),
    ("import anipose", "--min-likelihood", ["-0.1", "1.5", *NOT_NUMBERS]),
    ("import cameras", "--wand-length", ["0", "-1", *NOT_NUMBERS]),
    ("import cameras", "--size", ["0x480", "640", "-640x480", "axb"]),
    ("calibrate", "--sync-max-offset", ["0", "-1", "10001", "2.5"]),
    ("guidance", "--target-mm", ["0", "-1", *NOT_NUMBERS]),
    ("guidance", "--min-coverage", ["-1", "2", *NOT_NUMBERS]),
    ("trigger-emulator", "--vanish-after", ["-1", "x"]),
    ("trigger-emulator", "--start-us", ["-1", "4294967296"]),
    ("serve", "--port", ["0", "-1", "65536", "x"]),
    ("serve", "--workers", ["-1", "65", "x"]),
]
# options whose type parses something other than a number (lists, policies, models)
NOT_NUMERIC = {"--refine-intrinsics", "--solve-only", "--images", "--background"}


@pytest.mark.parametrize(("command", "option", "values"), CASES, ids=[f"{c} {o}" for c, o, _ in CASES])
def test_out_of_range_exits_2_naming_the_option(command, option, values, capsys):
    for value in values:
        with pytest.raises(SystemExit) as stop:
            main([*BASE[command], f"{option}={value}"])
        assert stop.value.code == 2, (option, value)
        err = capsys.readouterr().err
        assert f"argument {option}" in err and "Traceback" not in err, (option, value, err)


def test_simulate_past_the_default_ring_needs_a_shape(tmp_path, capsys):
    """The default ring holds 64 cameras; --shape rigs 256, each in its own size range."""
    assert main(["simulate", str(tmp_path / "a"), "--cameras", "65"]) == 2
    assert "--shape ring" in capsys.readouterr().err
    assert main(["simulate", str(tmp_path / "b"), "--shape", "hallway", "--size", "5"]) == 2
    assert "give 10.0 to 120.0 m" in capsys.readouterr().err
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_every_numeric_option_has_a_case():
    covered = {(c, o) for c, o, _ in CASES}
    found = set()

    def walk(parser: argparse.ArgumentParser, prefix: str) -> None:
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    walk(sub, f"{prefix} {name}".strip())
            elif action.type is not None and action.option_strings:
                option = max(action.option_strings, key=len)
                if option not in NOT_NUMERIC and getattr(action.type, "__name__", "") not in ("Path", "str"):
                    found.add((prefix, option))

    walk(build_parser(), "")
    assert found - covered == set(), "numeric options without a test case"


def test_max_rounds_zero_is_refused_before_any_solve(tmp_path):
    """The report's case, as a process: exit 2 at once, not 245 rounds."""
    r = subprocess.run([sys.executable, "-m", "wandcal.service.cli", "calibrate", str(tmp_path), "--method", "paper",
                        "--max-rounds", "0"], capture_output=True, text=True, timeout=120, check=False)
    assert r.returncode == 2 and "--max-rounds" in r.stderr and "at least 1" in r.stderr


def test_options_of_other_methods_are_refused(tmp_path):
    from tests.service.conftest import simulated_capture

    folder, _ = simulated_capture(tmp_path / "cap", cameras=3, frames=50, seed=2)
    for extra in (["--max-rounds", "5"], ["--method", "lp", "--max-rounds", "5"], ["--lp-time-limit", "3"]):
        assert main(["calibrate", str(folder), "--quiet", *extra]) == 2
        assert not (folder / "result.json").exists()


@pytest.mark.parametrize(("url", "extra", "words"), [
    ("sim://?cameras=100000", [], "cameras must be at least 2 and at most 32"),
    ("sim://?cameras=2&frames=1000000000000", [], "frames must be at least 1 and at most 360000"),
    ("sim://?cameras=2&drop=cam2:0-999999999999", [], "must name frames from 0 to 459999"),
    ("sim://?cameras=2&drop=cam2:9-3", [], "the first one first"),
    ("sim://?cameras=2&noise=inf", [], "noise must be at least 0"),
    ("sim://?cameras=2&seed=-1", [], "seed must be at least 0"),
    ("sim://?cameras=2", ["--frames", "400000"], "at most 100000 static and 360000 wand frames"),
])
def test_simulated_rig_limits_exit_2_before_anything_is_written(tmp_path, capsys, url, extra, words):
    out = tmp_path / "cap"
    code = main(["capture", "--camera", url, "--frames", "5", *extra, "--images", "none", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and words in err and "Traceback" not in err, err
    assert not out.exists()
