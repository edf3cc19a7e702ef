"""Knocks on real sessions against what the step test can tell (issue 31, decision 0083).

For each knock the judgement's own step test on the knocked camera (its first test in ``calibrate``,
:func:`wandcal.calib.judge.faults.pose_steps.pose_step`) gives the turn it estimates, its standard
deviation and ``detectable_deg``: the turn the test names at that split (noise-free, 50% power,
:func:`wandcal.calib.judge.faults.pose_steps.detectable_turn`). A knock is *determinable* when its
turn is at least that bound; the table counts the knocks named on their camera among the determinable
and the others, and every ``moved`` named on another camera.

Cases: ``--listed`` the real-faults bench's knock rows (bench/real_faults.py: the middle of the shared
frames, 0.47 and 0.82 deg); by default the held-out grid: every camera of each session, the turns of
``--degrees`` about the axis of each ``--seeds``, at the shares ``--at`` of the camera's shared frames.

    python bench/bench_knock_bound.py --listed
    python bench/bench_knock_bound.py [--sessions brown1,...] [--degrees 0.3,0.6,1,2] [--at 0.35,0.65] [--seeds 7]

Prints only: docs/benchmarks.md is not written.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench import real_faults as rf
from bench.bench_real_subsamples import StepRecorder
from bench.fault_injectors import _rotated, timed_observations
from wandcal.calib.errors import CalibrationError
from wandcal.calib.geometry import rotvec_to_matrix
from wandcal.calib.judge.faults.f_distribution import critical_f
from wandcal.calib.judge.faults.pose_steps import STEP_ALPHA, detectable_turn
from wandcal.calib.rig import PointObservations, WandObservations


def knock_at(obs, c: int, share: float) -> float:
    """The frame at ``share`` of camera c's frames that another camera sees too (all its frames where none is)."""
    mine = obs.camera == c
    shared = mine & np.isin(obs.frame, obs.frame[~mine])
    frames = np.unique(obs.frame[shared if shared.any() else mine])
    return float(frames[min(int(share * len(frames)), len(frames) - 1)]) + 0.5


def knock_axis(seed: int) -> np.ndarray:
    """(3,) the knock's axis in the camera's frame, as bench/fault_injectors.knocked draws it from ``seed``."""
    axis = np.random.default_rng(seed).normal(size=3)
    return axis / np.linalg.norm(axis)


def knocked(session: rf.Session, c: int, degrees: float, seed: int, share: float) -> rf.Session:
    """Camera c turned by ``degrees`` about a random axis (``seed``) after ``share`` of its shared
    frames (as bench/fault_injectors.knocked, which knocks at their middle)."""
    axis = knock_axis(seed)
    Rk = rotvec_to_matrix(np.radians(degrees) * axis / np.linalg.norm(axis))
    out, at = session, None
    for name, obs in timed_observations(session):
        at = knock_at(obs, c, share) if at is None else at
        uv = obs.uv.copy()
        after = (obs.camera == c) & (obs.frame > at)
        uv[after] = _rotated(session.rig.cameras[c], obs.uv[after], Rk)
        moved = PointObservations(obs.frame, obs.camera, uv, point=obs.point) if name == "points" else \
            WandObservations(obs.frame, obs.camera, uv)
        out = replace(out, **{name: moved})
    return out


def run_one(session: rf.Session, c: int, label: str, knocked_session: rf.Session, knock: tuple[float, np.ndarray],
            recorder: StepRecorder) -> dict:
    """One knock (degrees, axis (3,)) judged: the camera's first step test, the turn it names about
    the knock's axis (its bound), and every ``moved`` named."""
    degrees, axis = knock
    recorder.take()
    try:
        doc = rf.calibrated(knocked_session).to_json()
    except CalibrationError as e:
        return {"session": session.name, "label": label, "degrees": degrees, "refused": str(e)[:60], "camera": ""}
    steps = dict(recorder.take())
    ids = [cam.id for cam in session.rig.cameras]
    moved = [f["camera"] for f in doc["verdict"]["faults"] if f["kind"] == "moved"]
    s = steps.get(c)
    return {"camera": ids[c], "session": session.name, "label": label, "degrees": degrees, "step": s,
            "bound": float("nan") if s is None else s.detectable_along(axis),
            "oracle": float("nan") if s is None else independent_bound(s, axis),
            "faults": [f"{f['kind']} {f['camera']}" for f in doc["verdict"]["faults"]],
            "named": ids[c] in moved, "other": [m for m in moved if m != ids[c]]}


def independent_bound(s, axis: np.ndarray) -> float:
    """The bound were the camera's timed views independent (no batch means: the inflation taken out
    and the views' own dof): what the step test could name if the residuals' run in time were known
    to be nil, the most it could do on these views."""
    if s.turn_cov is None:
        return float("nan")
    return detectable_turn(s.turn_cov / s.inflation, axis, critical_f(3, s.views_dof, STEP_ALPHA / s.splits))


def cases(session: rf.Session, listed: bool, degrees: list[float], shares: list[float], seeds: list[int]):
    """(camera, label, knocked session, (degrees, axis)) of each case."""
    if listed:
        for case in rf.cases(session):
            if case.family == "knock":
                yield case.camera, case.label, rf.inject(session, case, []), (case.size, knock_axis(rf._seed(case)))
        return
    for c, cam in enumerate(session.rig.cameras):
        for d in degrees:
            for share in shares:
                for seed in seeds:
                    yield (c, f"{cam.id} {d:g} deg at {share:g} seed {seed}", knocked(session, c, d, seed, share),
                           (d, knock_axis(seed)))


def line(r: dict) -> str:
    if "refused" in r:
        return f"{r['session']:<20} {r['label']:<34} refused: {r['refused']}"
    s = r["step"]
    if s is None:
        return (f"{r['session']:<20} {r['label']:<34} no step test (too few timed views)  named {r['named']} other {r['other']}; "
                f"faults {', '.join(r['faults']) or '-'}")
    return (f"{r['session']:<20} {r['label']:<34} step {s.degrees:.2f} +- {s.degrees_std:.2f} deg at {s.frame}, p {s.p_value:.2g}, "
            f"detectable about the knock's axis {r['bound']:.2f} deg (its own {s.detectable_deg:.2f}): "
            f"{'above' if r['degrees'] >= r['bound'] else 'below'}; independent views {r['oracle']:.2f}; "
            f"named {r['named']}{'; other ' + ','.join(str(m) for m in r['other']) if r['other'] else ''}; faults {', '.join(r['faults']) or '-'}")


def summary(rows: list[dict]) -> str:
    ok = [r for r in rows if "refused" not in r]
    det = [r for r in ok if r["step"] is not None and r["degrees"] >= r["bound"]]
    und = [r for r in ok if r not in det]
    indep = [r for r in ok if r["step"] is not None and r["degrees"] >= r["oracle"]]
    return (f"above the bound were the views independent: {len(indep)}, named {sum(r['named'] for r in indep)}\n"
            f"knocks named as another fault on their camera: "
            f"{sum(any(f.endswith(' ' + r['camera']) for f in r['faults']) and not r['named'] for r in ok)}\n" + f"knocks {len(rows)} (refused {len(rows) - len(ok)}): named on their camera {sum(r['named'] for r in ok)}; "
            f"determinable {len(det)}, named {sum(r['named'] for r in det)}; below the bound (or untested) {len(und)}, "
            f"named {sum(r['named'] for r in und)}; moved named on another camera {sum(len(r['other']) for r in ok)}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", default="brown1,brown2,ushichka,svoboda,cpp")
    ap.add_argument("--listed", action="store_true", help="the real-faults bench's knock rows")
    ap.add_argument("--degrees", default="0.3,0.6,1,2")
    ap.add_argument("--at", default="0.35,0.65", help="shares of the camera's shared frames")
    ap.add_argument("--seeds", default="7")
    a = ap.parse_args()
    if not rf.available():
        print(f"no data at {rf.SHARED_DATA}")
        return 0
    degrees = [float(x) for x in a.degrees.split(",")]
    shares = [float(x) for x in a.at.split(",")]
    seeds = [int(x) for x in a.seeds.split(",")]
    rows: list[dict] = []
    start = time.process_time()
    with StepRecorder() as rec:
        for session in rf.load_sessions(a.sessions.split(",")):
            for c, label, k, knock in cases(session, a.listed, degrees, shares, seeds):
                rows.append(run_one(session, c, label, k, knock, rec))
                print(line(rows[-1]), flush=True)
    print(summary(rows))
    print(f"CPU {time.process_time() - start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
