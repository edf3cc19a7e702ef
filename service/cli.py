"""The ``wandcal`` command line.

Each command lives with the layer it drives; a module contributes commands through a
``register(subparsers)`` function listed in :data:`COMMAND_MODULES`.
"""

from __future__ import annotations

import argparse
import importlib
import sys

COMMAND_MODULES = (
    "service.commands",  # simulate, calibrate, demo
    "capture.cli",  # capture, detect, trigger-emulator
    "service.serve",  # serve
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="wandcal", description="Capture and calibrate multi-camera motion-capture rigs with a wand."
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name != name:
                raise
            continue  # a layer that is not built yet contributes no commands
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    from calib.errors import CalibrationError

    args = build_parser().parse_args(argv)
    try:
        return int(args.run(args) or 0)
    except CalibrationError as exc:
        print(f"wandcal {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"wandcal {args.command}: error: {exc}", file=sys.stderr)
        return 3
    except KeyboardInterrupt:
        print(f"wandcal {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
