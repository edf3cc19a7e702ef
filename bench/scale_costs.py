"""bench_scale.py's part 7 (``--parts costs``, "Scale: judgement, guidance, check and sync on every
shape"): the commands that follow or accompany a calibration, each a whole process beside
`wandcal calibrate` of the same capture, in CPU seconds, and each one's share of that calibrate
(issue 33: each at most 20%). With ``--base CHECKOUT``, that checkout's processes ("before") beside
this one's ("after"), alternated round by round on the same captures.

Run through bench/bench_scale.py (``--parts costs --cost-rigs ... [--base CHECKOUT]``).
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from bench.whole_process import checkout_view, child_env, simulate, warm_bytecode

REPO = Path(__file__).resolve().parents[1]
EVERY_SHAPE_128 = "ring:128x3000,dome:128x3000,tiers:128x3000,hallway:128x3000"  # issue 33's judging-cost rigs
PARTS = ("calibrate", "judgement", "check", "guidance", "sync auto")
# what `check` and `guidance` import beyond calibrate's modules (whole_process.warm_bytecode's): compiled before
# any round is timed, so the first round's check does not pay for compiling them
WARM_IMPORTS = ("import wandcal.service.standing_result, wandcal.calib.judge.bumps, wandcal.service.cli.recording.guidance, "
                "wandcal.calib.run.guidance, wandcal.calib.solve.sync")


def _costs_round(folder: Path, tmp: Path, failed: dict[str, str], view: Path | None = None) -> dict[str, float]:
    """One round of :func:`part_costs` on one capture: CPU seconds (user + system) of calibrate
    under bench/stage_timer.py (the whole process, and its judgement), then `check` of its result,
    `guidance`, and `calibrate --sync auto` less this round's calibrate. A command that refuses the
    capture (exit 2) gives NaN and its reason in ``failed``. ``view``: another checkout's code,
    first on the path (None: this one)."""
    out, stages = tmp / "result.json", tmp / "stages.json"

    def cpu(*argv: str, module: str = "wandcal.service.cli") -> float:
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        done = subprocess.run([sys.executable, "-m", module, *argv], capture_output=True, text=True, cwd=REPO,
                              env=child_env(view), check=False)
        if done.returncode == 2:  # refused: the run measured nothing, and the row says why
            failed[" ".join(argv[:1] + argv[-2:])] = done.stderr.strip().splitlines()[-1]
            return float("nan")
        if done.returncode != 0:
            raise RuntimeError(f"{argv}: exit {done.returncode}: {done.stderr[-2000:]}")
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)

    run: dict[str, float] = {}
    run["calibrate"] = cpu(str(stages), "calibrate", str(folder), "--quiet", "--out", str(out), module="bench.stage_timer")
    run["judgement"] = float(json.loads(stages.read_text())["judgement"])
    run["check"] = cpu("check", str(out), str(folder))
    run["guidance"] = cpu("guidance", str(folder))
    run["sync auto"] = cpu("calibrate", str(folder), "--quiet", "--out", str(tmp / "sync.json"), "--sync", "auto") - run["calibrate"]
    return run


def _warm(view: Path | None) -> None:
    """Compile every module the timed commands import (``view``'s or this checkout's), untimed."""
    warm_bytecode(view)
    subprocess.run([sys.executable, "-c", WARM_IMPORTS], check=True, cwd=REPO, env=child_env(view))


def part_costs(rigs: list[str], repeats: int, base: Path | None = None) -> str:
    """The commands that follow or accompany a calibration, each a whole process beside `wandcal
    calibrate` of the same capture, alternated run by run, CPU seconds (the machine is shared), on
    each rig: `wandcal check` of the result against the capture, `wandcal guidance`, `calibrate
    --sync auto` (its cost: the difference), and the judgement inside calibrate (bench/stage_timer.py's
    timer around it, in the same process as the calibrate timed). Medians of the rounds, each share
    of that round's calibrate. With ``base`` (another checkout), its round and this one's alternated
    on each rig, columns "before" and "after"."""
    per: dict[tuple[str, str], dict[str, list[float]]] = {}
    load = [os.getloadavg()[0]]
    failed: dict[str, str] = {}
    with tempfile.TemporaryDirectory() as tmp:
        variants: dict[str, Path | None] = {"": None}
        if base is not None:
            # after: this bench's own checkout on the path too (not whatever the editable install maps), so a
            # frozen copy of a branch can be measured while its worktree moves on
            variants = {"before": checkout_view(base, Path(tmp) / "view"), "after": checkout_view(REPO, Path(tmp) / "head")}
        folders = {}
        for rig in rigs:
            shape, size = rig.split(":") if ":" in rig else (None, rig)
            cameras, frames = (int(v) for v in size.split("x"))
            folders[rig] = Path(tmp) / rig.replace(":", "-")
            simulate(folders[rig], cameras, frames, shape=shape)
            for name in variants:
                per[(rig, name)] = {part: [] for part in PARTS}
        for view in variants.values():
            _warm(view)
        for _ in range(repeats):
            for rig in rigs:  # the rigs alternated too: the load drifts over a run
                for name, view in variants.items():
                    for part, value in _costs_round(folders[rig], Path(tmp), failed, view).items():
                        per[(rig, name)][part].append(value)
                    load.append(os.getloadavg()[0])
                    print(rig, name, {k: round(v[-1], 2) for k, v in per[(rig, name)].items()}, flush=True)
    return _costs_table(per, [(rig, name) for rig in rigs for name in variants], repeats, load, failed, base)


def _costs_table(per: dict[tuple[str, str], dict[str, list[float]]], cols: list[tuple[str, str]], repeats: int,
                 load: list[float], failed: dict[str, str], base: Path | None) -> str:
    """:func:`part_costs`'s section: the table of medians and shares, how it was measured, every run."""
    def label(col: tuple[str, str]) -> str:
        return col[0] + (f": {col[1]}" if col[1] else "")

    rows = ["| command or part | " + " | ".join(f"{label(c)}: CPU s (share)" for c in cols) + " |", "|---|" + "---|" * len(cols)]
    for part in PARTS:
        cells = []
        for col in cols:
            values = per[col][part]
            shares = [v / c for v, c in zip(values, per[col]["calibrate"])]
            cells.append(f"{np.median(values):.2f} ({np.median(shares):.0%}; max {max(shares):.0%})")
        rows.append(f"| {part} | " + " | ".join(cells) + " |")
    runs = "\n".join(f"- {label(col)}: " + "; ".join(f"{k} {', '.join(f'{v:.2f}' for v in vs)}" for k, vs in per[col].items())
                     for col in cols)
    against = (" Before: the checkout given by --base, on PYTHONPATH; after: this one; alternated round by round on the "
               "same capture." if base is not None else "")
    return (f"Each rig a `wandcal simulate --shape` capture (0.3 px, 2% outliers, L-frame, seed 1); each command a whole "
            f"process (Python start-up included), the commands and the rigs alternated, {repeats} rounds; CPU seconds, "
            f"user + system, because the machine is shared (1-minute load average {min(load):.1f}-{max(load):.1f} on its "
            f"{os.cpu_count()} cores). calibrate: the whole process under bench/stage_timer.py; judgement: that process's "
            "`_judgement` step (its timer, no profiler); check: the result against the capture it came from; sync auto: "
            "`calibrate --sync auto` less plain `calibrate` of the same round. Share: of the same round's calibrate, "
            f"the median over the rounds, and the largest.{against}\n\n" + "\n".join(rows)
            + "\n\nGoal (issue 33): each at most 20% of the calibrate time.\n\nThe runs (CPU s):\n\n" + runs
            + "".join(f"\n\n`wandcal {k}` refused the capture: {v}" for k, v in failed.items()))
