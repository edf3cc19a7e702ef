"""The whole `wandcal calibrate` process of this tree beside another tree's (a base commit), on
the same simulated synchronised two-marker captures, runs interleaved: did a change slow it?

The captures are the Peers bench's (bench/bench_peers.py's `calibrate_process`: `wandcal simulate`
with an L-frame, then `wandcal calibrate --quiet`), made once by the base tree. Each round runs
base then head, or head then base (alternating, so that a drift of the shared host's load falls
on both alike); BLAS is pinned to one thread as the solvers pin it. Reported: medians of the
rounds of wall and CPU seconds of the process, and the solver's own seconds from result.json.

Usage: python bench/bench_against_base.py --base /tmp/h23base=LABEL [--base ...] [--rigs 8x1500,16x2500]
[--outliers 0,0.08] [--rounds 5] [--command calibrate|check|guidance] [--no-write]
(the base: ``git archive <commit> | tar -x -C /tmp/h23base``).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from bench.common import publish  # noqa: E402

PACKAGES = ("calib", "capture", "drivers", "service")  # the folders pyproject maps into the wandcal namespace
GOAL = 0.05  # issue 23: no more than 5% slower on a synchronised two-marker capture


def namespace(tree: Path, into: Path) -> Path:
    """A folder whose ``wandcal`` package is ``tree``'s (a regular package of symlinks, found on
    PYTHONPATH before the editable install's namespace)."""
    pkg = into / "wandcal"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    for name in PACKAGES:
        (pkg / name).symlink_to(tree / name)
    return into


def run(env: dict, folder: Path, out: Path, command: str = "calibrate") -> tuple[float, float, float]:
    """(wall s, CPU s, solver s) of one `wandcal COMMAND` process on ``folder``: calibrate writes
    ``out``; check judges ``folder`` against the standing result beside ``out`` (standing.json);
    guidance prints the folder's wanding guidance (their solver column is 0)."""
    argv = {"calibrate": ["calibrate", str(folder), "--quiet", "--out", str(out)],
            "check": ["check", str(out.parent / "standing.json"), str(folder)],
            "guidance": ["guidance", str(folder)]}[command]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "wandcal.service.cli", *argv], check=False, capture_output=True,
                          env=env, cwd=REPO)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode not in ((0,) if command == "calibrate" else (0, 1)):
        raise SystemExit(f"{command} exited {done.returncode}: {done.stderr.decode()[-500:]}")
    cpu = after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime
    return wall, cpu, float(json.loads(out.read_text())["solver"]["seconds"]) if command == "calibrate" else 0.0


def compare(rig: str, outliers: float, envs: dict, tmp: Path, rounds: int, command: str = "calibrate") -> list[str]:
    """The table rows of one rig (``CxF``) at one outlier fraction: base and head, interleaved."""
    cameras, frames = rig.split("x")
    folder = tmp / f"{rig}-{outliers}"
    subprocess.run([sys.executable, "-m", "wandcal.service.cli", "simulate", str(folder), "--cameras", cameras,
                    "--frames", frames, "--outliers", str(outliers)], check=True, capture_output=True, env=envs["base"],
                   cwd=REPO)
    if command == "check":  # the standing result: the base's calibration of the same capture
        run(envs["base"], folder, tmp / "standing.json")
    got: dict[str, list] = {"base": [], "head": []}
    for r in range(rounds):
        for name in ("base", "head") if r % 2 == 0 else ("head", "base"):
            got[name].append(run(envs[name], folder, tmp / f"{name}.json", command))
            print(rig, outliers, name, r, " ".join(f"{v:.3f}" for v in got[name][-1]), flush=True)
    med = {name: np.median(np.array(v), axis=0) for name, v in got.items()}
    ratio = med["head"] / med["base"]
    return [f"| {rig} | {outliers:.0%} | {name} | {med[name][0]:.3f} | {med[name][1]:.3f} | {med[name][2]:.3f} | "
            + (f"{ratio[0]:.3f}, {ratio[1]:.3f} |" if name == "head" else "|") for name in ("base", "head")]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", required=True, action="append",
                    help="TREE=LABEL: a base tree (a git archive of the commit) and what it is; repeat for several")
    ap.add_argument("--rigs", default="8x1500,16x2500")
    ap.add_argument("--outliers", default="0", help="outlier fractions, each simulated on every rig (the Peers bench: 0 and 0.08)")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--command", choices=("calibrate", "check", "guidance"), default="calibrate",
                    help="the command timed (check: against the base's calibration of the same capture)")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    pinned = dict.fromkeys(("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"), "1")
    rows = ["| base | rig | outliers | tree | process wall (s) | process CPU (s) | solver (s) | head / base (wall, CPU) |",
            "|---|---|---|---|---|---|---|---|"]
    for spec in args.base:
        tree, _, label = spec.partition("=")
        with tempfile.TemporaryDirectory() as tmp:
            trees = {"base": namespace(Path(tree).resolve(), Path(tmp) / "base"), "head": namespace(REPO, Path(tmp) / "head")}
            envs = {name: dict(os.environ, PYTHONPATH=str(path), **pinned) for name, path in trees.items()}
            for rig in args.rigs.split(","):
                for outliers in map(float, args.outliers.split(",")):
                    rows += [f"| {label or tree} " + row for row in compare(rig, outliers, envs, Path(tmp), args.rounds, args.command)]
    if args.command != "calibrate":
        body = (f"The whole `wandcal {args.command}` process on the Peers bench's simulated synchronised two-marker "
                f"captures (with an L-frame; check: against the base's calibration of the same capture), this tree "
                f"against each base, {args.rounds} rounds interleaved, medians; BLAS on one thread.\n\n" + "\n".join(rows))
        return publish(f"Issue 32: `{args.command}` before and after", body, not args.no_write)
    body = (f"The whole `wandcal calibrate` process on the Peers bench's simulated synchronised two-marker captures "
            f"(with an L-frame), this tree against each base, {args.rounds} rounds interleaved (base first in even "
            f"rounds), medians; BLAS on one thread. Goal (issue 23): head no more than {GOAL:.0%} slower. A base of "
            f"this tree itself (A/A) shows the shared host's noise; a base older than the last merge from main also "
            f"differs by every other issue merged since.\n\n" + "\n".join(rows))
    return publish("Issue 23: multi-marker and planar wands against the two-marker speed", body, not args.no_write)


if __name__ == "__main__":
    sys.exit(main())
