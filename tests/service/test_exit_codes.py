"""One exit-code table for every command (README "Exit codes", service/cli/support/exits.py): each
command's error paths end with the code the table gives, its own usage and, for a mistyped option or
choice, a suggestion. Exits 1 and 3 of check and calibrate --require: tests/service/test_cli_check.py
and test_cli.py; 3 for a trigger that vanishes mid-capture: tests/capture/test_capture_pty.py; 130:
tests/capture/test_capture_interrupt.py (real signals on a pseudo-terminal)."""

from __future__ import annotations

import argparse
import re
import socket
from pathlib import Path

import pytest

from wandcal.service.cli import COMMANDS, build_parser, main
from wandcal.service.cli.support import exits

REPO = Path(__file__).resolve().parents[2]

# command -> arguments that are bad input, checked after the parse (a path that is not there)
MISSING = {
    "simulate": ["simulate", "{tmp}/sim", "--cameras", "3", "--frames", "20", "--seed", "x"],
    "calibrate": ["calibrate", "{tmp}/nope"],
    "check": ["check", "{tmp}/nope.json", "{tmp}/nope"],
    "demo": ["demo", "--cameras", "1"],
    "capture": ["capture", "--camera", "gopro://1", "--frames", "5", "--out", "{tmp}/cap"],
    "detect": ["detect", "{tmp}/nope"],
    "trigger-emulator": ["trigger-emulator", "--vanish-after", "-1"],
    "import": ["import", "easywand", "{tmp}/nope.mat", "--out", "{tmp}/imp"],
    "guidance": ["guidance", "{tmp}/nope"],
    "serve": ["serve", "--config", "{tmp}/nope.toml", "--data-dir", "{tmp}/data"],
    "export": ["export", "{tmp}/nope.json", "--format", "dlt-csv", "--out", "{tmp}/e.csv"],
    "report": ["report", "{tmp}/nope.json", "--out", "{tmp}/rep"],
    "watch": ["watch", "{tmp}/nope.json", "{tmp}/nope"],
}


# command -> what it requires, so the parse reaches the mistyped option
REQUIRED = {"simulate": ["o"], "calibrate": ["c"], "check": ["r.json", "c"], "detect": ["c"], "guidance": ["c"],
            "capture": ["--camera", "sim://", "--frames", "1", "--out", "o"], "import": ["easywand", "s.mat", "--out", "o"],
            "export": ["r.json", "--format", "dlt-csv", "--out", "o"], "report": ["r.json", "--out", "o"],
            "watch": ["r.json", "t"]}


def test_every_command_has_a_bad_input_case():
    assert set(MISSING) == set(COMMANDS)


def run(argv: list[str], capsys) -> tuple[int, str]:
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own errors exit from inside the parse
        code = exc.code
    return code, capsys.readouterr().err


@pytest.mark.parametrize("command", list(COMMANDS))
def test_bad_input_exits_2_naming_the_command(command, tmp_path, capsys):
    argv = [a.format(tmp=tmp_path) for a in MISSING[command]]
    code, err = run(argv, capsys)
    assert code == exits.BAD_INPUT, err
    assert f"wandcal {command}: error: " in err and "Traceback" not in err


def some_long_option(command: str) -> str:
    parser = build_parser([command])
    own = parser.commands[command]
    if command == "import":
        own = next(a for a in own._actions if isinstance(a, argparse._SubParsersAction)).choices["easywand"]
    return next(s for a in own._actions for s in a.option_strings
                if s.startswith("--") and s != "--help" and len(s) > 5 and not isinstance(a, argparse._HelpAction))


@pytest.mark.parametrize("command", list(COMMANDS))
def test_a_mistyped_option_shows_the_commands_usage_and_what_was_meant(command, capsys):
    option = some_long_option(command)
    typo = option[:3] + option[4] + option[3] + option[5:]  # two letters swapped: --method -> --mtehod, no prefix
    code, err = run([command, *REQUIRED.get(command, []), typo, "1"], capsys)
    assert code == exits.BAD_INPUT
    assert f"usage: wandcal {command} {'easywand ' if command == 'import' else ''}" in err, err
    assert f"did you mean {option}?" in err, err


def test_the_readme_example_of_a_mistyped_option(capsys):
    code, err = run(["calibrate", "base", "--methd", "lp"], capsys)
    assert code == exits.BAD_INPUT
    assert "usage: wandcal calibrate" in err and "unrecognized arguments: --methd lp; did you mean --method?" in err


@pytest.mark.parametrize("argv, meant", [
    (["calibrat", "x"], "calibrate"),
    (["calibrate", "x", "--method", "lpp"], "lp"),
    (["export", "r.json", "--format", "dlt_csv", "--out", "x"], "dlt-csv"),
])
def test_a_mistyped_command_or_choice_says_what_was_meant(argv, meant, capsys):
    code, err = run(argv, capsys)
    assert code == exits.BAD_INPUT and f"did you mean {meant}?" in err, err


def test_capture_into_a_folder_with_a_capture_exits_2(tmp_path, capsys):
    out = tmp_path / "cap"
    short = ["capture", "--camera", "sim://?cameras=2&seed=4", "--frames", "10", "--images", "none", "--no-guidance",
             "--out", str(out)]
    assert run(short, capsys)[0] == exits.OK
    code, err = run(short, capsys)
    assert code == exits.BAD_INPUT and "already holds a complete capture of 10 wand sets" in err
    assert "--overwrite" in err and f"wandcal calibrate {out}" in err


@pytest.mark.parametrize("extra, words", [
    (["--trigger", "/dev/ttyACM97"], "plug in the trigger board"),
    (["--trigger", "serial:///dev/nope/ttyUSB0"], "wandcal trigger-emulator"),
])
def test_capture_without_a_board_exits_2_before_writing(tmp_path, capsys, extra, words):
    out = tmp_path / "cap"
    code, err = run(["capture", "--camera", "sim://?cameras=2", "--frames", "10", "--out", str(out), *extra], capsys)
    assert code == exits.BAD_INPUT and words in err, err
    assert not out.exists()


def test_serve_on_a_taken_port_exits_2(tmp_path, capsys):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        code, err = run(["serve", "--port", str(port), "--data-dir", str(tmp_path / "data")], capsys)
    assert code == exits.BAD_INPUT and f"127.0.0.1:{port}" in err and "--port" in err, err


def test_serve_on_a_public_address_without_a_token_exits_2(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("WANDCAL_TOKEN", raising=False)
    code, err = run(["serve", "--host", "0.0.0.0", "--data-dir", str(tmp_path / "data")], capsys)
    assert code == exits.BAD_INPUT and "WANDCAL_TOKEN" in err


@pytest.mark.parametrize("command", list(COMMANDS))
def test_every_help_ends_with_the_table_and_shows_every_default(command, capsys):
    with pytest.raises(SystemExit):
        main([command, "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert " ".join(exits.TABLE.split()) in text
    own = build_parser([command]).commands[command]
    for action in own._actions:
        flags = (argparse._HelpAction, argparse._StoreTrueAction, argparse._StoreFalseAction, argparse._StoreConstAction)
        if action.option_strings and not action.required and not isinstance(action, flags):
            assert "default" in (action.help or ""), f"{command} {action.option_strings[-1]}: no default in its help"


def test_serve_help_lists_the_environment_it_reads(capsys):
    from wandcal.service.settings import Settings

    with pytest.raises(SystemExit):
        main(["serve", "--help"])
    out = capsys.readouterr().out
    for name in ["WANDCAL_CONFIG", *(f"WANDCAL_{n.upper()}" for n in Settings.model_fields)]:
        assert name in out
    assert "WANDCAL_REPLAY_ROOT" in out and "WANDCAL_TOKEN" in out


def test_the_readme_table_is_the_one_the_help_gives():
    readme = (REPO / "README.md").read_text()
    rows = dict(re.findall(r"^\| (\d+) \| (.+) \|$", readme, re.M))
    assert sorted(map(int, rows)) == [exits.OK, exits.FAULT, exits.BAD_INPUT, exits.NO_ANSWER, exits.INTERRUPTED]
    for code in rows:
        assert f" {code} " in f" {exits.TABLE} "


def test_an_empty_wand_csv_is_reported_as_empty(tmp_path, capsys):
    out = tmp_path / "cap"
    assert main(["simulate", str(out), "--cameras", "3", "--frames", "20"]) == 0
    (out / "wand.csv").write_text("")
    code, err = run(["calibrate", str(out), "--quiet"], capsys)
    assert code == exits.BAD_INPUT and "wand.csv: the file is empty" in err, err
