"""Judging's cost before and after (issue 31): the judgement's CPU seconds inside `calibrate`, this
tree beside a base tree, in one run.

Two measurements, each in its own process per tree (the base's ``wandcal`` put first on
PYTHONPATH, bench/bench_against_base.py's ``namespace``), base and head interleaved round by round
(base first in even rounds, so that a drift of the shared host's load falls on both alike), BLAS on
one thread, CPU seconds (``time.process_time``: the machine is shared, its wall seconds are not the
code's):

- a clean simulated 16 x 2500 rig (the Peers bench's, 0.3 px, L-frame), `calibrate` in-process
  ``--repeats`` times, the judgement (``calib.run.calibrate.judge``) timed inside each run; the
  share is judge / calibrate per run, its median per process, then the median over the rounds.
  Goal (issue 31): judging adds at most 10% to `calibrate`.
- broken real sessions of four cameras (bench/real_faults.py's sessions and injectors: a knock,
  a focal length 8% long, or one frame late, on the first target camera of Brown 1 and Brown 2),
  `calibrate` and its judgement. Goal: a broken 4-camera real session is judged in at most 3 s.

Usage: python bench/bench_judging_cost.py --base /tmp/base=LABEL [--rounds 5] [--repeats 5] [--no-write]
(the base: ``git archive <commit> | tar -x -C /tmp/base``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from bench.bench_against_base import namespace  # noqa: E402
from bench.common import judge_timed, publish  # noqa: E402

GOAL_SHARE = 0.10  # issue 31: judging adds at most this to calibrate
SHARE = "share"
GOAL_REAL_S = 3.0  # issue 31: a broken 4-camera real session judged within this
# (session, fault family, the case label's start): 4 cameras each
REAL_CASES = tuple((session, family, label) for session in ("brown1", "brown2")
                   for family, label in (("knock", "knocked"), ("focal", "focal +8%"), ("timing whole", "late 1")))


def clean_share(repeats: int) -> dict:
    """This process's tree on the clean 16 x 2500 rig: medians of ``repeats`` runs of calibrate CPU
    seconds, the judgement's and their ratio."""
    from wandcal.calib.sim.simulate import simulate_capture

    sim = simulate_capture(16, 2500, 0.3, 0.0, True, 1)
    totals = []
    with judge_timed() as (pipeline, inside):
        pipeline.calibrate(sim.rig, sim.wand, sim.static)  # the judgement's modules imported, not timed
        inside.clear()
        for _ in range(repeats):
            start = time.process_time()
            pipeline.calibrate(sim.rig, sim.wand, sim.static)
            totals.append(time.process_time() - start)
    return {"calibrate": float(np.median(totals)), "judge": float(np.median(inside)),
            "share": float(np.median(np.array(inside) / np.array(totals)))}


def real_broken(repeats: int) -> dict:
    """This process's tree on :data:`REAL_CASES`: per case, medians of ``repeats`` runs of calibrate
    CPU seconds and the judgement's, the cameras, and the faults the verdict named."""
    from bench import real_faults as rf

    out = {}
    sessions = {key: found[0] for key in sorted({key for key, _, _ in REAL_CASES}) if (found := rf.load_sessions([key]))}
    with judge_timed() as (_, inside):
        for name, family, label in REAL_CASES:
            session = sessions.get(name)
            if session is None:
                continue
            case = next(c for c in rf.cases(session)
                        if c.family == family and c.camera == session.targets[0] and c.label.startswith(label))
            broken = rf.inject(session, case, [])
            totals, judged, named = [], [], []
            for _ in range(repeats + 1):
                inside.clear()
                start = time.process_time()
                doc = rf.calibrated(broken).to_json()
                totals.append(time.process_time() - start)
                judged.append(sum(inside))
                named = sorted(f"{f['kind']} {f['camera']}" for f in doc["verdict"]["faults"])
            out[f"{session.name}|{case.label}"] = {"cameras": len(session.rig.cameras), "calibrate": float(np.median(totals[1:])),
                                           "judge": float(np.median(judged[1:])), "named": named}
    return out


def child(env: dict, what: str, repeats: int) -> dict:
    """One measurement in a fresh process of the tree ``env`` puts first on PYTHONPATH."""
    done = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--child", what, "--repeats", str(repeats)],
                          check=True, capture_output=True, env=env, cwd=REPO)
    return json.loads(done.stdout.decode().strip().splitlines()[-1])


def _rounds(envs: dict, what: str, rounds: int, repeats: int) -> dict[str, list[dict]]:
    got: dict[str, list[dict]] = {"base": [], "head": []}
    for r in range(rounds):
        for name in ("base", "head") if r % 2 == 0 else ("head", "base"):
            got[name].append(child(envs[name], what, repeats))
            print(what, name, r, json.dumps(got[name][-1])[:200], flush=True)
    return got


def _share_rows(got: dict[str, list[dict]], label: str) -> list[str]:
    med = {name: {k: float(np.median([g[k] for g in runs])) for k in ("calibrate", "judge", "share")}
           for name, runs in got.items()}
    rows = []
    for name in ("base", "head"):
        m = med[name]
        rows.append(f"| {label if name == 'base' else 'this tree'} | {m['calibrate']:.3f} | {m['judge']:.4f} | "
                    f"{100 * m['share']:.1f}% | {' '.join(f'{100 * g[SHARE]:.1f}' for g in got[name])} |")
    rows.append(f"| head / base | | {med['head']['judge'] / med['base']['judge']:.2f} | | |")
    return rows


def _real_rows(got: dict[str, list[dict]], label: str) -> list[str]:
    rows = []
    for key in got["head"][0]:
        session, case = key.split("|")
        for name in ("base", "head"):
            runs = [g[key] for g in got[name] if key in g]
            rows.append(f"| {session} ({runs[0]['cameras']} cameras), {case} | {label if name == 'base' else 'this tree'} | "
                        f"{np.median([r['calibrate'] for r in runs]):.2f} | {np.median([r['judge'] for r in runs]):.2f} | "
                        f"{', '.join(runs[0]['named']) or '-'} |")
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", help="TREE=LABEL: the base tree (a git archive of the commit) and what it is")
    ap.add_argument("--rounds", type=int, default=5, help="processes per tree, interleaved")
    ap.add_argument("--repeats", type=int, default=5, help="calibrate runs per process")
    ap.add_argument("--real-rounds", type=int, default=3, help="processes per tree for the real sessions")
    ap.add_argument("--child", choices=("share", "real"), help=argparse.SUPPRESS)
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    if args.child:
        print(json.dumps(clean_share(args.repeats) if args.child == "share" else real_broken(args.repeats)))
        return 0
    if not args.base:
        ap.error("--base TREE=LABEL is required")
    tree, _, label = args.base.partition("=")
    label = label or tree
    pinned = dict.fromkeys(("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"), "1")
    with tempfile.TemporaryDirectory() as tmp:
        trees = {"base": namespace(Path(tree).resolve(), Path(tmp) / "base"), "head": namespace(REPO, Path(tmp) / "head")}
        envs = {name: dict(os.environ, PYTHONPATH=str(path), **pinned) for name, path in trees.items()}
        shares = _rounds(envs, "share", args.rounds, args.repeats)
        real = _rounds(envs, "real", args.real_rounds, 1)
    load = os.getloadavg()
    body = (f"CPU seconds (BLAS on one thread), this tree beside the base in one run, interleaved; host load average "
            f"{load[0]:.1f} at the end (2 cores, shared). Clean 16 x 2500 rig: {args.rounds} processes a tree, "
            f"{args.repeats} calibrate runs each; medians (the share's per process, then over processes). Goal "
            f"(issue 31): judging adds at most {GOAL_SHARE:.0%} to `calibrate`.\n\n"
            "| tree | `calibrate` CPU (s) | judgement CPU (s) | judgement / `calibrate` | per process (%) |\n"
            "|---|---|---|---|---|\n" + "\n".join(_share_rows(shares, label)) + "\n\n"
            f"Broken real sessions (bench/real_faults.py's injectors, the first target camera), {args.real_rounds} "
            f"processes a tree, the median of each process's second run (the first imports). Goal: judged in at most "
            f"{GOAL_REAL_S:g} s.\n\n"
            "| session, fault | tree | `calibrate` CPU (s) | judgement CPU (s) | faults named |\n|---|---|---|---|---|\n"
            + "\n".join(_real_rows(real, label)))
    return publish("Judging's cost before and after", body, not args.no_write)


if __name__ == "__main__":
    sys.exit(main())
