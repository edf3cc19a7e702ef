"""Stadium-scale rigs (issue 22): the whole `wandcal calibrate` process on 64 and 128 cameras beside
COLMAP's bundle adjuster with a Cauchy loss, a point-heavy rig, and where the process's time goes
as the rig grows.

Part 1 ("Scale: the whole command beside COLMAP"): each rig simulated by `wandcal simulate` (0.3
px noise, 2% gross outliers, an L-frame), the whole `wandcal calibrate` process timed (Python
start-up included; peak RSS its own VmHWM; centre error against the simulator's truth after a
similarity alignment), beside COLMAP-Cauchy's solve of the same rig as in bench_peers.py (labelled
at the truth, started 1 deg / 3 cm off, the Cauchy scale the one `ba` ends with, its solve alone),
in the same run; medians of the repeats.

Part 2 ("Scale: point-heavy rig"): 12 cameras, a 1500-frame wand capture with its L-frame, and
15,000 frames of one marker each seen by every camera it falls in (~180k point observations).

Part 3 ("Scale: stages"): the process under cProfile at 16, 32, 64 and 128 cameras x 3000 frames,
each stage's cumulative time (attributed by caller, so a stage's nested calls are not counted
twice) and its growth exponent: the least-squares slope of log(seconds) against log(cameras).

Part 4 ("Scale: guidance"): the live guidance update at 64 x 3000. Part 5 ("Scale: small rigs before
and after", only with --base): 8 x 1500 and 16 x 2500 against another checkout, alternated. Part 6
("Scale: lp beside ba", --parts methods): the whole process with `--method lp` and `--method ba`. Part 7
(--parts costs, "Scale: judgement, guidance, check and sync on every shape"): those commands beside calibrate, --cost-rigs
(bench/scale_costs.py; with --base CHECKOUT, that checkout's beside this one's).
Part 8 (--parts where, "Scale: where the whole command's CPU goes (sparse shapes)"): each stage's CPU seconds
in a whole process on --where-rigs, by timers around the stages' functions (bench/stage_timer.py), not cProfile;
with --base CHECKOUT, that checkout's process beside this one's, alternated run by run on the same capture.

How a whole process is run, timed and profiled, and the captures it reads: bench/whole_process.py.

Usage: python bench/bench_scale.py [--repeats 3] [--parts peers,points,stages,guidance,methods,costs,where] [--rigs 64x3000,128x3000]
    [--where-rigs ring:128x3000,tiers:128x3000]
    [--stage-cameras 16,32,64,128] [--stage-shape ring] [--colmap-repeats 1] [--base CHECKOUT] [--no-write]
    --rigs ring:64x3000,dome:128x3000 (SHAPE:CAMSxFRAMES): rigs of calib/sim/shapes.py, section "Scale: every shape beside COLMAP"
    e.g. git archive 3925791 | tar -x -C /tmp/base && python bench/bench_scale.py --parts regression --base /tmp/base
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from bench.bench_peers import run_ba, run_colmap, scene  # noqa: E402
from bench.common import write_section  # noqa: E402
from bench.scale_costs import EVERY_SHAPE_128, part_costs  # noqa: E402
from bench.whole_process import (  # noqa: E402
    OUTLIERS,
    STAGES,
    add_points,
    alternated,
    centre_error_mm,
    checkout_view,
    child_env,
    run_process,
    simulate,
    stage_seconds,
    warm_bytecode,
)

STAGE_FRAMES = 3000
REGRESSION_RIGS = "8x1500:0,8x1500:0.08,16x2500:0"  # the Peers bench's whole-command rigs
POINT_RIG = (12, 1500, 15000)  # cameras, wand frames, point frames


def colmap_cauchy(cameras: int, frames: int, shape: str | None = None) -> tuple[float, float, str, float]:
    """COLMAP-Cauchy's solve seconds, its centre error (mm), iterations and the CPU seconds of this
    process over the solve (Ceres's threads included) on the bench_peers scene (of ``shape``)."""
    from bench.bench_peers import centre_error_mm as peer_error

    sim, labelled, setup = scene(cameras, frames, OUTLIERS, shape=shape)
    scale = run_ba(sim, labelled, setup)[3]
    cpu = time.process_time()
    R, t, iterations, seconds = run_colmap(sim, labelled, setup, scale)
    cpu = time.process_time() - cpu
    return seconds, peer_error(R, t, sim), str(iterations), cpu


def part_peers(rigs: list[str], repeats: int, colmap_repeats: int) -> str:
    import resource

    rows = ["| rig | outliers | `wandcal calibrate` process: wall / CPU (s) | process CPU: user + system (s) "
            "| COLMAP-Cauchy solve: wall / CPU (s) | COLMAP's solves, wall (s) | ratio: wall / CPU "
            "| centre error wandcal / COLMAP (mm) | process peak RSS (MB) |",
            "|---|---|---|---|---|---|---|---|---|"]
    for rig in rigs:
        shape, size = rig.split(":") if ":" in rig else (None, rig)  # SHAPE:CAMSxFRAMES, a rig of calib/sim/shapes.py
        cameras, frames = (int(v) for v in size.split("x"))
        with tempfile.TemporaryDirectory() as tmp:
            folder = Path(tmp) / "capture"
            simulate(folder, cameras, frames, shape=shape)
            warm_bytecode()
            times, peaks, cpus, cm, cm_cpu, split = [], [], [], [], [], []
            error = colmap_error = float("nan")
            iterations = "-"
            for k in range(repeats):
                before = resource.getrusage(resource.RUSAGE_CHILDREN)
                seconds, peak, cpu = run_process(folder, Path(tmp) / "result.json")
                after = resource.getrusage(resource.RUSAGE_CHILDREN)
                split.append((after.ru_utime - before.ru_utime, after.ru_stime - before.ru_stime))
                times.append(seconds)
                peaks.append(peak)
                cpus.append(cpu)
                error = centre_error_mm(Path(tmp) / "result.json", folder / "truth.json")
                if k < colmap_repeats:
                    c_seconds, colmap_error, iterations, c_cpu = colmap_cauchy(cameras, frames, shape)
                    cm.append(c_seconds)
                    cm_cpu.append(c_cpu)
                print(f"{rig}: process {seconds:.2f} s, {peak:.0f} MB" + (f"; COLMAP-Cauchy {cm[-1]:.2f} s" if cm else ""),
                      flush=True)
        cm_s, ratio = ((f"{np.median(cm):.2f} / {np.median(cm_cpu):.2f} ({iterations} steps)",
                        f"{np.median(times) / np.median(cm):.2f} / {np.median(cpus) / np.median(cm_cpu):.2f}") if cm else ("-", "-"))
        user, system = np.median(split, axis=0)
        solves = ", ".join(f"{c:.1f}" for c in cm) or "-"
        rows.append(f"| {rig} | {OUTLIERS:.0%} | {np.median(times):.2f} / {np.median(cpus):.2f} | {user:.2f} + {system:.2f} | "
                    f"{cm_s} | {solves} | {ratio} | {error:.3f} / {colmap_error:.3f} | {max(peaks):.0f} |")
        print(rows[-1], flush=True)
    shapes = ("Rigs SHAPE:CAMSxFRAMES are `wandcal simulate --shape SHAPE` at its default size (seed 1; each frame in 2-4 "
              "cameras, |k1| to 0.1), COLMAP's scene the same rig without its L-frame. " if any(":" in r for r in rigs) else "")
    return (shapes + "The whole command (Python start-up included) on a simulated capture folder (0.3 px, 2% outliers, "
            "L-frame), and COLMAP-Cauchy's solve of the same rig labelled at the truth and started 1 deg / 3 cm off "
            "(bench_peers.py's scene, its gauge on the camera farthest from the first: decision 0019; its steps: "
            f"successful+unsuccessful), alternated in one run; medians of {repeats} processes and {colmap_repeats} COLMAP "
            "solves (minutes each at 128 cameras); ratio: median process / median COLMAP, of wall and of CPU seconds "
            "(COLMAP's Ceres runs on both cores, wandcal's BLAS on one); the process's CPU split into user and system "
            "seconds (medians of each). Centre error: RMS after a similarity alignment "
            "to the truth.\n\n"
            + "\n".join(rows) + "\n\nGoals (issue 22): 128 x 3000 process <= 0.3x COLMAP-Cauchy, peak RSS <= 1.2 GB, "
            "accuracy within 1.05x of before; 64 x 3000 <= 0.3x COLMAP-Cauchy.")


def part_points(repeats: int) -> str:
    cameras, wand_frames, point_frames = POINT_RIG
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "capture"
        n_obs = add_points(folder, cameras, wand_frames, point_frames)
        warm_bytecode()
        runs = [run_process(folder, Path(tmp) / "result.json")[:2] for _ in range(repeats)]
        error = centre_error_mm(Path(tmp) / "result.json", folder / "truth.json")
    seconds = float(np.median([r[0] for r in runs]))
    peak = max(r[1] for r in runs)
    print(f"point-heavy: {seconds:.2f} s, {peak:.0f} MB, {error:.3f} mm", flush=True)
    return (f"{cameras} cameras, a {wand_frames}-frame wand capture with its L-frame (2% outliers) and {point_frames:,} "
            f"frames of one marker ({n_obs:,} point observations, 0.3 px); the whole `wandcal calibrate` process, "
            f"median of {repeats}:\n\n| rig | point observations | process (s) | peak RSS (MB) | centre error (mm) |\n"
            f"|---|---|---|---|---|\n| {cameras} x {point_frames} points | {n_obs:,} | {seconds:.2f} | {peak:.0f} | {error:.3f} |"
            "\n\nGoal (issue 22): <= 10 s and <= 1 GB.")


def part_stages(cameras_list: list[int], repeats: int, shape: str | None = None) -> str:
    per = {}
    with tempfile.TemporaryDirectory() as tmp:
        for cameras in cameras_list:
            folder = Path(tmp) / f"c{cameras}"
            simulate(folder, cameras, STAGE_FRAMES, shape=shape)
            runs = []
            for _ in range(repeats):
                run_process(folder, Path(tmp) / "result.json", Path(tmp) / "profile")
                runs.append(stage_seconds(Path(tmp) / "profile"))
            per[cameras] = {k: float(np.median([r[k] for r in runs])) for k in runs[0]}
            print(cameras, {k: round(v, 2) for k, v in per[cameras].items()}, flush=True)
    names = list(STAGES) + ["other", "whole"]
    head = "| stage | " + " | ".join(f"{c} cams (CPU s)" for c in cameras_list) + " | growth exponent | last doubling |"
    rows = [head, "|" + "---|" * (len(cameras_list) + 3)]
    x = np.log(cameras_list)
    for name in names:
        y = np.array([max(per[c][name], 1e-4) for c in cameras_list])
        slope = np.polyfit(x, np.log(y), 1)[0]
        last = np.log(y[-1] / y[-2]) / np.log(cameras_list[-1] / cameras_list[-2])
        rows.append(f"| {name} | " + " | ".join(f"{v:.2f}" for v in y) + f" | {slope:.2f} | {last:.2f} |")
    rigs = f"`wandcal simulate --shape {shape}` rigs" if shape else "`wandcal simulate` rigs"
    return (f"`wandcal calibrate` under cProfile on {rigs} at {STAGE_FRAMES} frames (0.3 px, 2% outliers, L-frame), in CPU "
            f"seconds (the machine is shared), the median of {repeats} runs per rig and stage; each stage's cumulative "
            "time attributed by caller (the profiler's overhead included; imports not counted, \"other\" is the "
            "reports and the verdict). Growth exponent: the least-squares slope of "
            "log(seconds) on log(cameras); last doubling: the slope from the second-largest rig to the largest.\n\n"
            + "\n".join(rows) + "\n\nGoal (issue 22): every stage at most cameras^1.2.")


def part_where(rigs: list[str], repeats: int, base: Path | None = None) -> str:
    """Where the whole command's CPU goes, stage by stage, on each rig: the process under
    bench/stage_timer.py (each stage's CPU seconds by timers around its functions, no profiler),
    medians of the repeats; the stages' shares of the whole process. With ``base`` (another
    checkout), its process and this one's alternated run by run on the same capture, before and
    after side by side."""
    import os

    from bench.stage_timer import STAGE_FUNCTIONS

    variants: dict[str, Path | None] = {"": None}
    load = [os.getloadavg()[0]]
    with tempfile.TemporaryDirectory() as tmp:
        if base is not None:
            variants = {"before": checkout_view(base, Path(tmp) / "view"), "after": None}
        per: dict[tuple[str, str], dict[str, float]] = {}
        for rig in rigs:
            shape, size = rig.split(":") if ":" in rig else (None, rig)
            cameras, frames = (int(v) for v in size.split("x"))
            folder = Path(tmp) / rig.replace(":", "-")
            simulate(folder, cameras, frames, shape=shape)
            for view in variants.values():
                warm_bytecode(view)
            runs: dict[str, list[dict[str, float]]] = {name: [] for name in variants}
            for _ in range(repeats):
                for name, view in variants.items():
                    runs[name].append(_stage_run(folder, Path(tmp), view))
                    load.append(os.getloadavg()[0])
            for name in variants:
                per[(rig, name)] = {k: float(np.median([r[k] for r in runs[name]])) for k in runs[name][0]}
                print(rig, name, {k: round(v, 3) for k, v in per[(rig, name)].items()}, flush=True)
    names = list(STAGE_FUNCTIONS) + ["other", "whole"]
    cols = [(rig, name) for rig in rigs for name in variants]
    rows = ["| stage | " + " | ".join(f"{rig}{': ' + name if name else ''}: CPU s (share)" for rig, name in cols) + " |",
            "|---|" + "---|" * len(cols)]
    rows += [f"| {stage} | " + " | ".join(f"{per[c][stage]:.3f} ({per[c][stage] / per[c]['whole']:.0%})" for c in cols) + " |"
             for stage in names]
    against = (" Before: the checkout given by --base, on PYTHONPATH; after: this one; alternated process by process on the "
               "same capture." if base is not None else "")
    return ("Each rig a `wandcal simulate --shape` capture (0.3 px, 2% outliers, L-frame, seed 1), the whole `wandcal "
            f"calibrate` process run {repeats} times with its stages timed in CPU seconds by timers around their "
            "functions (bench/stage_timer.py: no profiler, whose cost per Python call inflates the Python-heavy stages "
            "up to twentyfold); medians. \"other\": Python's start-up, the imports, the argument parsing and the "
            f"summary.{against} 1-minute load average {min(load):.1f}-{max(load):.1f} on {os.cpu_count()} cores.\n\n"
            + "\n".join(rows))


def _stage_run(folder: Path, tmp: Path, view: Path | None) -> dict[str, float]:
    """One whole `wandcal calibrate` process on ``folder`` under bench/stage_timer.py: each stage's
    CPU seconds (``view``: another checkout's, first on the path; None: this one)."""
    import json

    out = tmp / "stages.json"
    subprocess.run([sys.executable, "-m", "bench.stage_timer", str(out), "calibrate", str(folder), "--quiet",
                    "--out", str(tmp / "result.json")], check=True, capture_output=True, cwd=REPO, env=child_env(view))
    return json.loads(out.read_text())


def part_guidance(cameras: int, frames: int, repeats: int) -> str:
    """The live guidance update at a big rig: cold, and live (the capture grew by 10% since the
    update it starts from), wall and CPU seconds, alternated run by run (BLAS on one thread),
    medians, with the machine's load average over the runs."""
    import os

    from threadpoolctl import threadpool_limits

    from wandcal.calib.rig import WandObservations
    from wandcal.calib.run.guidance import wanding_guidance
    from wandcal.calib.sim.simulate import simulate_capture

    sim = simulate_capture(cameras, frames, 0.3, 0.0, True, 1)
    keep = sim.wand.frame < int(0.9 * frames)
    before = WandObservations(sim.wand.frame[keep], sim.wand.camera[keep], sim.wand.uv[keep])
    start = wanding_guidance(sim.rig, before, sim.static).solution

    def timed(fn):
        wall, cpu = time.perf_counter(), time.process_time()
        fn()
        return time.perf_counter() - wall, time.process_time() - cpu

    runs: dict[str, list] = {"cold": [], "live": []}
    load = [os.getloadavg()[0]]
    with threadpool_limits(1):
        for _ in range(repeats):
            runs["cold"].append(timed(lambda: wanding_guidance(sim.rig, before, sim.static)))
            runs["live"].append(timed(lambda: wanding_guidance(sim.rig, sim.wand, sim.static, start=start)))
            load.append(os.getloadavg()[0])
    cold, live = np.median(runs["cold"], axis=0), np.median(runs["live"], axis=0)
    print(f"guidance {cameras} x {frames}: cold {cold}, live {live}, live runs {runs['live']}", flush=True)
    return (f"`wanding_guidance` on a simulated {cameras} x {frames} capture (0.3 px, L-frame), in this process, the "
            f"cold and the live update alternated, BLAS on one thread, medians of {repeats}; CPU seconds beside the wall "
            f"seconds because the machine is shared (1-minute load average {min(load):.1f}-{max(load):.1f} on its "
            f"{os.cpu_count()} cores during the runs):\n\n"
            "| rig | cold update, wall / CPU (s) | live update (+10% frames, warm start), wall / CPU (s) | live: slowest run, wall (s) |\n"
            "|---|---|---|---|\n"
            f"| {cameras} x {frames} | {cold[0]:.2f} / {cold[1]:.2f} | {live[0]:.2f} / {live[1]:.2f} | "
            f"{max(r[0] for r in runs['live']):.2f} |\n\n"
            "Goal (issue 22): the live update at 64 x 3000 in <= 1 s.")


def part_methods(cameras_list: list[int], repeats: int) -> str:
    """`--method lp` against `--method ba` (the default), the whole process on the same capture,
    alternated run by run; the ratio of CPU seconds, median of the runs' ratios."""
    rows = ["| rig | `ba`: wall / CPU (s) | `lp`: wall / CPU (s) | lp / ba (CPU) | centre error ba / lp (mm) |", "|---|---|---|---|---|"]
    with tempfile.TemporaryDirectory() as tmp:
        for cameras in cameras_list:
            folder = Path(tmp) / f"c{cameras}"
            simulate(folder, cameras, STAGE_FRAMES)
            medians, ratio, errors = alternated(folder, Path(tmp), {"ba": (None, "ba"), "lp": (None, "lp")}, repeats)
            b, lp = medians["ba"], medians["lp"]
            rows.append(f"| {cameras} x {STAGE_FRAMES} | {b[0]:.2f} / {b[1]:.2f} | {lp[0]:.2f} / {lp[1]:.2f} | {ratio:.2f} | "
                        f"{errors['ba']:.3f} / {errors['lp']:.3f} |")
            print(rows[-1], flush=True)
    return (f"The whole `wandcal calibrate` process with `--method ba` and `--method lp` on the same simulated capture "
            f"(0.3 px, 2% outliers, L-frame), alternated run by run, medians of {repeats}; CPU seconds (user + system) "
            "beside wall seconds because the machine is shared; the ratio is the median of the runs' CPU ratios.\n\n"
            + "\n".join(rows) + "\n\nGoal (issue 22): `lp` at 128 cameras <= 1.5x `ba`.")


def part_regression(base: Path, repeats: int, rigs: str) -> str:
    """Rigs ``CAMSxFRAMES:OUTLIERS,...`` (the Peers bench's small ones by default), this checkout
    against ``base``, alternated run by run."""
    rows = ["| rig | outliers | before: wall / CPU (s) | after: wall / CPU (s) | after / before (CPU) | centre error before / after (mm) |",
            "|---|---|---|---|---|---|"]
    with tempfile.TemporaryDirectory() as tmp:
        view = checkout_view(base, Path(tmp) / "view")
        warm_bytecode(view)
        warm_bytecode()
        for rig in rigs.split(","):
            size, outliers = rig.split(":")[0], float(rig.split(":")[1])
            cameras, frames = (int(v) for v in size.split("x"))
            folder = Path(tmp) / f"c{cameras}x{frames}"
            simulate(folder, cameras, frames, outliers)
            medians, ratio, errors = alternated(folder, Path(tmp), {"before": (view, "ba"), "after": (None, "ba")}, repeats)
            b, a = medians["before"], medians["after"]
            rows.append(f"| {cameras}x{frames} | {outliers:.0%} | {b[0]:.2f} / {b[1]:.2f} | {a[0]:.2f} / {a[1]:.2f} | "
                        f"{ratio:.2f} | {errors['before']:.3f} / {errors['after']:.3f} |")
            print(rows[-1], flush=True)
    return (f"Simulated rigs (`wandcal simulate`, 0.3 px, L-frame), the whole `wandcal calibrate` process "
            f"of the checkout given by `--base` (before) and of this one (after), alternated run by run, medians of {repeats}; CPU "
            "seconds beside wall seconds because the machine is shared:\n\n" + "\n".join(rows)
            + ("\n\nGoal (issue 22): 8 x 1500 and 16 x 2500 no slower than before." if rigs == REGRESSION_RIGS else
               "\n\nGoal (issue 22): accuracy within 1.05x of before."))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--parts", default="peers,points,stages,guidance")
    ap.add_argument("--rigs", default="64x3000,128x3000")
    ap.add_argument("--stage-cameras", default="16,32,64,128")
    ap.add_argument("--stage-shape", default=None, help="rigs of calib/sim/shapes.py (ring, dome, tiers, hallway) for --parts stages")
    ap.add_argument("--colmap-repeats", type=int, default=1, help="COLMAP solves per rig (0: none)")
    ap.add_argument("--base", type=Path, help="a checkout of the code before, for --parts regression (and beside this "
                    "one in --parts where and costs)")
    ap.add_argument("--regression-rigs", default=REGRESSION_RIGS,
                    help="CAMSxFRAMES:OUTLIERS,... for --parts regression")
    ap.add_argument("--method-cameras", default="64,128", help="rigs (cameras x 3000 frames) for --parts methods")
    ap.add_argument("--cost-rigs", default=EVERY_SHAPE_128, help="[SHAPE:]CAMSxFRAMES,... for --parts costs")
    ap.add_argument("--where-rigs", default="ring:128x3000,tiers:128x3000", help="[SHAPE:]CAMSxFRAMES,... for --parts where")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    parts = args.parts.split(",")
    sections = []
    if "peers" in parts:
        # rigs given as SHAPE:CAMSxFRAMES (calib/sim/shapes.py) get their own section
        title = "Scale: every shape beside COLMAP" if ":" in args.rigs else "Scale: the whole command beside COLMAP"
        sections.append((title, part_peers(args.rigs.split(","), args.repeats, args.colmap_repeats)))
    if "points" in parts:
        sections.append(("Scale: point-heavy rig", part_points(args.repeats)))
    if "regression" in parts:
        if args.base is None:
            ap.error("--parts regression needs --base CHECKOUT (the code before, e.g. from git archive)")
        small = args.regression_rigs == REGRESSION_RIGS
        title = "Scale: small rigs before and after" if small else f"Scale: before and after ({args.regression_rigs})"
        sections.append((title, part_regression(args.base, args.repeats, args.regression_rigs)))
    if "methods" in parts:
        sections.append(("Scale: lp beside ba", part_methods([int(c) for c in args.method_cameras.split(",")], args.repeats)))
    if "guidance" in parts:
        sections.append(("Scale: guidance", part_guidance(64, 3000, args.repeats)))
    if "costs" in parts:
        title = ("Scale: judgement, guidance, check and sync on every shape (issue 33)" if args.cost_rigs == EVERY_SHAPE_128
                 else f"Scale: judgement, guidance, check and sync ({args.cost_rigs})")
        sections.append((title, part_costs(args.cost_rigs.split(","), args.repeats, args.base)))
    if "where" in parts:
        sections.append(("Scale: where the whole command's CPU goes (sparse shapes)",
                         part_where(args.where_rigs.split(","), args.repeats, args.base)))
    if "stages" in parts:
        title = f"Scale: stages ({args.stage_shape})" if args.stage_shape else "Scale: stages"
        sections.append((title, part_stages([int(c) for c in args.stage_cameras.split(",")], args.repeats, args.stage_shape)))
    for title, body in sections:
        print(f"\n## {title}\n\n{body}")
        if not args.no_write:
            write_section(title, body)
    return 0


if __name__ == "__main__":
    sys.exit(main())
