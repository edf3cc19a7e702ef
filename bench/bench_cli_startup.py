"""Start-up cost of the command line: ``wandcal --version``, ``wandcal --help``, ``wandcal calibrate
--help`` and a whole ``wandcal calibrate`` of a simulated 8 x 1500 capture, each a fresh process.

    python bench/bench_cli_startup.py --runs 9 --python before=/venv-a/bin/python --python after=/venv-b/bin/python

Each ``--python NAME=EXE`` is an interpreter with one checkout of wandcal installed (default: this
one). Every command runs under every interpreter in turn, round-robin, so other jobs on a shared
machine weigh on every column alike; the table gives the medians side by side and their ratio
to the first interpreter's (docs/benchmarks.md, "Command-line start-up").
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _time(cmd: list[str], cwd: Path) -> float:
    started = time.perf_counter()
    done = subprocess.run(cmd, cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, check=False)
    seconds = time.perf_counter() - started
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({done.returncode}): {done.stderr[-400:]}")
    return seconds


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=7)
    parser.add_argument("--python", action="append", metavar="NAME=EXE", default=[])
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    pythons = dict(item.split("=", 1) for item in args.python) or {"this": sys.executable}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        first = next(iter(pythons.values()))
        subprocess.run([first, "-m", "wandcal.service.cli", "simulate", "sim", "--cameras", "8", "--frames", "1500"],
                       cwd=work, check=True, stdout=subprocess.DEVNULL)
        cli = ["-m", "wandcal.service.cli"]
        cases = {
            "python -c pass (the interpreter alone)": ["-c", "pass"],
            "wandcal --version": [*cli, "--version"],
            "wandcal --help": [*cli, "--help"],
            "wandcal calibrate --help": [*cli, "calibrate", "--help"],
            "wandcal calibrate (8 x 1500, ba, whole command)": [*cli, "calibrate", "sim", "--quiet", "--out", "r.json"],
        }
        times = {case: {name: [] for name in pythons} for case in cases}
        for _ in range(args.runs):
            for case, cmd in cases.items():
                for name, exe in pythons.items():
                    times[case][name].append(_time([exe, *cmd], work))
    load = os.getloadavg()[0]
    names = list(pythons)
    print(f"runs={args.runs}, medians in seconds; load average {load:.1f} at the end")
    header = ["command", *names, *(f"{n} / {names[0]}" for n in names[1:])]
    print("| " + " | ".join(header) + " |")
    print("|---" * len(header) + "|")
    for case, by_name in times.items():
        med = {n: statistics.median(ts) for n, ts in by_name.items()}
        cells = [case, *(f"{med[n]:.3f}" for n in names), *(f"{med[n] / med[names[0]]:.2f}x" for n in names[1:])]
        print("| " + " | ".join(cells) + " |")
    if args.json:
        args.json.write_text(json.dumps({"pythons": pythons, "load": load, "times": times}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
