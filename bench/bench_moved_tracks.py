"""The moved camera from point tracks in the wand's time (docs/decisions/0051): simulated sparse
rigs, clean and with one camera knocked, judged with the tracks timed and as another recording.

Each seed: a ring of CAMERAS (calib/sim, 0.3 px, L-frame), its wand kept in ring pairs of cameras
(calib/sim/scenes.pairwise_wand) on WAND_SHARE of the frames, POINTS point tracks in ring pairs at
random frames within the wand's; the knocked case turns one camera, drawn from the seed, by 0.3-1
degree about a random axis after the middle of its wand frames (its wand and its tracks after it).
*in time*: the tracks as made; *another recording*: the same tracks numbered from the power of
ten above every wand frame, as ``wandcal import`` numbers background points (the step test then
gives them a turn of their own, as every track beside a wand had before 0051).

Usage: python bench/bench_moved_tracks.py [--cameras 3,4,8] [--seeds 8] [--frames 1000]
       [--points 400] [--wand-share 0.1]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from wandcal.calib.geometry import distort_points, rotvec_to_matrix, undistort_points
from wandcal.calib.rig import PointObservations, WandObservations
from wandcal.calib.run.calibrate import calibrate
from wandcal.calib.sim.scenes import pairwise_points, pairwise_wand
from wandcal.calib.sim.simulate import simulate_capture

KNOCK_DEG = (0.3, 1.0)
NOISE_PX = 0.3


def _turned(cam, uv: np.ndarray, Rk: np.ndarray) -> np.ndarray:
    """(B, 2) raw pixels of camera ``cam`` after it turned by Rk (camera frame)."""
    ray = np.concatenate([undistort_points(cam, uv), np.ones((len(uv), 1))], axis=1) @ Rk.T
    return distort_points(cam, ray[:, :2] / ray[:, 2:])


def scene(seed: int, cameras: int, frames: int, points: int, wand_share: float, knock: bool):
    """(sim, wand, points, (camera id, degrees, frame) of the knock or None)."""
    sim = simulate_capture(cameras, frames, NOISE_PX, 0.0, True, seed)
    rng = np.random.default_rng(seed + 1000)
    wand = pairwise_wand(sim, rng)
    kept = (rng.random(frames) < wand_share)[wand.frame]
    wand = WandObservations(wand.frame[kept], wand.camera[kept], wand.uv[kept])
    pts = pairwise_points(sim, points, rng, noise_px=NOISE_PX)
    at_frames = np.sort(rng.choice(frames, points, replace=False))
    pts = PointObservations(at_frames[pts.frame], pts.camera, pts.uv)
    if not knock:
        return sim, wand, pts, None
    c, degrees = int(rng.integers(cameras)), float(rng.uniform(*KNOCK_DEG))
    axis = rng.normal(size=3)
    Rk = rotvec_to_matrix(np.radians(degrees) * axis / np.linalg.norm(axis))
    at = float(np.median(wand.frame[wand.camera == c]))
    cam = sim.rig.cameras[c]
    after = (wand.camera == c) & (wand.frame > at)
    uv = wand.uv.copy()
    uv[after] = _turned(cam, wand.uv[after], Rk)
    wand = WandObservations(wand.frame, wand.camera, uv)
    after = (pts.camera == c) & (pts.frame > at)
    uv = pts.uv.copy()
    uv[after] = _turned(cam, pts.uv[after], Rk)
    return sim, wand, PointObservations(pts.frame, pts.camera, uv), (cam.id, degrees, at)


def another_recording(pts: PointObservations, wand: WandObservations) -> PointObservations:
    """The tracks numbered from the power of ten above every wand frame (docs/import.md)."""
    first = 10 ** len(str(int(wand.frame.max()) + 1))
    return PointObservations(pts.frame + first, pts.camera, pts.uv)


def faults(sim, wand, pts) -> list[tuple[str, str]]:
    doc = calibrate(sim.rig, wand, sim.static, points=pts).to_json()
    return sorted((f["kind"], f["camera"]) for f in doc["verdict"]["faults"])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cameras", default="3,4,8")
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--frames", type=int, default=1000)
    ap.add_argument("--points", type=int, default=400)
    ap.add_argument("--wand-share", type=float, default=0.1)
    args = ap.parse_args()
    rows = []
    for n in (int(c) for c in args.cameras.split(",")):
        tally = {mode: [0, 0, 0] for mode in ("another recording", "in time")}  # clean named, knock right, knock elsewhere
        for seed in range(1, args.seeds + 1):
            for knock in (False, True):
                sim, wand, pts, truth = scene(seed, n, args.frames, args.points, args.wand_share, knock)
                line = []
                for mode, p in (("another recording", another_recording(pts, wand)), ("in time", pts)):
                    named = faults(sim, wand, p)
                    moved = [cam for kind, cam in named if kind == "moved"]
                    if truth is None:
                        tally[mode][0] += bool(named)
                    else:
                        tally[mode][1] += moved == [truth[0]]
                        tally[mode][2] += any(cam != truth[0] for cam in moved)
                    line.append(f"{mode}: {named}")
                what = "clean" if truth is None else f"{truth[0]} {truth[1]:.2f} deg after frame {truth[2]:.0f}"
                print(f"{n} cameras seed {seed} {what} | " + " | ".join(line), flush=True)
        a, b = tally["another recording"], tally["in time"]
        s = args.seeds
        rows.append(f"| {n} | 1-{s} | {a[0]} / {b[0]} of {s} | {a[1]} / {b[1]} of {s} | {a[2]} / {b[2]} |")
    print("\n| cameras | seeds | clean: a fault named, another recording / in time | knock named `moved` on its "
          "camera | `moved` on another camera |\n|---|---|---|---|---|")
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
