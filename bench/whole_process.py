"""A whole `wandcal calibrate` process, run and measured for the scale benches (bench_scale.py): the
simulated capture folders it reads (past `wandcal simulate`'s 64-camera cap; a point-heavy one), the
timed child process (wall and CPU seconds, peak RSS, cached bytecode), its cProfile stages, and runs
alternated against another checkout or method; centre errors against the simulator's truth."""

from __future__ import annotations

import json
import pstats
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.common import aligned_rms_mm

REPO = Path(__file__).resolve().parents[1]
OUTLIERS = 0.02  # share of camera-frames with a gross outlier in the scale benches' captures
POINT_NOISE_PX = 0.3  # the point-heavy capture's marker noise, the wand blobs' own
# VmHWM, not ru_maxrss: Linux carries ru_maxrss over from the forking bench through exec
PROBE = ("import sys; from wandcal.service.cli import main; code = main(); "
         "print(next(l.split()[1] for l in open('/proc/self/status') if l.startswith('VmHWM:')), file=sys.stderr); "
         "sys.exit(code)")
# the stage profile counts the process's CPU seconds, not wall seconds: the machine is shared, and
# another job's load stretches wall time unevenly between runs (BLAS may use both cores: CPU
# seconds can exceed wall seconds)
PROFILE = ("import cProfile, sys, time; from wandcal.service.cli import main; from wandcal.service.cli.support.batch_memory import keep_freed_memory; "
           "keep_freed_memory(); p = cProfile.Profile(time.process_time); "
           "code = p.runcall(main, sys.argv[2:]); p.dump_stats(sys.argv[1]); sys.exit(code)")
# stage: (caller, callee) function names whose cumulative time (the callee's, called from that
# caller) makes the stage; the rest of the process is "other" (start-up, imports, the summary). The
# names are calib/run/calibrate.py's steps since issue 30 (before this session the table still
# looked for the pre-issue-30 names and gave 0 s to every stage but read and write); the first
# steps' names are calib/run/start_steps.py's since that module was split from calibrate.py
STAGES = {
    "read": [("_calibrated", "read_capture")],
    "start": [("calibrate", "observations"), ("refinement_start", "static_object_poses"),
              ("refinement_start", "check_capture"), ("refinement_start", "initial_poses")],
    "labelling": [("refinement_start", "label_ends")],
    "refinement": [("calibrate", "_refine")],
    "world frame": [("calibrate", "_world")],
    "reports": [("calibrate", "_figures")],
    "judgement": [("calibrate", "_judgement")],
    "write": [("run_calibrate", "to_json"), ("run_calibrate", "_write_result")],
}


# The processes timed here run as an installed package does: from compiled bytecode (a pip
# install writes it). PYTHONDONTWRITEBYTECODE, set on some machines (this one), made every process
# compile wandcal's ~50 modules again: 0.07 s wall, 0.1 s CPU of each run. The bytecode goes to
# its own folder, not into the checkout.
PYCACHE = Path(tempfile.gettempdir()) / "wandcal-bench-pycache"


def child_env(pythonpath: Path | None = None) -> dict[str, str]:
    """The environment of a timed `wandcal` process: bytecode cached under :data:`PYCACHE`, and
    ``pythonpath`` (another checkout's view) first on the path when given."""
    import os

    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"} | {"PYTHONPYCACHEPREFIX": str(PYCACHE)}
    return env | ({"PYTHONPATH": str(pythonpath)} if pythonpath is not None else {})


def warm_bytecode(pythonpath: Path | None = None) -> None:
    """Compile the modules `wandcal calibrate` imports into :data:`PYCACHE`, untimed."""
    subprocess.run([sys.executable, "-c", "import wandcal.service.cli.calibrate, wandcal.service.cli"], check=True, cwd=REPO,
                   env=child_env(pythonpath))


# in a child process, as `wandcal simulate` does (seed 1), but past the command's 64-camera cap
SIMULATE = ("import json, sys; from pathlib import Path; from wandcal.calib.sim.simulate import simulate_capture; "
            "from wandcal.capture.folder import write_capture; out = Path(sys.argv[1]); "
            "sim = simulate_capture(int(sys.argv[2]), int(sys.argv[3]), 0.3, float(sys.argv[4]), True, 1); "
            "write_capture(out, sim.rig, sim.wand, sim.static); "
            "(out / 'truth.json').write_text(json.dumps(sim.truth.to_json(sim.rig)))")


# a rig of calib/sim/shapes.py instead (each frame in 2-4 cameras, |k1| to 0.1), as `wandcal simulate --shape`
SIMULATE_SHAPE = ("import json, sys; from pathlib import Path; from wandcal.calib.sim.shapes import RigShape, default_size, "
                  "simulate_shape; from wandcal.capture.folder import write_capture; out = Path(sys.argv[1]); "
                  "kind = sys.argv[5]; shape = RigShape(kind, int(sys.argv[2]), default_size(kind)); "
                  "sim = simulate_shape(shape, int(sys.argv[3]), 0.3, float(sys.argv[4]), 1); "
                  "write_capture(out, sim.rig, sim.wand, sim.static); "
                  "(out / 'truth.json').write_text(json.dumps(sim.truth.to_json(sim.rig)))")


def simulate(folder: Path, cameras: int, frames: int, outliers: float = OUTLIERS, shape: str | None = None) -> None:
    """A capture folder and its truth.json: `wandcal simulate`'s rig (0.3 px, L-frame, seed 1), or
    with ``shape`` ("ring", "dome", "tiers", "hallway") `wandcal simulate --shape`'s at its default size."""
    code, extra = (SIMULATE, []) if shape is None else (SIMULATE_SHAPE, [shape])
    subprocess.run([sys.executable, "-c", code, str(folder), str(cameras), str(frames), str(outliers), *extra],
                   check=True, capture_output=True, cwd=REPO)


def add_points(folder: Path, cameras: int, wand_frames: int, point_frames: int, seed: int = 5) -> int:
    """Write a point-heavy capture: the simulator's wand and L-frame, and ``point_frames`` single
    markers spread through the volume, each seen by every camera it falls in. Returns the number
    of point observations."""
    from wandcal.calib.geometry import distort_points, project_normalized
    from wandcal.calib.rig import PointObservations
    from wandcal.calib.sim.simulate import simulate_capture
    from wandcal.capture.folder import write_capture

    sim = simulate_capture(cameras, wand_frames, POINT_NOISE_PX, OUTLIERS, True, 1)
    rng = np.random.default_rng(seed)
    X = rng.uniform([-0.9, -0.9, 0.3], [0.9, 0.9, 1.7], (point_frames, 3))
    cams = sim.rig.cameras
    uv = np.stack([distort_points(c, project_normalized(sim.truth.R[i], sim.truth.t[i], X)) for i, c in enumerate(cams)], 1)
    uv += rng.normal(0, POINT_NOISE_PX, uv.shape)
    inside = (uv[..., 0] > 0) & (uv[..., 0] < cams[0].width) & (uv[..., 1] > 0) & (uv[..., 1] < cams[0].height)
    frame, camera = np.nonzero(inside)
    # point frames after the wand's, so no capture frame holds both
    write_capture(folder, sim.rig, sim.wand, sim.static, PointObservations(frame + wand_frames, camera, uv[frame, camera]))
    (folder / "truth.json").write_text(json.dumps(sim.truth.to_json(sim.rig)))
    return len(frame)


def centre_error_mm(result: Path, truth: Path) -> float:
    """RMS camera-centre error of a result against the simulator's truth, after a similarity alignment."""
    cams = json.loads(result.read_text())["cameras"]
    true = {c["id"]: c["center"] for c in json.loads(truth.read_text())["cameras"]}
    return aligned_rms_mm(np.array([c["center"] for c in cams]), np.array([true[c["id"]] for c in cams]))


def run_process(folder: Path, out: Path, profile: Path | None = None) -> tuple[float, float, float]:
    """(wall seconds, peak RSS MB, CPU seconds: user + system) of one `wandcal calibrate` process,
    optionally under cProfile."""
    import resource

    cmd = [sys.executable, "-c", PROBE, "calibrate", str(folder), "--quiet", "--out", str(out)]
    if profile is not None:
        cmd = [sys.executable, "-c", PROFILE, str(profile), "calibrate", str(folder), "--quiet", "--out", str(out)]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(cmd, check=True, capture_output=True, text=True, cwd=REPO, env=child_env())
    seconds = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    peak = float(done.stderr.strip().splitlines()[-1]) / 1024 if profile is None else float("nan")
    return seconds, peak, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def stage_seconds(profile: Path) -> dict[str, float]:
    """Each stage's cumulative seconds from a cProfile dump, attributed by caller."""
    stats = pstats.Stats(str(profile)).stats  # type: ignore[attr-defined]
    out = {}
    for stage, pairs in STAGES.items():
        total = 0.0
        for caller, callee in pairs:
            for func, (_, _, _, _, callers) in stats.items():
                if func[2] != callee:
                    continue
                total += sum(ct for c, (_, _, _, ct) in callers.items() if c[2] == caller)
        out[stage] = total
    whole = max(ct for (_, _, _, ct, _) in stats.values())
    out["other"] = whole - sum(out.values())
    out["whole"] = whole
    return out


def checkout_view(checkout: Path, into: Path) -> Path:
    """A directory that imports ``wandcal`` from another checkout (its four folders under
    wandcal/), ahead of this one's editable install when put on PYTHONPATH. The folder holds an
    ``__init__.py``: without one it is only a namespace portion, which the editable install's finder
    outranks, and the "other checkout" ran this one's code (as bench_against_base.namespace does)."""
    (into / "wandcal").mkdir(parents=True, exist_ok=True)
    (into / "wandcal" / "__init__.py").touch()
    for top in ("calib", "capture", "drivers", "service"):
        link = into / "wandcal" / top
        if not link.exists():
            link.symlink_to(checkout.resolve() / top)
    return into


def cpu_run(folder: Path, out: Path, pythonpath: Path | None, method: str = "ba") -> tuple[float, float]:
    """(wall seconds, CPU seconds) of one `wandcal calibrate` process (CPU: user + system of the child)."""
    import resource

    env = child_env(pythonpath)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "wandcal.service.cli", "calibrate", str(folder), "--quiet", "--out", str(out),
                    "--method", method], check=True, capture_output=True, cwd=REPO, env=env)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def alternated(folder: Path, tmp: Path, variants: dict[str, tuple[Path | None, str]], repeats: int):
    """Each variant (name -> (checkout on PYTHONPATH or None for this one, method)) run as a whole
    `wandcal calibrate` process on ``folder``, alternated run by run: ({name: median (wall, CPU)},
    the median over the rounds of the last variant's CPU over the first's, {name: centre error mm})."""
    runs: dict[str, list] = {name: [] for name in variants}
    errors = {}
    for _ in range(repeats):
        for name, (path, method) in variants.items():
            out = tmp / f"{name}.json"
            runs[name].append(cpu_run(folder, out, path, method))
            errors[name] = centre_error_mm(out, folder / "truth.json")
        print(folder.name, runs, flush=True)
    first, last = runs[next(iter(variants))], runs[list(variants)[-1]]
    ratio = float(np.median([x[1] / y[1] for x, y in zip(last, first)]))
    return {name: np.median(r, axis=0) for name, r in runs.items()}, ratio, errors
