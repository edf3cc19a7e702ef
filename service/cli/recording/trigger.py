"""``wandcal trigger-emulator``: the strobe trigger's protocol spoken on a new pseudo-terminal, for
tests and for trying ``wandcal capture`` without the board."""

from __future__ import annotations

import argparse

from wandcal.service.cli.support.args import arg_whole

MAX_DEVICE_US = 2**32 - 1  # the trigger's microsecond counter is 32 bits and wraps


def register(sub: argparse._SubParsersAction, *, arguments: bool = True) -> None:
    p = sub.add_parser("trigger-emulator", help="emulate the strobe trigger on a pseudo-terminal",
                       description="Speak wandcal-trigger/1 on a new pseudo-terminal; prints its path (alone on the "
                                   "first line of stdout) and the wandcal capture command that uses it.")
    p.set_defaults(run=run_emulator)
    if arguments:
        p.add_argument("--vanish-after", type=arg_whole(0), default=None, metavar="N",
                       help="close the terminal after N pulses, as if the board were unplugged (default: never)")
        p.add_argument("--start-us", type=arg_whole(0, MAX_DEVICE_US), default=0, metavar="US",
                       help=f"device clock at start, 0 to {MAX_DEVICE_US} (near the top tests the wrap; default 0)")


def run_emulator(args) -> int:
    import sys

    from wandcal.drivers.trigger_emulator import serve_pty

    def announce(path: str) -> None:
        """The path alone on stdout's first line (for scripts), then what to do with it on stderr."""
        print(path, flush=True)
        print(f"the strobe trigger emulator listens on {path}; in another terminal, record with it:\n"
              f"  wandcal capture --camera 'sim://?cameras=4' --trigger {path} --static-frames 100 --frames 3000 "
              "--out out/live\n(Ctrl-C here stops the emulator)", file=sys.stderr, flush=True)

    return serve_pty(vanish_after=args.vanish_after, start_us=args.start_us, announce=announce)
