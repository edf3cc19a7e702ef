"""The ``wandcal`` command line: one module a command in this package (the commands used at the rig
while recording in :mod:`wandcal.service.cli.recording`), listed in :data:`COMMANDS`;
what several commands share (argparse types, the progress line, the summary, what they read beside
a capture, the batch memory policy) is in :mod:`wandcal.service.cli.support`.

Each command module has ``register(sub, *, arguments=True)``, which adds its parser and, with
``arguments``, its options. Registration imports nothing heavy: a command's numerical code (and the
constants its options quote, such as the methods' names) is imported when its arguments are added
or when it runs, so ``wandcal --help`` and ``wandcal --version`` start without NumPy or the web
framework, and ``wandcal calibrate`` loads neither the web framework nor the camera drivers.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Mapping
from typing import NoReturn

from wandcal.service.cli.support import exits

# command -> its module, in the order ``wandcal --help`` lists them
COMMANDS = {
    "simulate": "wandcal.service.cli.simulate",
    "calibrate": "wandcal.service.cli.calibrate",
    "check": "wandcal.service.cli.check",
    "watch": "wandcal.service.cli.watch",
    "demo": "wandcal.service.cli.demo",
    "capture": "wandcal.service.cli.recording.capture",
    "detect": "wandcal.service.cli.recording.detect",
    "trigger-emulator": "wandcal.service.cli.recording.trigger",
    "import": "wandcal.service.cli.import_",
    "guidance": "wandcal.service.cli.recording.guidance",
    "serve": "wandcal.service.cli.serve",
    "export": "wandcal.service.cli.export",
    "report": "wandcal.service.cli.report",
}
# commands that compute once and exit: their process keeps the memory it frees (service/cli/support/batch_memory.py)
BATCH_COMMANDS = frozenset({"simulate", "calibrate", "demo", "check", "watch", "detect", "import", "export", "report"})


class _Formatter(argparse.HelpFormatter):
    """argparse's formatter, except that a description's or epilog's own line breaks stay (the
    exit-code table, the environment a command reads); each line is wrapped on its own."""

    def _fill_text(self, text, width, indent):
        return "\n".join(super(_Formatter, self)._fill_text(line, width, indent) for line in text.splitlines())


class _Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose errors suggest what was meant ("did you mean --method?"):
    Python 3.11's argparse does not. The command parsers are made of this class too; the top
    one keeps them in ``commands`` (name -> parser)."""

    commands: Mapping[str, argparse.ArgumentParser]

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", _Formatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> NoReturn:
        super().error(message + suggestion(self, message))


def suggestion(parser: argparse.ArgumentParser, message: str) -> str:
    """"; did you mean X?" for an argparse error about a mistyped option or choice, else ""."""
    import difflib
    import re

    if message.startswith("unrecognized arguments: "):
        words = [w.split("=")[0] for w in message.split(": ", 1)[1].split() if w.startswith("--")]
        known = [s for s in parser._option_string_actions if s.startswith("--")]
    else:
        choice = re.search(r"invalid choice: '([^']*)' \(choose from (.*)\)$", message)
        if choice is None:
            return ""
        words, known = [choice.group(1)], re.findall(r"'([^']*)'", choice.group(2))
    meant = [m for w in words for m in difflib.get_close_matches(w, known, n=1, cutoff=0.6)]
    return f"; did you mean {' or '.join(meant)}?" if meant else ""


def build_parser(argv: list[str] | None = None) -> _Parser:
    """The parser. When ``argv`` names a command, only that command's module is imported; when it
    names none, ``--help`` lists every command without its options, and ``--version`` needs none;
    ``argv`` None builds every command with all its options (the tests that walk them). Each
    command's help ends with the exit-code table (:data:`wandcal.service.cli.support.exits.TABLE`)."""
    parser = _Parser(prog="wandcal", description="Capture and calibrate multi-camera motion-capture rigs with a wand.",
                     epilog=exits.TABLE)
    parser.add_argument("--version", action=_Version, nargs=0, help="print the version and exit")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    parser.commands = sub.choices
    command = next((a for a in (argv or []) if not a.startswith("-")), None)
    if argv is not None and command is None and not {"-h", "--help"} & set(argv):
        return parser  # --version, or no command at all (argparse says one is required): nothing to list
    named = [command] if command in COMMANDS else list(COMMANDS)
    for name in named:
        importlib.import_module(COMMANDS[name]).register(sub, arguments=argv is None or name == command)
        own = sub.choices[name]
        own.epilog = f"{own.epilog}\n{exits.TABLE}" if own.epilog else exits.TABLE
    return parser


def parse(argv: list[str] | None) -> argparse.Namespace:
    """The arguments; an option the command does not have is reported with that command's usage
    (argparse would show the top-level one) and a suggestion."""
    parser = build_parser(sys.argv[1:] if argv is None else argv)
    args, extra = parser.parse_known_args(argv)
    if extra:
        own: argparse.ArgumentParser = parser.commands.get(args.command, parser)
        for action in own._actions:  # a command with commands of its own (import FORMAT): the one chosen
            if isinstance(action, argparse._SubParsersAction) and getattr(args, action.dest, None) in action.choices:
                own = action.choices[getattr(args, action.dest)]
        own.error(f"unrecognized arguments: {' '.join(extra)}")
    return args


class _Version(argparse.Action):
    """``--version``: the installed distribution's version, looked up only when asked (so the
    metadata machinery stays out of every other command's start-up)."""

    def __call__(self, parser, namespace, values, option_string=None):
        from importlib.metadata import PackageNotFoundError, version

        try:
            text = version("wandcal")
        except PackageNotFoundError:
            text = "unknown (not installed; pip install -e .)"
        print(f"wandcal {text}")
        parser.exit()


# what an interrupted command leaves, for the commands that write their files only at their end
KEPT_WHEN_INTERRUPTED = {
    "calibrate": "no result was written (an earlier one is as it was); run it again to calibrate",
    "detect": "wand.csv and static.csv are as they were; run it again to detect",
}


def main(argv: list[str] | None = None) -> int:
    """Run one command. ``argv`` None: this is the ``wandcal`` process itself (its arguments are
    ``sys.argv``), so a batch command also takes the batch memory policy; a caller that passes
    ``argv`` (a test, another program) keeps its own process's."""
    args = parse(argv)
    if argv is None and args.command in BATCH_COMMANDS:
        from wandcal.service.cli.support.batch_memory import keep_freed_memory

        keep_freed_memory()
    from wandcal.calib.errors import CalibrationError  # after the parse: --help and --version load no NumPy

    try:
        return int(args.run(args) or 0)
    except (CalibrationError, exits.InputError) as exc:
        print(f"wandcal {args.command}: error: {exc}", file=sys.stderr)
        return exits.BAD_INPUT
    except OSError as exc:
        from wandcal.drivers.registry import CameraUrlError  # bad input, not a device fault

        print(f"wandcal {args.command}: error: {exc}", file=sys.stderr)
        return exits.BAD_INPUT if isinstance(exc, (CameraUrlError, *exits.PATH_ERRORS)) else exits.NO_ANSWER
    except KeyboardInterrupt:
        kept = KEPT_WHEN_INTERRUPTED.get(args.command)
        print(f"wandcal {args.command}: interrupted" + (f"; {kept}" if kept else ""), file=sys.stderr)
        return exits.INTERRUPTED

