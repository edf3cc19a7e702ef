"""Fresh faults: a third table of the judgement on real sessions, drawn from a seed, that nobody tuned on.

The listed faults (bench/real_faults.py) and the held-out ones (bench/held_out_faults.py) were both
looked at while the judgement was designed. Here every fault's size and target camera are drawn
from ``--fresh SEED`` (``python bench/bench_real_faults.py --fresh 101,102``) from ranges that are
realistic and differ from both: :data:`DRAWS` cases per family, session and seed, on any camera of
the session (not only the two fixed targets). The sessions and their clean runs are
bench/real_faults.py's; a single fault is scored by :func:`bench.real_faults.run_case` and a swap by
:func:`bench.held_out_faults.run_held_out_case`, unchanged.

| family | what is changed (drawn per case) | expected kind |
|---|---|---|
| focal | focal length times 1 ± 1-4% | ``intrinsics`` (or limited: focal length) |
| principal | principal point moved 1-3% of the width in a random direction | ``intrinsics`` (or absorbed, limited: cx/cy) |
| k1 | k1 ± 0.02-0.08 added | ``intrinsics`` (or limited: k1) |
| tangential | p1, p2 each ± 0.001-0.004 added | ``intrinsics`` (or absorbed, limited: p1/p2) |
| knock | turned 0.3-3° about a random axis after a random 25-75% of its shared frames (bench/bench_knock_bound.py's knock) | ``moved`` |
| noise | Gaussian noise, 1.5-4x the camera's own in all | ``noise`` (or at the limit) |
| timing | late or early by 0.3-3 frames (whole and fractional alike) | ``timing`` |
| slow clock | its clock drifts to 0.3-3 frames late by the capture's end | ``timing`` |
| swapped | two random cameras' observations swapped | as the held-out swap |
| wand length | the wand's length ± 1-5% | ``wand_scale`` (undeterminable here: no second length) |
| subsample | a random 40-80% of the frames, no fault | no camera, not poorer than the clean run |
| subsample + fault | one of the camera faults above, then a 40-80% subsample | that fault's kind and rules |
| two faults | two of the camera faults above on two different cameras | both, each by its own rules |

Timing faults (and a timing fault drawn for the last two rows) go only on cameras whose samples are
consecutive frames (:meth:`bench.real_faults.Session.consecutive`), as in the other tables.

Rules for the new rows, fixed before the first run, from what issue 31 calls right ("right",
"no fault named on the wrong camera"), with no threshold of their own:

- *subsample + fault* is scored exactly as the single fault it carries (the same ``run_case``,
  its family's absorbed / limited / at-the-limit rules), only counted in its own row.
- *two faults* on cameras A and B is right when each target is right by its own family's rule
  taken on that camera alone (its kind named on it; or, for an absorbable family, nothing named on
  it and it moved within :data:`bench.fault_scores.ABSORBED_SIGMAS` of its geometry sigma; or, for
  a limitable one, the verdict's limits name its intrinsic on it and it moved within 3 honest
  sigma; or, for noise, its noise said to be at the limit of poor) and no fault is named on a
  third camera. The rig may be poor (the faults make it so): the single rule's "not poor" for an
  absorbed principal point is dropped here. A refusal is wrong (one camera out of time does not
  account for the other fault). *wrong camera*: a third camera named; *wrong kind*: a target named
  with another kind than its own fault's; else *missed*.
"""

from __future__ import annotations

import json
import time
import zlib
from dataclasses import dataclass, replace

import numpy as np

from bench import held_out_faults as ho
from bench import real_faults as rf
from bench.bench_knock_bound import knocked as knocked_at
from bench.common import aligned_centres_mm
from bench.fault_injectors import late, noisy, subsample, wand_off, with_focal
from bench.fault_scores import ABSORBED_SIGMAS, at_limit_lines, covered, noise_at_limit_named
from bench.real_sessions import BROWN, SHARED_DATA, USHICHKA
from wandcal.calib.errors import CalibrationError

DRAWS = 2  # cases per family, session and seed
RANGES = {"focal": (0.01, 0.04), "principal": (0.01, 0.03), "k1": (0.02, 0.08), "tangential": (0.001, 0.004),
          "knock": (0.3, 3.0), "knock at": (0.25, 0.75), "noise": (1.5, 4.0), "timing": (0.3, 3.0),
          "slow clock": (0.3, 3.0), "wand length": (0.01, 0.05), "share": (0.4, 0.8)}
SINGLE = ("focal", "principal", "k1", "tangential", "knock", "noise", "timing")  # the faults a subsample or a pair carries
FRESH_FAMILIES = (*SINGLE, "slow clock", "swapped", "wand length", "subsample", "subsample + fault", "two faults")
EXPECTED = {"focal": "intrinsics", "principal": "intrinsics", "k1": "intrinsics", "tangential": "intrinsics",
            "knock": "moved", "noise": "noise", "timing": "timing", "slow clock": "timing", "swapped": None,
            "wand length": "wand_scale", "subsample": None}
NOTES = {"wand length": rf.UNDETERMINABLE["wand length"]}


@dataclass(frozen=True)
class FreshCase(rf.Case):
    """A drawn case. row: the table's row (``family`` is the fault the case is scored as); draw: the
    fault's further draws (a direction, where a knock falls, p1 and p2, a subsample's share and
    seed, a seed); second: a pair's second fault (on ``second.camera``), or None."""

    row: str = ""
    draw: tuple = ()
    second: FreshCase | None = None


# -- drawing the cases -----------------------------------------------------------------------

def _single(session: rf.Session, rng: np.random.Generator, family: str, c: int, row: str) -> FreshCase:
    """One camera fault of ``family`` on camera c, its size and further draws from ``rng``."""
    cam = session.rig.cameras[c].id
    sign = float(rng.choice((-1.0, 1.0)))
    lo, hi = RANGES[family]
    size = float(rng.uniform(lo, hi))
    seed = int(rng.integers(2**31))
    if family == "focal":
        size, draw, label = 1 + sign * size, (seed,), f"focal {100 * sign * size:+.1f}%"
    elif family == "principal":
        angle = float(rng.uniform(0, 2 * np.pi))
        draw, label = (angle, seed), f"principal point {100 * size:.1f}% at {np.degrees(angle):.0f} deg"
    elif family == "k1":
        size, draw, label = sign * size, (seed,), f"k1 {sign * size:+.3f}"
    elif family == "tangential":
        p = (sign * size, float(rng.choice((-1.0, 1.0)) * rng.uniform(lo, hi)))
        draw, label = (*p, seed), f"p1 {p[0]:+.4f}, p2 {p[1]:+.4f}"
    elif family == "knock":
        at = float(rng.uniform(*RANGES["knock at"]))
        draw, label = (at, seed), f"knocked {size:.2f} deg at {100 * at:.0f}%"
    elif family == "noise":
        draw, label = (seed,), f"noise {size:.2f}x"
    elif family == "timing":
        size, draw, label = sign * size, (seed,), f"{'late' if sign > 0 else 'early'} {size:.2f} frame"
    elif family == "slow clock":
        draw, label = (seed,), f"clock slow to {size:.2f} frame"
    else:
        raise ValueError(f"not a camera fault: {family!r}")
    return FreshCase(session.name, family, f"{label} {cam}", c, size, EXPECTED[family], row=row or family, draw=draw)


def _timeable(session: rf.Session) -> list[int]:
    return [c for c in range(len(session.rig.cameras)) if session.consecutive(c)]


def _camera_fault(session: rf.Session, rng: np.random.Generator, row: str, exclude: int | None = None) -> FreshCase:
    """A camera fault drawn from :data:`SINGLE` (timing only where some camera can be shifted) on a
    random camera other than ``exclude``."""
    cams = [c for c in range(len(session.rig.cameras)) if c != exclude]
    families = [f for f in SINGLE if f != "timing" or set(_timeable(session)) - {exclude}]
    family = str(rng.choice(families))
    pool = [c for c in cams if c in _timeable(session)] if family == "timing" else cams
    return _single(session, rng, family, int(rng.choice(pool)), row)


def fresh_cases(session: rf.Session, seed: int) -> list[FreshCase]:
    """:data:`DRAWS` cases of every family of :data:`FRESH_FAMILIES` on ``session``, drawn from
    ``seed`` (and the session's name), in a fixed order."""
    rng = np.random.default_rng([seed, zlib.crc32(session.name.encode())])
    n = len(session.rig.cameras)
    out: list[FreshCase] = []
    for _ in range(DRAWS):
        for family in (*SINGLE, "slow clock"):
            pool = _timeable(session) if family in ("timing", "slow clock") else list(range(n))
            if pool:
                out.append(_single(session, rng, family, int(rng.choice(pool)), family))
        a, b = (int(x) for x in rng.choice(n, 2, replace=False))
        ids = session.rig.cameras[a].id, session.rig.cameras[b].id
        out.append(FreshCase(session.name, "swapped", f"{ids[0]} and {ids[1]} swapped", a, float(b), None, row="swapped"))
        if session.rig.wand_length is not None and len(session.wand):
            factor = 1 + float(rng.choice((-1.0, 1.0))) * float(rng.uniform(*RANGES["wand length"]))
            out.append(FreshCase(session.name, "wand length", f"wand {100 * (factor - 1):+.1f}%", None, factor,
                                 "wand_scale", row="wand length"))
        share, sub_seed = float(rng.uniform(*RANGES["share"])), int(rng.integers(2**31))
        out.append(FreshCase(session.name, "subsample", f"subsample {100 * share:.0f}%", None, float(sub_seed), None,
                             row="subsample", draw=(share, sub_seed)))
        inner = _camera_fault(session, rng, "subsample + fault")
        share, sub_seed = float(rng.uniform(*RANGES["share"])), int(rng.integers(2**31))
        out.append(replace(inner, label=f"{inner.label} on {100 * share:.0f}%", draw=(*inner.draw, share, sub_seed)))
        first = _camera_fault(session, rng, "two faults")
        second = _camera_fault(session, rng, "two faults", exclude=first.camera)
        out.append(replace(first, label=f"{first.label} + {second.label}", second=second))
    return out


# -- injecting -------------------------------------------------------------------------------

def _with_camera(session: rf.Session, c: int, **changes) -> rf.Session:
    cams = list(session.rig.cameras)
    cams[c] = replace(cams[c], **changes)
    return replace(session, rig=replace(session.rig, cameras=tuple(cams)))


def _dist5(cam) -> np.ndarray:
    dist = np.zeros(max(5, len(cam.dist)))
    dist[:len(cam.dist)] = np.asarray(cam.dist, float)
    return dist


def inject_one(session: rf.Session, case: FreshCase, noise_px: list[float]) -> rf.Session:
    """The session with ``case``'s own fault (not its subsample, not its second fault)."""
    c, size, family = case.camera, case.size, case.family
    assert c is not None
    cam = session.rig.cameras[c]
    if family == "focal":
        return with_focal(session, c, size)
    if family == "principal":
        K = cam.K.copy()
        K[:2, 2] += size * cam.width * np.array([np.cos(case.draw[0]), np.sin(case.draw[0])])
        return _with_camera(session, c, K=K)
    if family == "k1":
        dist = _dist5(cam)
        dist[0] += size
        return _with_camera(session, c, dist=dist)
    if family == "tangential":
        dist = _dist5(cam)
        dist[2:4] += case.draw[:2]
        return _with_camera(session, c, dist=dist)
    if family == "knock":
        return knocked_at(session, c, size, case.draw[1], case.draw[0])
    if family == "noise":
        return noisy(session, c, noise_px[c], case.draw[0], size)
    if family == "timing":
        return late(session, c, size)
    if family == "slow clock":
        return ho.slow_clock(session, c, size)
    raise ValueError(f"not a camera fault: {family!r}")


def inject_fresh(session: rf.Session, case: FreshCase, noise_px: list[float]) -> rf.Session:
    """The session with ``case``'s fault(s) and, for a subsample row, its subsample (after the fault:
    a time shift and a knock are made from the whole track, as the camera would have recorded it)."""
    if case.family == "wand length":
        return wand_off(session, case.size)
    if case.family == "subsample":
        return subsample(session, case.draw[1], case.draw[0])
    out = inject_one(session, case, noise_px)
    if case.second is not None:
        out = inject_one(out, case.second, noise_px)
    if case.row == "subsample + fault":
        out = subsample(out, case.draw[-1], case.draw[-2])
    return out


# -- scoring ---------------------------------------------------------------------------------

def _target_right(case: FreshCase, doc: dict, named: list, centres: np.ndarray, clean: rf.Clean, ids: list[str]) -> str | None:
    """How a pair's target camera is right by its own family's rule (module docstring): ``right``,
    ``absorbed``, ``limited``, ``at the limit``; None when it is not."""
    target = ids[case.camera]
    if (case.expected, target) in named:
        return "right"
    disp = float(aligned_centres_mm(centres, clean.centres)[case.camera])
    sigma, honest = rf._sigmas_mm(doc["cameras"][case.camera])
    on_target = [kind for kind, cam in named if cam == target and (kind, cam) not in clean.faults]
    if case.family in rf.ABSORBABLE and not on_target and sigma and disp <= ABSORBED_SIGMAS * sigma:
        return "absorbed"
    limits = {lim["parameter"] for lim in doc["verdict"].get("limits") or [] if lim["camera"] == target}
    probe = rf.Outcome(case, False, doc["verdict"]["level"], named, displacement_mm=disp, sigma_mm=sigma,
                       honest_sigma_mm=honest, at_limit=at_limit_lines(doc["verdict"]))
    if rf.LIMITABLE.get(case.family, set()) & limits and covered(probe):
        return "limited"
    if case.expected == "noise" and noise_at_limit_named(probe, target):
        return "at the limit"
    return None


def run_pair(session: rf.Session, clean: rf.Clean, case: FreshCase) -> rf.Outcome:
    """Calibrate the session with a pair's two faults and score it (:func:`score_pair`)."""
    start = time.perf_counter()
    try:
        result = rf.calibrated(inject_fresh(session, case, clean.noise_px))
    except CalibrationError as exc:
        out = rf.Outcome(case, False, "refused", [], message=str(exc), seconds=time.perf_counter() - start)
        out.outcome = "refused"
        return out
    out = score_pair(case, result.to_json(), np.asarray(result.centers), clean, [c.id for c in session.rig.cameras])
    out.seconds = time.perf_counter() - start
    return out


def score_pair(case: FreshCase, doc: dict, centres: np.ndarray, clean: rf.Clean, ids: list[str]) -> rf.Outcome:
    """A pair's outcome from its result's JSON ``doc`` and camera centres (N, 3), by the module
    docstring's rule: each target right by its own family's rule, no third camera named."""
    assert case.second is not None
    named = [(f["kind"], f["camera"]) for f in doc["verdict"]["faults"]]
    ways = [_target_right(part, doc, named, centres, clean, ids) for part in (case, case.second)]
    targets = {ids[case.camera], ids[case.second.camera]}
    cams_named = {cam for kind, cam in named if cam is not None and (kind, cam) not in clean.faults}
    out = rf.Outcome(case, all(ways) and not cams_named - targets, doc["verdict"]["level"], named,
                     message=next((f["message"] for f in doc["verdict"]["faults"]), ""))
    out.displacement_mm = float(aligned_centres_mm(centres, clean.centres)[case.camera])
    out.sigma_mm, out.honest_sigma_mm = rf._sigmas_mm(doc["cameras"][case.camera])
    if out.right:
        out.outcome = next((w for w in ("limited", "absorbed", "at the limit") if w in ways), "right")
        out.limited_right = out.outcome == "limited"
    else:
        expected = {ids[part.camera]: part.expected for part in (case, case.second)}
        other_kind = any(cam in expected and kind != expected[cam] for kind, cam in named if (kind, cam) not in clean.faults)
        out.outcome = "wrong camera" if cams_named - targets else "wrong kind" if other_kind else "missed"
    return out


def run_fresh_case(session: rf.Session, clean: rf.Clean, case: FreshCase) -> rf.Outcome:
    """One fresh case run and scored (module docstring), its outcome's case put in its row."""
    if case.second is not None:
        out = run_pair(session, clean, case)
    elif case.family == "swapped":
        out = ho.run_held_out_case(session, clean, case)
    else:
        out = rf.run_case(session, clean, case, inject_fresh)
    out.case = replace(case, family=case.row)  # the table's row; scored above as case.family
    return out


# -- published figures -----------------------------------------------------------------------

def published_line(session: rf.Session) -> str:
    """The session's clean run beside what its own tool published, where it published anything:
    easyWand's wand score and per-camera DLT RMSE (Brown 1 and 2, Ushichka), MultiCamSelfCal's
    mean reprojection error (0.62 px, as bench/real_sessions.py takes it)."""
    result = rf.calibrated(session)
    w = result.wand_report
    ours = f"wand score {100 * w.length_std_m / w.length_mean_m:.3f}%" if w is not None and w.length_mean_m else "no wand score"
    rms = ", ".join(f"{c.reprojection_rms_px / np.sqrt(2):.2f}" if c.reprojection_rms_px else "-" for c in result.cameras)
    ours += f", rms per axis (px) {rms}, level {result.to_json()['verdict']['level']}"
    folder = {"Brown 1": SHARED_DATA / BROWN / "calibration1", "Brown 2": SHARED_DATA / BROWN / "calibration2",
              "Ushichka": SHARED_DATA / USHICHKA}.get(session.name)
    if folder is not None:
        pub = json.loads((folder / "easywand_result.json").read_text())["published_result"]
        theirs = (f"easyWand wand score {pub['wandScore_percent']:.3f}%, DLT RMSE (px) "
                  + ", ".join(f"{x:.2f}" for x in pub["dltRMSE_px_per_camera"]))
    elif session.name == "MultiCamSelfCal":
        theirs = "MultiCamSelfCal mean reprojection error 0.62 px (bench/real_sessions.py)"
    else:
        theirs = "nothing published"
    return f"{session.name}: ours {ours}; published: {theirs}"


def run_fresh(sessions: list[rf.Session], seeds: list[int], progress=None, on_clean=None) -> list[rf.Outcome]:
    """Every fresh case of every session and seed; progress(outcome) after each, on_clean(session,
    clean) after each session's clean run (once: the clean run does not depend on the seed)."""
    outcomes = []
    for session in sessions:
        clean = rf.clean_run(session)
        if on_clean is not None:
            on_clean(session, clean)
        for seed in seeds:
            for case in fresh_cases(session, seed):
                outcomes.append(run_fresh_case(session, clean, replace(case, label=f"s{seed} {case.label}")))
                if progress is not None:
                    progress(outcomes[-1])
    return outcomes
