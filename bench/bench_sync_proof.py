"""Whether ``frame_offsets(..., prove_sparse=True)`` (what ``calibrate --sync auto`` calls, decision
0081) gives the default search's answer on the inputs the sync tests and benches use: the same
offsets, TooFewShared where the default raises it (calibrate then falls back to the triangulation
search, whatever the message), or the same refusal message; and the CPU seconds of each.

Inputs: bench_sync's 16 x 2500 (in time, and +-5 frames plus fractions), bench_sync_accuracy's
16 x 2500 and 8 x 1500 (seeds 1-6), bench_sync_markers' 5 x 600 three-marker wand (seeds 4-6),
bench_scale's shapes (ring, dome, tiers, hallway) at 32 and 128 cameras x 3000 (and the hallway with four
cameras 1-2 frames out), tests/calib/
test_sparse_offsets.py's 64-camera ring, and the real sessions with a wand (Brown 1 and 2 as
recorded and with cam3 two frames out, the easyWand C++ sample, Ushichka); each at +-8 (calibrate's
default) and +-3 frames.

    python bench/bench_sync_proof.py [--only hallway] [--no-write]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.common import publish

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"


def _inputs():
    """(name, a function giving (rig, pairs)), each pair of cameras' end pairs on their own frame numbers."""
    from bench.bench_sync_accuracy import offsets as accuracy_offsets
    from bench.matrix_inputs import CW500_M
    from wandcal.calib.rig import WandObservations
    from wandcal.calib.sim.shapes import RigShape, default_size, simulate_shape
    from wandcal.calib.sim.simulate import simulate_capture
    from wandcal.calib.start.markerlabels import end_pairs

    def sim(s):
        return s.rig, end_pairs(s.rig, s.wand)

    rng = np.random.default_rng(1)
    late = rng.integers(-5, 6, 16) + rng.uniform(-0.5, 0.5, 16)
    late[0] = 0.0
    yield "bench_sync 16x2500 in time", lambda: sim(simulate_capture(16, 2500, 0.3, static=False, seed=1))
    yield "bench_sync 16x2500 +-5", lambda: sim(simulate_capture(16, 2500, 0.3, static=False, seed=1, offsets=late))
    for n, frames in ((16, 2500), (8, 1500)):
        for seed in range(1, 7):
            yield f"accuracy {n}x{frames} seed {seed}", lambda n=n, f=frames, s=seed: sim(simulate_capture(
                n, f, 0.3, static=False, seed=s, offsets=accuracy_offsets(n, s)))
    for seed in (4, 5, 6):
        yield f"markers 5x600 seed {seed}", lambda s=seed: sim(simulate_capture(
            5, 600, 0.3, 0.0, False, s, wand_markers=CW500_M, offsets=np.array([0.0, 0.0, 2.3, 0.0, 0.0])))
    yield "ring 64x1500 (test_sparse_offsets)", lambda: sim(simulate_shape(
        RigShape("ring", 64, default_size("ring")), 1500, 0.3, 0.02, seed=3))
    for kind in ("ring", "dome", "tiers", "hallway"):
        for n in (32, 128):
            yield f"{kind} {n}x3000", lambda k=kind, n=n: sim(simulate_shape(RigShape(k, n, default_size(k)), 3000, 0.3, 0.02, 1))
    def hallway_late():  # 4 cameras 1-2 frames out: the pairs the sync meets on a hallway without a trigger
        s = simulate_shape(RigShape("hallway", 128, default_size("hallway")), 3000, 0.3, 0.02, 1)
        true = np.zeros(128, np.int64)
        true[[10, 45, 80, 115]] = [1, 2, -1, -2]
        return s.rig, end_pairs(s.rig, WandObservations(s.wand.frame - true[s.wand.camera], s.wand.camera, s.wand.uv))
    yield "hallway 128x3000, 4 cameras 1-2 frames out", hallway_late
    if DATA.exists():
        from wandcal.capture.importers.easywand import read_easywand_mat

        for session in (1, 2):
            for late_frames in (0, 2):
                def brown(session=session, late_frames=late_frames):
                    cap = read_easywand_mat(DATA / f"easywand_brown_windtunnel_4cam/calibration{session}/"
                                            "extrinsicCalib_20230228_easyWandData.mat").capture
                    w = cap.wand
                    w = WandObservations(np.where(w.camera == 2, w.frame + late_frames, w.frame), w.camera, w.uv)
                    return cap.rig, end_pairs(cap.rig, w)
                yield f"Brown {session}" + (f", cam3 {late_frames} frames out" if late_frames else ""), brown

        def ushichka():
            cap = read_easywand_mat(DATA / "easywand_ushichka_thermal_3cam/round3_2018-07-28_easyWandData.mat",
                                    height=512).capture
            return cap.rig, end_pairs(cap.rig, cap.wand)
        yield "Ushichka", ushichka


def _outcome(rig, pairs, window: int, **kw) -> tuple[str, float]:
    from wandcal.calib.errors import CalibrationError
    from wandcal.calib.start.offsets.whole_frames import TooFewShared, frame_offsets

    t = time.process_time()
    try:
        found = frame_offsets(rig, pairs, window, **kw)
        out = "offsets " + ",".join(str(int(v)) for v in found.offsets) + f" share {np.round(found.share, 6).tolist()}"
    except TooFewShared:
        out = "TooFewShared"
    except CalibrationError as exc:
        out = f"refused: {exc}"
    return out, time.process_time() - t


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", help="inputs whose name contains this")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    rows = ["| input | window | default | prove_sparse | same | CPU s default / prove_sparse |", "|---|---|---|---|---|---|"]
    differ = 0
    for name, make in _inputs():
        if args.only and args.only not in name:
            continue
        rig, pairs = make()
        for window in (8, 3):
            old, t_old = _outcome(rig, pairs, window)
            new, t_new = _outcome(rig, pairs, window, prove_sparse=True)
            differ += old != new
            short = [o if o.startswith(("TooFew", "refused")) else o.split(" share")[0] for o in (old, new)]
            rows.append(f"| {name} | +-{window} | {short[0][:90]} | {'same' if old == new else short[1][:90]} | "
                        f"{'yes' if old == new else '**no**'} | {t_old:.2f} / {t_new:.2f} |")
            print(rows[-1], flush=True)
    body = "\n".join(rows) + f"\n\n{differ} of {len(rows) - 2} differ."
    publish("Sync: the sparse proof against the default search", body, not args.no_write)
    return 1 if differ else 0


if __name__ == "__main__":
    raise SystemExit(main())
