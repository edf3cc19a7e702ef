"""Wanding guidance: the time of one update, and the live capture's rate with guidance and images on and off.

    python bench/bench_guidance.py [--seconds 10] [--repeats 3] [--write-docs]

Part 1 times :func:`wandcal.calib.run.guidance.wanding_guidance` on simulated captures (8 x 1500 and
16 x 2500 frames): a cold update, the live case (the capture grew by 10% since the last update,
which starts this one), and the same without subsampling, with how far the subsampled sigma is
from the full solve's. Part 2 compares the guidance's rig-relative sigma with the calibration
result's ``center_std_mm`` in the static object's and in the wand volume's frame, as frames
arrive and with one camera starved (docs/decisions/0010-guidance-uncertainty.md). Part 3 records
from 8 simulated 1280 x 1024 cameras triggered at 100 Hz by the trigger emulator on a
pseudo-terminal, each capture in a child process, with images off/on and guidance off/on, repeated; the cores other jobs used are printed beside each run because
they share the machine's two. Prints the tables and, with --write-docs, puts them in
docs/benchmarks.md under "## Guidance".
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from bench.common import replace_section  # noqa: E402
from wandcal.calib.rig import WandObservations  # noqa: E402
from wandcal.calib.run.calibrate import calibrate  # noqa: E402
from wandcal.calib.run.guidance import GuidanceSettings, wanding_guidance  # noqa: E402
from wandcal.calib.sim.simulate import simulate_capture  # noqa: E402

RIGS = ((8, 1500), (16, 2500))
GROWTH = 0.9  # the live case: the last update saw 90% of the frames
RATE_HZ = 100.0
CAMERAS = 8
IMAGES_ON_SECONDS = 1.5  # PNG writing tops out near 10 sets/s at 8 cameras: 150 sets say as much
ALL_FRAMES = 10**9  # frames_per_camera that keeps every frame


def _prefix(wand: WandObservations, frames: int) -> WandObservations:
    keep = wand.frame < frames
    return WandObservations(wand.frame[keep], wand.camera[keep], wand.uv[keep])


def _median_time(fn, repeats: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times), out


def bench_updates(repeats: int) -> list[tuple]:
    rows = []
    for cameras, frames in RIGS:
        sim = simulate_capture(cameras, frames, 0.3, 0.0, True, 1)
        rig, wand, static = sim.rig, sim.wand, sim.static
        cold, doc = _median_time(lambda: wanding_guidance(rig, wand, static), repeats)
        start = wanding_guidance(rig, _prefix(wand, int(GROWTH * frames)), static).solution
        live, warm = _median_time(lambda: wanding_guidance(rig, wand, static, start=start), repeats)
        full_settings = GuidanceSettings(frames_per_camera=ALL_FRAMES)
        full_time, full = _median_time(lambda: wanding_guidance(rig, wand, static, full_settings, start), repeats)
        ratio = np.array([a["center_std_mm"] / b["center_std_mm"]
                          for a, b in zip(warm.document["cameras"], full.document["cameras"])])
        rows.append((f"{cameras} x {frames}", cold, live, warm.document["solve"]["frames_used"], full_time,
                     full.document["solve"]["frames_used"], float(np.max(np.abs(ratio - 1)))))
    return rows


def _sigmas(doc_cameras) -> np.ndarray:
    return np.array([np.nan if c["center_std_mm"] is None else c["center_std_mm"] for c in doc_cameras])


def bench_frames() -> tuple[list[tuple], list[tuple]]:
    """The median camera's sigma as frames arrive, and the cameras' sigmas with one starved, in
    the three frames: the result's static-object frame, its wand-volume frame, the guidance's."""
    from tests.calib.judge.test_guidance import STARVED_FRAMES, covering_capture, starve

    growth = []
    for frames in (150, 300, 600, 1200, 2400):
        sim = simulate_capture(8, frames, 0.3, 0.0, True, 1)
        static = calibrate(sim.rig, sim.wand, sim.static).to_json()["cameras"]
        volume = calibrate(sim.rig, sim.wand, None).to_json()["cameras"]
        guide = wanding_guidance(sim.rig, sim.wand, sim.static).document["cameras"]
        growth.append((frames, *(float(np.nanmedian(_sigmas(c))) for c in (static, volume, guide))))
    starved = []
    rig, wand, static_obs, _ = covering_capture(8, 1500, 0)
    for cam in ("cam1", "cam5"):
        thin = starve(rig, wand, cam, STARVED_FRAMES)
        c = rig.index(cam)
        for name, run in (("static-object frame (calibrate)", lambda: calibrate(rig, thin, static_obs).to_json()["cameras"]),
                          ("wand-volume frame (calibrate, no static)", lambda: calibrate(rig, thin, None).to_json()["cameras"]),
                          ("guidance, rig-relative", lambda: wanding_guidance(rig, thin, static_obs).document["cameras"])):
            start = time.perf_counter()
            sig = _sigmas(run())
            seconds = time.perf_counter() - start
            others = np.delete(sig, c)
            starved.append((cam, name, sig[c], float(others.min()), float(others.max()), seconds))
    return growth, starved


def run_capture(images: str, guidance: bool, seconds: float) -> dict:
    """One capture in this process (the child): rate, missed frames, CPU time, guidance updates."""
    from wandcal.capture.recording.live_guidance import LiveGuidance
    from wandcal.capture.recording.record import ImagePolicy
    from wandcal.capture.recording.session import record
    from wandcal.drivers.registry import open_cameras
    from wandcal.drivers.trigger import open_trigger
    from wandcal.drivers.trigger_emulator import EmulatorProcess

    frames = int(RATE_HZ * seconds)
    cams = open_cameras(f"sim://?cameras={CAMERAS}&frames={frames}&seed=1")
    rig = cams[0].scene.rig
    speed = _machine_speed()
    updates, rates = [], []
    with EmulatorProcess() as emu, tempfile.TemporaryDirectory() as tmp:
        live = LiveGuidance(rig, on_update=lambda d: updates.append(d["solve"]["seconds"])) if guidance else None
        if live is not None:
            live.start()
        first = []  # CPU and sets at the first set recorded: the cameras' opening is not the capture's cost

        def progress(p) -> None:
            rates.append(p.fps)
            if not first and p.sets:
                first.append((_self_cpu(), p.sets))

        start = time.perf_counter()
        result = record(cams, open_trigger(emu.url), Path(tmp) / "cap", rig, frames=frames, rate_hz=RATE_HZ,
                        images=ImagePolicy.parse(images), guidance=live, progress=progress)
        wall = time.perf_counter() - start
        cpu = _self_cpu() - first[0][0]
        solver_cpu = 0.0
        if live is not None:
            solver_cpu = sum(_process_cpu(pid) for pid in live._pool._processes)  # the guidance's child
            live.close()
    return {"sets": result.frame_sets, "wall": wall, "fps": rates[-1] if rates else 0.0,
            "missed": sum(c["missed"] for c in result.per_camera.values()),
            "cpu": cpu, "cpu_sets": result.frame_sets - first[0][1], "solver_cpu": solver_cpu,
            "updates": len(updates), "update_s": statistics.median(updates) if updates else None, "speed": speed}


PROBE_FRAMES = 100


def _machine_speed() -> float:
    """Frames per second one thread renders and detects just now: the virtual machine's speed
    varies with its host (the same code measured 600-2800 frames/s of rendering within an hour)."""
    from wandcal.calib.detect import detect_blobs
    from wandcal.drivers.registry import open_cameras

    (cam, *_) = open_cameras(f"sim://?cameras=2&frames={PROBE_FRAMES}")
    with cam:
        start = time.perf_counter()
        for seq in range(PROBE_FRAMES):
            detect_blobs(cam.render(seq))
        return PROBE_FRAMES / (time.perf_counter() - start)


def _self_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _process_cpu(pid: int) -> float:
    """User + system seconds of a running process (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _machine_busy() -> float:
    """CPU seconds all processes have used since boot (Linux /proc/stat: all but idle and iowait)."""
    ticks = [int(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:9]]
    return (sum(ticks) - ticks[3] - ticks[4]) / os.sysconf("SC_CLK_TCK")


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def child(images: str, guidance: bool, seconds: float) -> dict:
    """One capture in a child process, and the cores other jobs used meanwhile: the machine's busy
    time less that of the child and its own children (the trigger emulator, the guidance's solver)."""
    busy, ours, start = _machine_busy(), _children_cpu(), time.perf_counter()
    out = subprocess.run([sys.executable, __file__, "--child", images, "on" if guidance else "off", str(seconds)],
                         capture_output=True, text=True, check=True, cwd=ROOT)
    wall = time.perf_counter() - start
    others = ((_machine_busy() - busy) - (_children_cpu() - ours)) / wall
    return json.loads(out.stdout.strip().splitlines()[-1]) | {"others": max(others, 0.0)}


def bench_captures(seconds: float, repeats: int) -> list[tuple]:
    configs = [("none", False), ("none", True), ("all", False), ("all", True)]
    runs: dict[tuple, list[dict]] = {c: [] for c in configs}
    for _ in range(repeats):  # interleaved, so a change of the machine's load hits every configuration alike
        for images, guidance in configs:
            secs = seconds if images == "none" else IMAGES_ON_SECONDS
            runs[(images, guidance)].append(child(images, guidance, secs))
    rows = []
    for (images, guidance), rs in runs.items():
        med = lambda key: statistics.median(r[key] for r in rs)  # noqa: E731
        rate = med("fps")
        # cores the capture process needs for 100 sets/s: its CPU seconds per 100 sets
        need = statistics.median(100 * r["cpu"] / r["cpu_sets"] for r in rs)
        solver = statistics.median(r["solver_cpu"] / r["wall"] for r in rs) if guidance else None
        rows.append((images, "on" if guidance else "off", rs[0]["sets"], rate, rate * CAMERAS,
                     ", ".join(f"{r['fps']:.1f} ({r['others']:.2f}; {r['speed']:,.0f})" for r in rs), med("missed"), need,
                     "-" if solver is None else f"{solver:.2f}",
                     "-" if not guidance else f"{med('updates'):.0f} ({statistics.median(r['update_s'] for r in rs):.2f} s)"))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=10.0, help="recorded time of each images-off capture")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--write-docs", action="store_true")
    ap.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(run_capture(args.child[0], args.child[1] == "on", float(args.child[2]))))
        return
    load_start = os.getloadavg()
    updates = bench_updates(args.repeats)
    growth, starved = bench_frames()
    captures = bench_captures(args.seconds, args.repeats)
    t1 = ["| rig | cold update | live update (from the last, +10% frames) | frames in the fast solve | "
          "the same without subsampling | its frames | max abs(sigma / full - 1) |", "|---|---|---|---|---|---|---|"]
    t1 += [f"| {r[0]} | {r[1]:.2f} s | {r[2]:.2f} s | {r[3]} | {r[4]:.2f} s | {r[5]} | {r[6]:.1%} |" for r in updates]
    t3 = ["| wand frames | result, static-object frame | result, wand-volume frame | guidance, rig-relative |",
          "|---|---|---|---|"]
    t3 += [f"| {r[0]} | {r[1]:.2f} mm | {r[2]:.2f} mm | {r[3]:.2f} mm |" for r in growth]
    t4 = ["| starved camera | sigma in | its sigma | the others' sigma | time |", "|---|---|---|---|---|"]
    t4 += [f"| {r[0]} | {r[1]} | {r[2]:.2f} mm | {r[3]:.2f}-{r[4]:.2f} mm | {r[5]:.2f} s |" for r in starved]
    t2 = ["| images | guidance | sets asked | sets/s (median) | frames/s | each run: sets/s (other jobs' cores; "
          "1-thread render + detect, frames/s) | "
          "missed frames | capture process: cores for 100 sets/s | guidance child: cores | guidance updates "
          "(median time) |", "|---|---|---|---|---|---|---|---|---|---|"]
    t2 += [f"| {r[0]} | {r[1]} | {r[2]} | {r[3]:.1f} | {r[4]:.0f} | {r[5]} | {r[6]:.0f} | {r[7]:.2f} | {r[8]} | {r[9]} |"
           for r in captures]
    header = (f"Command: `python bench/bench_guidance.py --seconds {args.seconds:g} --repeats {args.repeats} --write-docs`  \n"
              f"Machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}; load average "
              f"{load_start[0]:.1f} (1 min) / {load_start[1]:.1f} (5 min) at the start: other jobs share the two cores, "
              "so the capture rates below are what was left to wandcal; beside each run, the cores the other jobs "
              "used during it (the machine's busy time less the capture's, its trigger emulator's and its "
              "solver's).\n\n"
              "One guidance update (`wandcal.calib.run.guidance.wanding_guidance`, simulated ring rigs, 0.3 px noise, median of "
              f"{args.repeats}). The live update starts from the last solution (no initial poses) and keeps about 400 "
              "frames per camera; its sigma, scaled by sqrt(kept / all), is within the last column of the full "
              "solve's:\n")
    capture_text = (f"A live capture: {CAMERAS} simulated 1280 x 1024 cameras, triggered at {RATE_HZ:g} Hz by the "
                    "trigger emulator on a pseudo-terminal, detection in the reader threads, centroids recorded as "
                    f"they come. Images off: {args.seconds:g} s of sets; images on (every frame as PNG): "
                    f"{IMAGES_ON_SECONDS:g} s. Guidance on: `LiveGuidance` solving once a second in a child process. "
                    "sets/s is the wand phase's rate; a simulated camera queues the pulses it has not yet drawn, so a "
                    "rate under 100 is what a real camera would drop. The CPU columns depend less on the load: "
                    "the capture process's user + system seconds per 100 sets (the cores it needs to keep 100 sets/s), "
                    "and the guidance child's seconds per second of recording (the trigger emulator, a separate "
                    "process, is in neither). The machine is a virtual one whose speed varies with its host: each "
                    "run first measures how many frames one thread renders and detects per second (8 x 100 fps "
                    f"needs 800 across the cameras' threads). {args.repeats} runs each, interleaved.\n")
    from tests.calib.judge.test_guidance import STARVED_FRAMES

    frames_text = ("Which sigma tells the operator to keep waving: the median camera's predicted centre 1-sigma "
                   "as wand frames arrive (simulated 8-camera ring, seed 1, every frame used), and the cameras' "
                   f"sigmas when one camera saw the wand in only {STARVED_FRAMES} frames in the top-left of its image "
                   "(8 x 1500, the wand waved through the whole volume, tests/calib/judge/test_guidance.py):\n")
    text = (header + "\n" + "\n".join(t1) + "\n\n" + frames_text + "\n" + "\n".join(t3) + "\n\n" + "\n".join(t4)
            + "\n\n" + capture_text) + "\n" + "\n".join(t2) + "\n"
    print(text)
    if args.write_docs:
        replace_section("Guidance", text)


if __name__ == "__main__":
    main()
