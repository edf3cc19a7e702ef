"""The ``wandcal`` command line.

Each command lives with the layer it drives; a module contributes commands through a
``register(subparsers)`` function listed in :data:`COMMAND_MODULES`.
"""

from __future__ import annotations

import argparse
import importlib
import sys

COMMAND_MODULES = {
    "wandcal.service.cli.calibrate": ("simulate", "calibrate", "demo", "check"),
    "wandcal.service.cli.capture": ("capture", "detect", "trigger-emulator"),
    "wandcal.service.cli.import_": ("import",),
    "wandcal.service.cli.guidance": ("guidance",),
    "wandcal.service.cli.serve": ("serve",),
    "wandcal.service.cli.export": ("export",),
    "wandcal.service.cli.report": ("report",),
}
# commands that compute once and exit: their process keeps the memory it frees (service/cli/batch_memory.py)
BATCH_COMMANDS = frozenset({"simulate", "calibrate", "demo", "check", "detect", "import", "export", "report"})


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The parser; when ``argv`` names a command, only that command's module is imported (so
    ``wandcal calibrate`` loads neither the web framework nor the camera drivers)."""
    parser = argparse.ArgumentParser(
        prog="wandcal", description="Capture and calibrate multi-camera motion-capture rigs with a wand."
    )
    parser.add_argument("--version", action=_Version, nargs=0, help="print the version and exit")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    command = next((a for a in (argv or []) if not a.startswith("-")), None)
    modules = [m for m, names in COMMAND_MODULES.items() if command in names] or list(COMMAND_MODULES)
    for name in modules:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name != name:
                raise
            continue  # a layer that is not built yet contributes no commands
        module.register(sub)
    return parser


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


def main(argv: list[str] | None = None) -> int:
    """Run one command. ``argv`` None: this is the ``wandcal`` process itself (its arguments are
    ``sys.argv``), so a batch command also takes the batch memory policy; a caller that passes
    ``argv`` (a test, another program) keeps its own process's."""
    from wandcal.calib.errors import CalibrationError

    args = build_parser(sys.argv[1:] if argv is None else argv).parse_args(argv)
    if argv is None and args.command in BATCH_COMMANDS:
        from wandcal.service.cli.batch_memory import keep_freed_memory

        keep_freed_memory()
    try:
        return int(args.run(args) or 0)
    except CalibrationError as exc:
        print(f"wandcal {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        from wandcal.drivers.registry import CameraUrlError  # bad input, not a device fault

        print(f"wandcal {args.command}: error: {exc}", file=sys.stderr)
        return 2 if isinstance(exc, CameraUrlError) else 3
    except KeyboardInterrupt:
        print(f"wandcal {args.command}: interrupted", file=sys.stderr)
        return 130

