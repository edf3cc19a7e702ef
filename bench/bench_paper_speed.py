"""`--method paper`'s rounds on the acceptance rig (8 x 1500) and others of its kind (seeds): this tree's
code against an earlier revision's, side by side, with and without jumps along the tail.

The problem is the one `--method paper` solves in bench_acceptance.py: the pipeline runs to the
outlier pass (its robust `ba`), and `refine_paper` is then timed alone, in a fresh process per run
(one per code, jump cap and repeat, the codes alternating so the machine's load falls on both
alike; decisions 0033, 0045). Reports rounds, jumps, CPU seconds (medians over the repeats; the
machine is shared, so wall seconds are listed but say little), CPU and interior-point iterations a
round, each answer's largest camera-centre distance from the first row's of its seed, and from the fixed
point on the LP basis it ends on, where that basis holds (decision 0052), and its cameras' error against
the simulator's truth after the best rigid alignment (as bench_acceptance.py's "aligned"; decision 0060).

Usage: python bench/bench_paper_speed.py [--caps 10,0] [--before REV] [--repeats 1] [--seeds 11] [--no-write]
"""

from __future__ import annotations

import argparse
import os
import pickle
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


class _Caught(Exception):
    """refine_paper's arguments, caught on their way in."""


def paper_problem(seed: int) -> tuple:
    """refine_paper's arguments in the acceptance run of ``--method paper``, then the true camera
    centres (N, 3), metres, in the simulator's frame."""
    from wandcal.calib.run.calibrate import calibrate
    from wandcal.calib.run.options import CalibrationOptions
    from wandcal.calib.sim.simulate import simulate_capture
    from wandcal.calib.solve import paper

    sim = simulate_capture(8, 1500, noise_px=0.3, seed=seed)
    real = paper.refine_paper

    def catch(*args, **kwargs):
        raise _Caught(args)

    paper.refine_paper = catch
    try:
        calibrate(sim.rig, sim.wand, sim.static, options=CalibrationOptions(method="paper"))
    except _Caught as caught:
        return (*caught.args[0], sim.truth.centers)
    finally:
        paper.refine_paper = real
    raise SystemExit("--method paper did not reach refine_paper")


def child(tree: str, problem_file: str, cap: float, out: str) -> int:
    """One timed ``refine_paper`` with the code of ``tree`` (a checkout whose ``wandcal`` package
    is imported): (R, t, info, CPU s, wall s, LP iterations) pickled to ``out``."""
    sys.path.insert(0, tree)
    from wandcal.calib.geometry import camera_centers, kabsch
    from wandcal.calib.solve import paper

    R, t, wand, problem, fixed, up, truth = pickle.loads(Path(problem_file).read_bytes())
    paper.JUMP_CAP = cap
    iterations = []
    real_lp_step = paper.lp_step

    def counted(*args, **kwargs):
        solved = real_lp_step(*args, **kwargs)
        iterations.append(solved[2].iterations)
        return solved

    paper.lp_step = counted
    cpu, wall = time.process_time(), time.perf_counter()
    R1, t1, W1, info = paper.refine_paper(R, t, wand, problem, fixed, up)
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    apart = None  # um from the fixed point on the basis the last LP named (decision 0052), untimed
    try:  # a tree before decision 0052 has none
        from wandcal.calib.solve.paper_fixed_point import fixed_point_on_basis
    except ImportError:
        fixed_point_on_basis = None
    if fixed_point_on_basis is not None:
        found = fixed_point_on_basis(R1, t1, W1.reshape(-1, 3), problem, fixed, up,
                                     paper.height_pairs(R, t, wand.reshape(-1, 3), up))
        if found is not None:
            apart = float(np.linalg.norm(camera_centers(found[0], found[1]) - camera_centers(R1, t1), axis=1).max()) * 1e6
    C = camera_centers(R1, t1)
    Ra, ta, _ = kabsch(C, truth)
    error = np.linalg.norm(C @ Ra.T + ta - truth, axis=1) * 1000  # mm, after the best rigid alignment
    Path(out).write_bytes(pickle.dumps((C, info, cpu, wall, sum(iterations), apart,
                                        (float(error.max()), float(np.sqrt(np.mean(error**2)))))))
    return 0


def _export(rev: str, into: Path) -> str:
    """``rev``'s tree extracted under ``into`` (git archive), for its ``wandcal`` package."""
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    return str(into)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--caps", default="10,0", help="jump caps to run (0: no jumps)")
    ap.add_argument("--before", default=None, help="a git revision to run side by side with this tree")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--seeds", default="11", help="the simulated rigs' seeds (11: the acceptance rig)")
    ap.add_argument("--no-write", action="store_true")
    ap.add_argument("--child", nargs=4, metavar=("TREE", "PROBLEM", "CAP", "OUT"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        return child(args.child[0], args.child[1], float(args.child[2]), args.child[3])
    sys.path.insert(0, str(ROOT))
    from bench.common import publish

    with tempfile.TemporaryDirectory() as tmp:
        codes = {"this tree": str(ROOT)}
        if args.before:
            (Path(tmp) / "before").mkdir()
            codes = {args.before: _export(args.before, Path(tmp) / "before"), **codes}
        runs: dict = {}
        for seed in (int(s) for s in args.seeds.split(",")):
            problem_file = Path(tmp) / f"problem{seed}.pkl"
            problem = paper_problem(seed)
            problem_file.write_bytes(pickle.dumps(problem[:6] + problem[-1:]))
            for repeat in range(args.repeats):
                for cap in (float(c) for c in args.caps.split(",")):
                    for name, tree in codes.items():
                        out = Path(tmp) / "run.pkl"
                        subprocess.run([sys.executable, __file__, "--child", tree, str(problem_file), str(cap),
                                        str(out)], check=True)
                        runs.setdefault((seed, name, cap), []).append(pickle.loads(out.read_bytes()))
                        print(seed, name, cap, repeat, runs[(seed, name, cap)][-1][1:], flush=True)
    return publish("Seed paper's method: rounds at 8 x 1500", _table(runs, args), not args.no_write)


def _table(runs: dict, args) -> str:
    """The section's text: one row a (seed, code, jump cap), medians over the repeats."""
    rows, first = [], {}
    for (seed, name, cap), done in runs.items():
        centres, info, _, _, lp_iterations, fixed_apart, (err_max, err_rms) = done[-1]
        first.setdefault(seed, centres)
        cpu, wall = np.median([d[2] for d in done]), np.median([d[3] for d in done])
        rounds = info["iterations"]
        apart = float(np.linalg.norm(centres - first[seed], axis=1).max()) * 1e6
        rows.append(f"| {seed} | {name} | {cap:g} | {info['status']} | {rounds} | {info['jumps']} | {cpu:.1f} | "
                    f"{cpu / rounds:.3f} | {lp_iterations / rounds:.1f} | {wall:.0f} | {apart:.1f} | "
                    f"{'none' if fixed_apart is None else f'{fixed_apart:.3f}'} | {err_max:.3f} / {err_rms:.3f} |")
    return "\n".join([
        f"`refine_paper` alone on the problem `--method paper` solves in bench_acceptance.py (8 x 1500, 0.3 px; seed "
        f"11 is the acceptance rig; after the outlier pass), a fresh process a run, medians of {args.repeats} "
        f"repeat(s); load average {os.getloadavg()[0]:.1f} at the end. `apart`: the largest camera-centre distance "
        "from the seed's first row's answer; `fixed point`: from the answer to the fixed point on the basis its last "
        "LP named (paper_fixed_point.fixed_point_on_basis), none where that basis does not hold there (the rounds "
        "still creep from basis to basis); `error`: the cameras' centres against the simulator's truth after the "
        "best rigid alignment, max / RMS (bench_acceptance.py's \"aligned\").",
        "",
        "| seed | code | jump cap | status | rounds | jumps | CPU s | CPU s a round | LP iterations a round | wall s "
        "| apart (um) | fixed point (um) | error (mm) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
        *rows,
    ])


if __name__ == "__main__":
    sys.exit(main())
