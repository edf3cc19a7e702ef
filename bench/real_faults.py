"""Real sessions with one injected fault whose truth is known: is the judgement right on them?

The sessions are the real third-party ones in ../shared/data (Brown wind tunnel 1 and 2, Ushichka,
MultiCamSelfCal's caldata20130726, the easyWand C++ sample), read in place (some carry no
licence) and never copied. Each is calibrated as published (the *clean* run: its camera centres
are the reference a fault's displacement is measured from, its ``noise_px`` each camera's own
noise), then again with one fault put into its inputs:

| fault | what is changed | expected kind |
|---|---|---|
| focal ±3%, ±8% | the camera's focal length in rig.json | ``intrinsics`` |
| k1 off | the camera's k1 in rig.json left out (0; -0.15 where the lens had none) | ``intrinsics`` |
| principal point | moved by 2% of the image's width, right and down | ``intrinsics``, or absorbed |
| late / early by 1, 2 frames | the camera's 2D tracks shifted in time | ``timing`` |
| late / early by 0.3, 0.5 frame | its 2D tracks interpolated between its frames | ``timing`` |
| knocked 0.3-1° | its rays rotated after the middle of its frames, reprojected | ``moved`` |
| noise 3× | Gaussian noise added to its observations, 3× its own in total | ``noise`` |
| wand +4%, -20% | the wand's length in rig.json | ``wand_scale`` (undeterminable: no second length here) |
| 60% subsample | a random 60% of the wand frames and of the point tracks | no camera, not poor |

Each camera fault is put on two target cameras per session, one at a time. A run is right when the
verdict names the expected kind on the target camera and no fault on another camera; a subsample
is right when it names no camera and is not poorer than the clean run. A principal point the
camera's rotation takes up is *absorbed* (right) when nothing is named, the rig is not poor and
the camera moved by no more than :data:`ABSORBED_SIGMAS` of its reported geometry sigma. Timing
faults are injected only where a camera's samples are consecutive frames (not on Ushichka,
digitised every tenth frame or more: a one-frame shift cannot be made from its samples).

Used by ``bench/bench_real_faults.py`` (the table in docs/benchmarks.md) and
``tests/calib/judge/test_real_faults.py``.
"""

from __future__ import annotations

import time
import zlib
from collections import defaultdict
from dataclasses import dataclass, field, replace

import numpy as np

from bench.common import aligned_centres_mm
from bench.real_sessions import BROWN, BROWN_MAT, SHARED_DATA, SVOBODA, USHICHKA, USHICHKA_HEIGHT
from wandcal.calib.errors import CalibrationError
from wandcal.calib.geometry import distort_points, rotvec_to_matrix, undistort_points
from wandcal.calib.rig import PointObservations, Rig, WandObservations
from wandcal.calib.run.calibrate import calibrate

CPP_SAMPLE = "easywand_cpp_sample_3cam"
CPP_WAND_M = 1.0  # the sample gives no wand length: its scale is arbitrary, a metre is as good as any
PRINCIPAL_SHIFT = 0.02  # of the image's width: 51 px on Brown's 2560 px, 13 px on Ushichka's 640
K1_WHERE_NONE = -0.15  # "k1 off" on a lens rig.json gives none: a moderate barrel distortion
KNOCK_DEG = (0.3, 1.0)  # a knock's angle, drawn per case
NOISE_FACTOR = 3.0  # the camera's noise in all, against its own
SUBSAMPLE_SHARE = 0.6
SUBSAMPLES = 3  # random subsamples per session
ABSORBED_SIGMAS = 3.0  # a principal point the rotation absorbs moves the camera within this many sigma
CONSECUTIVE_SHARE = 0.8  # a camera's samples are a track in time when this share of its gaps is one frame


@dataclass(frozen=True, eq=False)
class Session:
    """One real session's inputs. targets: the two camera indices faults are put on;
    moving_points: the point tracks are one moving marker (they shift in time with the camera),
    not static background points."""

    name: str
    rig: Rig
    wand: WandObservations
    points: PointObservations | None
    axis: object
    targets: tuple[int, int]
    moving_points: bool = False

    def consecutive(self, c: int) -> bool:
        """Camera c's samples (wand, or moving points) are consecutive frames: a time shift can be made."""
        obs = self.wand if len(self.wand) else self.points
        frames = np.unique(obs.frame[obs.camera == c])
        return len(frames) > 2 and float(np.mean(np.diff(frames) == 1)) >= CONSECUTIVE_SHARE


@dataclass(frozen=True)
class Case:
    """One fault on one session. family: the row of the table (``focal``, ``k1``, ``principal``,
    ``timing whole``, ``timing fraction``, ``knock``, ``noise``, ``wand length``, ``subsample``);
    label: this case's own name; camera: the target index or None; size: the fault's size (the
    factor, the offset in frames (positive: late), the angle in degrees, the seed); expected: the
    fault kind the verdict should name, or None."""

    session: str
    family: str
    label: str
    camera: int | None
    size: float
    expected: str | None


@dataclass
class Outcome:
    """What the judgement said about one case. level: the rig's verdict (``refused`` when
    calibrate raised); named: (kind, camera id) of every fault; displacement_mm: the target
    camera's centre against the clean run's (similarity-aligned on the whole rig); sigma_mm: its
    reported geometry sigma; offset_frames: a timing fault's offset as found."""

    case: Case
    right: bool
    level: str
    named: list[tuple[str, str | None]]
    displacement_mm: float | None = None
    sigma_mm: float | None = None
    offset_frames: float | None = None
    absorbed: bool = False
    limited_right: bool = False
    honest_sigma_mm: float | None = None
    limited: bool = False
    message: str = ""
    seconds: float = 0.0
    outcome: str = field(default="")


# -- sessions --------------------------------------------------------------------------------

def _brown(session: int) -> Session:
    from wandcal.capture.importers.easywand import read_easywand_mat

    cap = read_easywand_mat(SHARED_DATA / BROWN / f"calibration{session}" / BROWN_MAT).capture
    targets = (0, 2) if session == 1 else (2, 3)
    return Session(f"Brown {session}", cap.rig, cap.wand, cap.points, cap.axis, targets)


def _ushichka() -> Session:
    from wandcal.capture.importers.easywand import read_easywand_mat

    cap = read_easywand_mat(SHARED_DATA / USHICHKA / "round3_2018-07-28_easyWandData.mat", height=USHICHKA_HEIGHT).capture
    return Session("Ushichka", cap.rig, cap.wand, cap.points, cap.axis, (0, 2))


def _svoboda() -> Session:
    from wandcal.capture.importers.svoboda import read_svoboda

    cap = read_svoboda(SHARED_DATA / SVOBODA).capture
    return Session("MultiCamSelfCal", cap.rig, cap.wand, cap.points, cap.axis, (1, 3), moving_points=True)


def _cpp() -> Session:
    from wandcal.capture.importers.easywand import read_easywand_files

    d = SHARED_DATA / CPP_SAMPLE
    cap = read_easywand_files(d / "wandpts.csv", d / "RGBsetup_profile.txt", CPP_WAND_M, d / "bkgdPts.csv").capture
    return Session("easyWand C++ sample", cap.rig, cap.wand, cap.points, cap.axis, (0, 2))


LOADERS = {"brown1": lambda: _brown(1), "brown2": lambda: _brown(2), "ushichka": _ushichka, "svoboda": _svoboda,
           "cpp": _cpp}


def available() -> bool:
    """The shared data are where :data:`bench.real_sessions.SHARED_DATA` says."""
    return (SHARED_DATA / BROWN).is_dir()


def load_sessions(names: list[str] | None = None) -> list[Session]:
    """The sessions of ``names`` (keys of :data:`LOADERS`; all by default) whose data are present."""
    out = []
    for name in names or list(LOADERS):
        try:
            out.append(LOADERS[name]())
        except (OSError, ValueError):
            continue
    return out


# -- injectors: each returns the session with one fault in its inputs -------------------------

def _with_camera(session: Session, c: int, **changes) -> Session:
    cams = list(session.rig.cameras)
    cams[c] = replace(cams[c], **changes)
    return replace(session, rig=replace(session.rig, cameras=tuple(cams)))


def with_focal(session: Session, c: int, factor: float) -> Session:
    """rig.json gives camera c ``factor`` times its focal length (the images unchanged)."""
    K = session.rig.cameras[c].K.copy()
    K[0, 0] *= factor
    K[1, 1] *= factor
    return _with_camera(session, c, K=K)


def without_k1(session: Session, c: int) -> Session:
    """rig.json leaves camera c's k1 out (0), or gives it :data:`K1_WHERE_NONE` where it had none."""
    dist = np.array(session.rig.cameras[c].dist, float)
    dist[0] = 0.0 if abs(dist[0]) > 1e-9 else K1_WHERE_NONE
    return _with_camera(session, c, dist=dist)


def with_principal(session: Session, c: int, share: float = PRINCIPAL_SHIFT) -> Session:
    """rig.json moves camera c's principal point by ``share`` of its width, right and down."""
    cam = session.rig.cameras[c]
    K = cam.K.copy()
    K[0, 2] += share * cam.width
    K[1, 2] += share * cam.width
    return _with_camera(session, c, K=K)


def _shift_rows(frame: np.ndarray, uv: np.ndarray, offset: float) -> tuple[np.ndarray, np.ndarray]:
    """One camera's samples (frame (B,), uv (B, 2); one or two blobs a frame) as a camera
    ``offset`` frames late would record them: at frame k the blobs of time k - offset, linear
    between its own samples at the frames around it (each blob paired with the nearer one of the
    next frame); frames without both neighbours are left out."""
    by_frame: dict[int, np.ndarray] = defaultdict(list)
    for f, p in zip(frame.tolist(), uv):
        by_frame[f].append(p)
    frames_out, uv_out = [], []
    lo_shift = int(np.floor(offset))
    w = offset - lo_shift  # time k - offset lies between frames k - lo_shift - 1 and k - lo_shift
    for k in sorted(by_frame):
        a, b = by_frame.get(k - lo_shift - 1), by_frame.get(k - lo_shift)
        if w == 0:
            blobs = [np.asarray(p) for p in by_frame.get(k - lo_shift, [])]
        elif a is None or b is None or len(a) != len(b):
            continue
        else:
            blobs = []
            for p in b:
                q = min(a, key=lambda q: float(np.linalg.norm(np.asarray(q) - p)))
                blobs.append((1 - w) * np.asarray(p) + w * np.asarray(q))  # w of the way back towards frame k-lo-1
        for p in blobs:
            frames_out.append(k)
            uv_out.append(p)
    return np.array(frames_out, np.int64), np.array(uv_out, float).reshape(-1, 2)


def _replace_rows(obs, c: int, frame: np.ndarray, uv: np.ndarray):
    other = obs.camera != c
    merged = {"frame": np.concatenate([obs.frame[other], frame]),
              "camera": np.concatenate([obs.camera[other], np.full(len(frame), c)]),
              "uv": np.concatenate([obs.uv[other], uv])}
    if isinstance(obs, PointObservations):
        return PointObservations(**merged, point=None)
    return WandObservations(**merged)


def late(session: Session, c: int, offset: float) -> Session:
    """Camera c ``offset`` frames late (negative: early): its wand (and a moving point's) samples
    at frame k are those of time k - offset (:func:`_shift_rows`). Only frames the shifted camera
    still has in the original's range are kept."""
    out = session
    if len(session.wand):
        mine = session.wand.camera == c
        f, uv = _shift_rows(session.wand.frame[mine], session.wand.uv[mine], offset)
        out = replace(out, wand=_replace_rows(session.wand, c, f, uv))
    if session.moving_points and session.points is not None:
        mine = session.points.camera == c
        f, uv = _shift_rows(session.points.frame[mine], session.points.uv[mine], offset)
        out = replace(out, points=_replace_rows(session.points, c, f, uv))
    return out


def _rotated(cam, uv: np.ndarray, Rk: np.ndarray) -> np.ndarray:
    """(B, 2) raw pixels uv of camera ``cam`` after it turned by Rk (camera frame): each ray
    undistorted, rotated, projected and distorted again."""
    xy = undistort_points(cam, uv)
    ray = np.concatenate([xy, np.ones((len(xy), 1))], axis=1) @ Rk.T
    return distort_points(cam, ray[:, :2] / ray[:, 2:])


def knocked(session: Session, c: int, degrees: float, seed: int) -> Session:
    """Camera c knocked by ``degrees`` about a random axis after the middle of its wand frames (or
    of its moving point's): its later samples seen through the turned camera. Static background
    points (digitised once) keep the pose before."""
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    Rk = rotvec_to_matrix(np.radians(degrees) * axis / np.linalg.norm(axis))
    cam = session.rig.cameras[c]
    out = session
    timed = [("wand", session.wand)] if len(session.wand) else []
    if session.moving_points and session.points is not None:
        timed.append(("points", session.points))
    at = None
    for name, obs in timed:
        mine = obs.camera == c
        if at is None:
            at = float(np.median(obs.frame[mine]))
        after = mine & (obs.frame > at)
        uv = obs.uv.copy()
        uv[after] = _rotated(cam, obs.uv[after], Rk)
        moved = PointObservations(obs.frame, obs.camera, uv, point=obs.point) if name == "points" else \
            WandObservations(obs.frame, obs.camera, uv)
        out = replace(out, **{name: moved})
    return out


def noisy(session: Session, c: int, noise_px: float, seed: int, factor: float = NOISE_FACTOR) -> Session:
    """Camera c's observations (wand and points) with Gaussian noise added per axis so that its
    noise in all is ``factor`` times its own ``noise_px``."""
    rng = np.random.default_rng(seed)
    extra = noise_px * np.sqrt(factor**2 - 1)
    out = session
    for name in ("wand", "points"):
        obs = getattr(session, name)
        if obs is None or not len(obs):
            continue
        uv = obs.uv.copy()
        mine = obs.camera == c
        uv[mine] += rng.normal(0, extra, (int(mine.sum()), 2))
        changed = PointObservations(obs.frame, obs.camera, uv, point=obs.point) if name == "points" else \
            WandObservations(obs.frame, obs.camera, uv)
        out = replace(out, **{name: changed})
    return out


def wand_off(session: Session, factor: float) -> Session:
    """rig.json gives the wand ``factor`` times its length."""
    return replace(session, rig=replace(session.rig, wand_length=session.rig.wand_length * factor))


def subsample(session: Session, seed: int, share: float = SUBSAMPLE_SHARE) -> Session:
    """A random ``share`` of the wand's frames and of the points' frames (each a track)."""
    rng = np.random.default_rng(seed)
    out = session
    for name in ("wand", "points"):
        obs = getattr(session, name)
        if obs is None or not len(obs):
            continue
        frames = np.unique(obs.frame)
        kept = np.isin(obs.frame, frames[rng.random(len(frames)) < share])
        changed = PointObservations(obs.frame[kept], obs.camera[kept], obs.uv[kept],
                                    point=None if obs.point is None else obs.point[kept]) if name == "points" else \
            WandObservations(obs.frame[kept], obs.camera[kept], obs.uv[kept])
        out = replace(out, **{name: changed})
    return out


# -- the cases -------------------------------------------------------------------------------

CAMERA_FAMILIES = ("focal", "k1", "principal", "timing whole", "timing fraction", "knock", "noise")
FAMILIES = (*CAMERA_FAMILIES, "wand length", "subsample")
EXPECTED = {"focal": "intrinsics", "k1": "intrinsics", "principal": "intrinsics", "timing whole": "timing",
            "timing fraction": "timing", "knock": "moved", "noise": "noise", "wand length": "wand_scale",
            "subsample": None}
UNDETERMINABLE = {"wand length": "no second length (static object) in these sessions: a wand's length only scales the rig"}


def cases(session: Session) -> list[Case]:
    """Every case of one session (:data:`FAMILIES`), in a fixed order."""
    out = []
    for k, c in enumerate(session.targets):
        cam = session.rig.cameras[c].id

        def add(family: str, label: str, size: float, c: int = c) -> None:
            out.append(Case(session.name, family, f"{label} {cam}", c, size, EXPECTED[family]))

        for factor in (1.03, 0.97, 1.08, 0.92):
            add("focal", f"focal {100 * (factor - 1):+.0f}%", factor)
        add("k1", "k1 off", 0.0)
        add("principal", f"principal point +{100 * PRINCIPAL_SHIFT:.0f}%", PRINCIPAL_SHIFT)
        if session.consecutive(c):
            for d in (1.0, -2.0):
                add("timing whole", f"{'late' if d > 0 else 'early'} {abs(d):g} frame", d)
            for d in (0.5, -0.3) if k else (0.3, -0.5):
                add("timing fraction", f"{'late' if d > 0 else 'early'} {abs(d):g} frame", d)
        angle = KNOCK_DEG[0] + (KNOCK_DEG[1] - KNOCK_DEG[0]) * (k + 0.5) / 2  # 0.475 and 0.825 degrees
        add("knock", f"knocked {angle:.2f} deg", angle)
        add("noise", f"noise {NOISE_FACTOR:g}x", NOISE_FACTOR)
    if session.rig.wand_length is not None and len(session.wand):
        out += [Case(session.name, "wand length", f"wand {100 * (factor - 1):+.0f}%", None, factor, EXPECTED["wand length"])
                for factor in (1.04, 0.8)]
    out += [Case(session.name, "subsample", f"subsample {100 * SUBSAMPLE_SHARE:.0f}% seed {seed}", None, seed, None)
            for seed in range(SUBSAMPLES)]
    return out


def inject(session: Session, case: Case, noise_px: list[float]) -> Session:
    """The session with ``case``'s fault; noise_px: each camera's own noise (the clean run's)."""
    c, size = case.camera, case.size
    seed = _seed(case)
    if case.family == "focal":
        return with_focal(session, c, size)
    if case.family == "k1":
        return without_k1(session, c)
    if case.family == "principal":
        return with_principal(session, c, size)
    if case.family.startswith("timing"):
        return late(session, c, size)
    if case.family == "knock":
        return knocked(session, c, size, seed)
    if case.family == "noise":
        return noisy(session, c, noise_px[c], seed, size)
    if case.family == "wand length":
        return wand_off(session, size)
    if case.family == "subsample":
        return subsample(session, seed)
    raise ValueError(f"unknown fault family {case.family!r}")


def _seed(case: Case) -> int:
    """A seed of the case's names that does not change from run to run (``hash`` of a str does)."""
    return zlib.crc32(f"{case.session}|{case.label}".encode())


# -- running and scoring ---------------------------------------------------------------------

def calibrated(session: Session):
    """The session's CalibrationResult (``ba``, as the user would run it)."""
    return calibrate(session.rig, session.wand, None, points=session.points, axis=session.axis)


@dataclass(frozen=True, eq=False)
class Clean:
    """A session's clean run: centres (N, 3), each camera's noise_px, the rig's level, and the
    faults (kind, camera) its published data really have (the easyWand C++ sample's cam2 runs
    0.018 frame late: taking it out lowers every camera's noise_px by 10-24%), which a case's
    verdict may name again without being wrong."""

    centres: np.ndarray
    noise_px: list[float]
    level: str
    faults: frozenset = frozenset()


def clean_run(session: Session) -> Clean:
    result = calibrated(session)
    doc = result.to_json()
    return Clean(np.asarray(result.centers), [float(c.get("noise_px") or 0.0) for c in doc["cameras"]],
                 doc["verdict"]["level"], frozenset((f["kind"], f["camera"]) for f in doc["verdict"]["faults"] if f["camera"]))


LEVEL_ORDER = ("excellent", "good", "poor")


def covered(o: Outcome, sigmas: float = ABSORBED_SIGMAS) -> bool:
    """The target camera's displacement is within ``sigmas`` of its honest sigma (the geometry
    sigma with its focal length's, wandcal.calib.judge.intrinsic_limits)."""
    return o.displacement_mm is not None and o.honest_sigma_mm is not None and o.displacement_mm <= sigmas * o.honest_sigma_mm


def run_case(session: Session, clean: Clean, case: Case) -> Outcome:
    """Calibrate the session with ``case``'s fault and score the verdict."""
    broken = inject(session, case, clean.noise_px)
    start = time.perf_counter()
    try:
        result = calibrated(broken)
    except CalibrationError as exc:
        # a refusal that names the camera out of time says what to fix: right for a timing case
        named = str(exc).startswith(f"{session.rig.cameras[case.camera].id} is out of time") if case.camera is not None else False
        right = named and case.expected == "timing"
        out = Outcome(case, right, "refused", [("timing", session.rig.cameras[case.camera].id)] if named else [],
                      message=str(exc), seconds=time.perf_counter() - start)
        out.outcome = "right" if right else "refused"
        return out
    seconds = time.perf_counter() - start
    doc = result.to_json()
    verdict = doc["verdict"]
    named = [(f["kind"], f["camera"]) for f in verdict["faults"]]
    ids = [c.id for c in session.rig.cameras]
    out = Outcome(case, False, verdict["level"], named, seconds=seconds,
                  message=next((f["message"] for f in verdict["faults"]), ""))
    if case.camera is not None:
        out.displacement_mm = float(aligned_centres_mm(np.asarray(result.centers), clean.centres)[case.camera])
        out.sigma_mm = doc["cameras"][case.camera].get("geometry_std_mm")
        out.honest_sigma_mm = doc["cameras"][case.camera].get("geometry_std_honest_mm")
        out.limited = ids[case.camera] in {limit["camera"] for limit in verdict.get("limits") or []}
    timing = [f["evidence"].get("timing", {}).get("offset_frames") for f in verdict["faults"] if f["kind"] == "timing"]
    out.offset_frames = timing[0] if timing else None
    cams_named = {cam for kind, cam in named if cam is not None and (kind, cam) not in clean.faults}
    if case.expected is None:  # a subsample of a clean session
        out.right = not cams_named and LEVEL_ORDER.index(out.level) <= LEVEL_ORDER.index(clean.level)
        out.outcome = "right" if out.right else ("wrong camera" if cams_named else "called poor")
        return out
    target = ids[case.camera] if case.camera is not None else None
    hit = (case.expected, target) in named
    others = cams_named - {target}
    out.right = hit and not others
    if case.family == "principal" and not out.right and not cams_named and out.level != "poor" \
            and out.displacement_mm is not None and out.sigma_mm \
            and out.displacement_mm <= ABSORBED_SIGMAS * out.sigma_mm:
        out.right = out.absorbed = True
    if case.family == "focal" and not out.right and not others and out.limited and covered(out):
        out.right = out.limited_right = True
    if out.right:
        out.outcome = "limited" if out.limited_right else "absorbed" if out.absorbed else "right"
    elif others:
        out.outcome = "wrong camera"
    elif target in cams_named or (target is None and named):
        out.outcome = "wrong kind"
    else:
        out.outcome = "missed"
    return out


def run_suite(sessions: list[Session], families: tuple[str, ...] = FAMILIES, progress=None,
              on_clean=None) -> list[Outcome]:
    """Every case of every session in ``families``; progress(outcome) after each, on_clean(session,
    clean) after each session's clean run."""
    outcomes = []
    for session in sessions:
        clean = clean_run(session)
        if on_clean is not None:
            on_clean(session, clean)
        for case in cases(session):
            if case.family not in families:
                continue
            out = run_case(session, clean, case)
            outcomes.append(out)
            if progress is not None:
                progress(out)
    return outcomes


OUTCOMES = ("right", "absorbed", "limited", "missed", "wrong kind", "wrong camera", "called poor", "refused")


def confusion_table(outcomes: list[Outcome]) -> str:
    """The confusion table by fault family (markdown): runs, right, and what the wrong ones were;
    the target camera's median displacement over its reported sigma."""
    lines = ["| fault | runs | right | " + " | ".join(OUTCOMES[1:]) + " | displacement / sigma (median) | note |",
             "|---|---|---|" + "---|" * (len(OUTCOMES) - 1) + "---|---|"]
    total = right = 0
    scored_total = scored_right = 0
    for family in FAMILIES:
        rows = [o for o in outcomes if o.case.family == family]
        if not rows:
            continue
        counts = {k: sum(o.outcome == k for o in rows) for k in OUTCOMES}
        ok = sum(o.right for o in rows)
        ratio = [o.displacement_mm / o.sigma_mm for o in rows if o.displacement_mm is not None and o.sigma_mm]
        median = f"{np.median(ratio):.1f}" if ratio else "-"
        lines.append(f"| {family} | {len(rows)} | {ok} ({100 * ok / len(rows):.0f}%) | "
                     + " | ".join(str(counts[k]) for k in OUTCOMES[1:]) + f" | {median} | {UNDETERMINABLE.get(family, '')} |")
        total += len(rows)
        right += ok
        if family not in UNDETERMINABLE:
            scored_total += len(rows)
            scored_right += ok
    lines.append(f"| **all** | {total} | {right} ({100 * right / max(total, 1):.0f}%) |" + " |" * (len(OUTCOMES) + 1))
    lines.append(f"| **all determinable** | {scored_total} | {scored_right} ({100 * scored_right / max(scored_total, 1):.0f}%)"
                 " | " + " |" * (len(OUTCOMES)))
    return "\n".join(lines)


def case_line(o: Outcome) -> str:
    """One case as a line of text: session, label, outcome, verdict, faults, displacement and sigma."""
    honest = f", honest {o.honest_sigma_mm:.2f}" if o.honest_sigma_mm is not None else ""
    limited = " limit named" if o.limited else ""
    disp = f" moved {o.displacement_mm:.1f} mm (sigma {o.sigma_mm:.2f}{honest}){limited}" if o.displacement_mm is not None and o.sigma_mm else ""
    off = f" offset {o.offset_frames:+.2f}" if o.offset_frames is not None else ""
    return f"{o.case.session:20s} {o.case.label:32s} {o.outcome:12s} {o.level:9s} {o.named}{disp}{off}"


def sigma_coverage(outcomes: list[Outcome], max_error: float = 0.03) -> str:
    """The honest sigma's coverage on the focal cases at most ``max_error`` off: the share of
    target cameras whose displacement is within 1, 2 and 3 of their honest sigma (and of their
    geometry sigma alone), and the share covered within 3 sigma or with the limiting focal length named."""
    rows = [o for o in outcomes if o.case.family == "focal" and abs(o.case.size - 1) <= max_error + 1e-9
            and o.displacement_mm is not None and o.honest_sigma_mm is not None]
    if not rows:
        return "no focal cases with an honest sigma"

    def share(test) -> str:
        n = sum(bool(test(o)) for o in rows)
        return f"{n}/{len(rows)} ({100 * n / len(rows):.0f}%)"

    parts = [f"within {k} sigma: honest {share(lambda o, k=k: covered(o, k))}, geometry alone "
             f"{share(lambda o, k=k: o.sigma_mm and o.displacement_mm <= k * o.sigma_mm)}" for k in (1, 2, 3)]
    return (f"Focal length within {100 * max_error:.0f}%, {len(rows)} target cameras: " + "; ".join(parts)
            + f"; within 3 honest sigma or the focal length named as its limit: {share(lambda o: covered(o) or o.limited)}")
