"""Issue 31: a multi-marker wand's interior markers in the judgement, on sparse simulated rigs.

Each case is a sparse simulated capture (few cameras, few frames, markers often hidden, as the real
sessions are) of a 3- or a 5-marker wand with one fault on one camera drawn from the seed: its
focal length 3% off in rig.json, a knock (0.5 degrees after the middle of its frames), its noise
3x, or the camera late by 0.5-2.5 frames. Each is judged twice in one process, side by side: as
before issue 31 (the judgement given the wand's two ends only) and with every interior marker
as a point track (calib/start/markerlabels.interior_tracks). A case is right when the fault's
kind and camera are named and no other; a good rig when no fault is named.

Usage: python bench/bench_marker_judgement.py [--seeds 8] [--cameras 4] [--rigs 40:0.2,80:0.15] [--cost-rig 8x1500]
       [--cost-repeats 3] [--cli-seed 301] [--no-write]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import publish
from wandcal.calib.errors import CalibrationError
from wandcal.calib.run import calibrate as pipeline
from wandcal.calib.sim.faults import knocked_camera, noisy_camera, wrong_focal
from wandcal.calib.sim.simulate import SimulatedCapture, simulate_capture
from wandcal.service.cli.simulate import WANDS

FIRST_SEED = 300  # held out: nothing in the judgement was set looking at these
NOISE_PX = 0.3
FOCAL_FACTOR = 0.03  # issue 31's focal length fault: 3% off, either way
KNOCK_DEG = 0.5  # issue 31's knock: 0.5 degrees partway through
NOISE_FACTOR = 3.0  # one camera's noise at 3x
LATE_FRAMES = (0.5, 2.5)  # a camera late by this many frames, drawn
CASES = {"good": None, "focal": "intrinsics", "knock": "moved", "noise": "noise", "late": "timing"}


def broken(case: str, wand: str, seed: int, args) -> tuple[SimulatedCapture, int | None]:
    """A sparse capture of ``wand`` (``args``: its cameras, frames and occlusion) with the fault
    ``case`` on a camera drawn from ``seed``; the camera's index (None for a good rig)."""
    rng = np.random.default_rng(2000 + seed)
    c, sign = int(rng.integers(0, args.cameras)), rng.choice([-1.0, 1.0])
    late = np.zeros(args.cameras)
    if case == "late":
        late[c] = rng.uniform(*LATE_FRAMES)
    sim = simulate_capture(args.cameras, args.frames, NOISE_PX, 0.0, True, seed, wand_markers=np.array(WANDS[wand]),
                           occlusion=args.occlusion, offsets=late if case == "late" else None)
    if case == "focal":
        sim = wrong_focal(sim, c, 1 + sign * FOCAL_FACTOR)
    elif case == "knock":
        sim = knocked_camera(sim, c, KNOCK_DEG, seed)
    elif case == "noise":
        sim = noisy_camera(sim, c, NOISE_PX * np.sqrt(NOISE_FACTOR**2 - 1), seed)
    return sim, None if case == "good" else c


def shared_frames(sim: SimulatedCapture) -> float:
    """The median camera's frames in which two other cameras see every wand marker too."""
    k = len(sim.rig.wand_markers)
    n = len(sim.rig.cameras)
    full = np.zeros((int(sim.wand.frame.max()) + 1, n), int)
    np.add.at(full, (sim.wand.frame, sim.wand.camera), 1)
    full = full == k
    return float(np.median([(full[:, c] & (full.sum(axis=1) - full[:, c] >= 2)).sum() for c in range(n)]))


def judged(sim: SimulatedCapture, ends_only: bool) -> tuple[set, float]:
    """(the faults named as (kind, camera), CPU seconds of the whole calibrate); ``ends_only``: the
    judgement without the interior markers (the sessions here have no point tracks of their own).
    A refusal counts as naming a timing fault where it names a camera out of time."""
    judge = pipeline.judge

    def without(*a, **k):
        return judge(*a[:8], None, *a[9:], **k)

    pipeline.judge = without if ends_only else judge
    start = time.process_time()
    try:
        doc = pipeline.calibrate(sim.rig, sim.wand, sim.static).to_json()
    except CalibrationError as exc:  # a refusal names a camera out of time, or not
        text = str(exc)
        return {("timing", text.split(maxsplit=1)[0]) if " is out of time" in text else ("refused", None)}, time.process_time() - start
    finally:
        pipeline.judge = judge
    return {(f["kind"], f["camera"]) for f in doc["verdict"]["faults"]}, time.process_time() - start


def run(args) -> tuple[list[str], np.ndarray]:
    """The table's rows for every rig (``--rigs``), wand and case, and the totals (runs, right with the
    ends only, right with every marker)."""
    rows: dict[tuple[str, str, str], list] = defaultdict(list)
    for rig in args.rigs.split(","):
        frames, occlusion = rig.split(":")
        sparse = argparse.Namespace(cameras=args.cameras, frames=int(frames), occlusion=float(occlusion))
        for wand in args.wands.split(","):
            for case, kind in CASES.items():
                for seed in range(args.first_seed, args.first_seed + args.seeds):
                    sim, c = broken(case, wand, seed, sparse)
                    want = set() if kind is None else {(kind, sim.rig.cameras[c].id)}
                    before, t0 = judged(sim, True)
                    after, t1 = judged(sim, False)
                    rows[rig, wand, case].append((before == want, after == want, t0, t1, shared_frames(sim)))
                    print(f"{rig} {wand} {case} seed {seed}: want {sorted(want)}; ends only {sorted(before)}; "
                          f"every marker {sorted(after)}", file=sys.stderr)
    lines, total = [], np.zeros(3, int)
    for (rig, wand, case), rs in rows.items():
        a = np.array(rs)
        total += [len(rs), int(a[:, 0].sum()), int(a[:, 1].sum())]
        frames, occlusion = rig.split(":")
        lines.append(f"| {args.cameras} x {frames}, {100 * float(occlusion):.0f}% | {wand} | {case} | {len(rs)} | "
                     f"{int(a[:, 0].sum())} | {int(a[:, 1].sum())} | {np.median(a[:, 4]):.0f} | "
                     f"{np.median(a[:, 2]):.2f} / {np.median(a[:, 3]):.2f} |")
    return lines, total


def cost(wand: str, cameras: int, frames: int, repeats: int) -> tuple[float, float, float]:
    """(median CPU s of ``calibrate`` judged on the ends only, on every marker, the median of the
    runs' ratios) on a clean, dense simulated capture of ``wand``, the two alternated run by run."""
    sim = simulate_capture(cameras, frames, NOISE_PX, 0.0, True, 1, wand_markers=np.array(WANDS[wand]))
    runs = np.array([[judged(sim, ends_only)[1] for ends_only in (True, False)] for _ in range(repeats)])
    return float(np.median(runs[:, 0])), float(np.median(runs[:, 1])), float(np.median(runs[:, 1] / runs[:, 0]))


def cli_runs(rig: str, seed: int, late_by: float = 2.3) -> list[str]:
    """Table rows of the commands a lab runs on a sparse 3-marker capture (``rig`` FRAMES:SHARE, 4
    cameras): ``calibrate``, ``calibrate --sync auto`` with cam3 ``late_by`` frames late, ``check``
    of a fresh capture with cam2 knocked 0.5 degrees, and ``--solve-only cam2`` from it. Each row:
    the command's exit status and its last line (or the verdict's faults)."""
    import json
    import subprocess
    import tempfile

    from wandcal.calib.sim.scenes import knocked_capture
    from wandcal.capture.folder import write_capture
    from wandcal.service.cli.simulate import write_simulated

    part = rig.split(":")
    frames, occlusion = int(part[0]), float(part[1])
    layout = np.array(WANDS["three"])
    sim = simulate_capture(4, frames, NOISE_PX, 0.0, True, seed, wand_markers=layout, occlusion=occlusion)
    late = simulate_capture(4, frames, NOISE_PX, 0.0, True, seed, wand_markers=layout, occlusion=occlusion,
                            offsets=np.array([0, 0, late_by, 0]))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        write_simulated(root / "clean", sim)
        write_simulated(root / "late", late)
        write_capture(root / "knocked", sim.rig, knocked_capture(sim, 1, 0.5, 0.0, frames, seed + 1)[0], None)
        for name, argv, out in (
                ("calibrate", ["calibrate", "clean", "--quiet"], "clean/result.json"),
                (f"calibrate --sync auto (cam3 {late_by} frames late)", ["calibrate", "late", "--sync", "auto", "--quiet"],
                 "late/result.json"),
                ("check (cam2 knocked 0.5 deg)", ["check", "clean/result.json", "knocked"], None),
                ("calibrate --from --solve-only cam2", ["calibrate", "knocked", "--from", "clean/result.json",
                                                        "--solve-only", "cam2", "--quiet"], "knocked/result.json")):
            done = subprocess.run([sys.executable, "-m", "wandcal.service.cli", *argv], cwd=root, capture_output=True,
                                  text=True, timeout=600, check=False)
            said = (done.stdout.strip() or done.stderr.strip()).splitlines()[-1:] or [""]
            if done.returncode == 0 and out is not None:
                doc = json.loads((root / out).read_text())
                offsets = [round(c["offset_frames"], 2) for c in (doc.get("sync") or {}).get("cameras", [])]
                said = [f"verdict {doc['verdict']['level']}, faults "
                        f"{[(f['kind'], f['camera']) for f in doc['verdict']['faults']] or 'none'}"
                        + (f", offsets {offsets}" if offsets else "")]
            rows.append(f"| 4 x {frames}, {100 * occlusion:.0f}% | `{name}` | {done.returncode} | "
                        f"{said[0][:220].replace('|', '/')} |")
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--first-seed", type=int, default=FIRST_SEED)
    ap.add_argument("--cameras", type=int, default=4)
    ap.add_argument("--rigs", default="40:0.2,80:0.15",
                    help="FRAMES:SHARE,...: frames of each capture and the chance a marker is hidden from a camera")
    ap.add_argument("--wands", default="three,five")
    ap.add_argument("--cost-rig", default="8x1500", help="CAMERASxFRAMES of the clean capture timed both ways")
    ap.add_argument("--cost-repeats", type=int, default=3)
    ap.add_argument("--cli-seed", type=int, default=FIRST_SEED + 1, help="the capture the commands run on")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    started, load = time.strftime("%H:%M", time.gmtime()), os.getloadavg()[0]
    lines, total = run(args)
    head = ["| rig: cameras x frames, markers hidden | wand | case | runs | right, ends only | right, every marker | "
            "frames a camera shares with two others (median) | CPU s a calibrate, ends only / every marker (median) |",
            "|---|---|---|---|---|---|---|---|"]
    text = "\n".join(head + lines) + (
        f"\n\nRight in {total[1]} of {total[0]} with the wand's ends only, {total[2]} of {total[0]} with every marker "
        f"(seeds {args.first_seed}-{args.first_seed + args.seeds - 1}).")
    if args.cost_repeats:
        n, f = map(int, args.cost_rig.split("x"))
        text += (f"\n\nThe cost: the whole `calibrate` of a clean {args.cost_rig} capture, CPU seconds, medians of "
                 f"{args.cost_repeats} runs alternated.\n\n| wand | ends only | every marker | every marker / ends only |"
                 "\n|---|---|---|---|")
        for wand in args.wands.split(","):
            a, b, ratio = cost(wand, n, f, args.cost_repeats)
            text += f"\n| {wand} | {a:.2f} | {b:.2f} | {ratio:.2f} |"
    if args.cli_seed is not None:
        text += ("\n\nThe commands on a sparse 3-marker capture (seed "
                 f"{args.cli_seed}):\n\n| rig | command | exit | said |\n|---|---|---|---|\n")
        text += "\n".join(row for rig in args.rigs.split(",") for row in cli_runs(rig, args.cli_seed))
    text += (f"\n\nRun {started}-{time.strftime('%H:%M', time.gmtime())} UTC, load average {load:.1f} at the start, "
             f"{os.getloadavg()[0]:.1f} at the end (CPU seconds, so the shared machine's load does not enter them).")
    return publish("Issue 31: every marker of a multi-marker wand in the judgement", __doc__.split("\n\n")[1] + "\n\n"
                   + text, not args.no_write)


if __name__ == "__main__":
    sys.exit(main())
