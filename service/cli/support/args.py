"""argparse types for the command line's numeric options: a value out of range stops the command
with exit code 2 and a message that gives the range (argparse names the option).

Every numeric option of every subcommand uses one of these (tests/service/test_cli_numbers.py
goes through them all). They are named ``arg_*`` because they parse a command-line word; the checks
of a JSON document's values (``capture/result_file.py``'s ``number``/``whole``,
``capture/rig_file.py``'s ``positive_number``) are another thing.
"""

from __future__ import annotations

import argparse
import math

MAX_SEED = 2**32 - 1  # numpy's seeds are unsigned; a bound keeps them printable and portable


def arg_whole(low: int, high: int | None = None):
    """A whole number from ``low`` to ``high`` (inclusive; no upper bound when None)."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
        if value < low or (high is not None and value > high):
            raise argparse.ArgumentTypeError(_range(low, high, value))
        return value

    parse.__name__ = "whole number"  # argparse's "invalid <name> value" when the type raises otherwise
    return parse


def arg_number(low: float, high: float | None = None, low_open: bool = False, high_open: bool = False):
    """A finite number from ``low`` to ``high``; ``low_open``/``high_open`` exclude the end."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        above = value > low if low_open else value >= low
        below = high is None or (value < high if high_open else value <= high)
        if not (math.isfinite(value) and above and below):
            raise argparse.ArgumentTypeError(_range(low, high, text, low_open, high_open))
        return value

    parse.__name__ = "number"
    return parse


arg_positive = arg_number(0, low_open=True)  # a finite number > 0: a length, a focal length, a sigma goal


def _range(low, high, got, low_open: bool = False, high_open: bool = False) -> str:
    lower = f"more than {low:g}" if low_open else f"at least {low:g}"
    if high is None:
        return f"must be {lower}, got {got}"
    upper = f"less than {high:g}" if high_open else f"at most {high:g}"
    return f"must be {lower} and {upper}, got {got}"
