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

The injectors are bench/fault_injectors.py, the counting and the table bench/fault_scores.py (their
names importable from here too). Used by ``bench/bench_real_faults.py`` (the table in
docs/benchmarks.md) and ``tests/calib/judge/test_real_faults.py``.
"""

from __future__ import annotations

import time
import zlib
from dataclasses import dataclass, field

import numpy as np

from bench.common import aligned_centres_mm
from bench.fault_injectors import (
    K1_WHERE_NONE,
    NOISE_FACTOR,
    PRINCIPAL_SHIFT,
    SUBSAMPLE_SHARE,
    knocked,
    late,
    noisy,
    subsample,
    wand_off,
    with_focal,
    with_principal,
    without_k1,
)
from bench.fault_scores import (
    ABSORBED_SIGMAS,
    OUTCOMES,
    at_limit_lines,
    before_line,
    case_line,
    confusion_table,
    covered,
    noise_at_limit_named,
    sigma_coverage,
)
from bench.real_sessions import BROWN, BROWN_MAT, SHARED_DATA, SVOBODA, USHICHKA, USHICHKA_HEIGHT
from wandcal.calib.errors import CalibrationError
from wandcal.calib.rig import PointObservations, Rig, WandObservations
from wandcal.calib.run.calibrate import calibrate

# the suite's face: its own names and those of the modules split from it (bench/fault_injectors.py,
# bench/fault_scores.py), importable from here as before the split
__all__ = [
    "ABSORBED_SIGMAS", "CAMERA_FAMILIES", "before_line", "EXPECTED", "FAMILIES", "K1_WHERE_NONE", "LEVEL_ORDER", "LOADERS",
    "NOISE_FACTOR", "OUTCOMES", "PRINCIPAL_SHIFT", "SHARED_DATA", "SUBSAMPLE_SHARE", "UNDETERMINABLE", "Case",
    "Clean", "Outcome", "Session", "available", "calibrated", "case_line", "cases", "clean_run", "confusion_table",
    "covered", "inject", "knocked", "late", "load_sessions", "noisy", "run_case", "run_suite", "sigma_coverage",
    "subsample", "wand_off", "with_focal", "with_principal", "without_k1",
]

CPP_SAMPLE = "easywand_cpp_sample_3cam"
CPP_WAND_M = 1.0  # the sample gives no wand length: its scale is arbitrary, a metre is as good as any
KNOCK_DEG = (0.3, 1.0)  # a knock's angle, drawn per case
SUBSAMPLES = 3  # random subsamples per session
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
    limited: bool = False  # the verdict's limits name the target camera with the fault's intrinsic (LIMITABLE)
    limited_by: list = field(default_factory=list)  # the intrinsics the limits name for the target camera
    message: str = ""
    seconds: float = 0.0
    outcome: str = field(default="")
    at_limit: list = field(default_factory=list)  # the verdict's criteria at the limit of poor (lines, fault_scores.at_limit_lines)
    at_limit_right: bool = False
    right_before: bool = False  # right as session 15 scored it (_right_before), for the tables' comparison


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
    0.018 frame early, docs/result-format.md's sign: taking it out lowers every camera's noise_px
    by 10-24%), which a case's verdict may name again without being wrong."""

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
# the families whose camera may be right without a fault named: a principal point (or a decentred
# lens, bench/held_out_faults.py) its rotation takes up, within ABSORBED_SIGMAS of its sigma; a
# focal length named as what limits the camera's position, within 3 honest sigma of it
# (as fixed before the held-out faults were first run, decision 0058: not widened after the fact)
ABSORBABLE = frozenset({"principal", "principal y", "tangential"})
LIMITABLE_BEFORE = frozenset({"focal", "focal subsample", "fy"})  # session 15's limited: the camera named for any limit
# an intrinsic fault is *limited* (right) when the verdict's limits name the target camera with the
# intrinsic the fault put off and its displacement is within 3 honest sigma (session 16: before,
# the focal families only, with the camera named for any intrinsic)
LIMITABLE = {"focal": {"focal length"}, "focal subsample": {"focal length"}, "fy": {"focal length"}, "k1": {"k1"},
             "principal": {"cx", "cy"}, "principal y": {"cy"}, "k2": {"k2"}, "tangential": {"p1", "p2"}}



def run_case(session: Session, clean: Clean, case: Case, injector=None) -> Outcome:
    """Calibrate the session with ``case``'s fault and score the verdict; injector(session, case,
    noise_px) puts the fault in (:func:`inject` by default; bench/held_out_faults.py has its own)."""
    broken = (injector or inject)(session, case, clean.noise_px)
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
        out.right_before = right
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
        out.sigma_mm, out.honest_sigma_mm = _sigmas_mm(doc["cameras"][case.camera])
        out.limited_by = [limit["parameter"] for limit in verdict.get("limits") or [] if limit["camera"] == ids[case.camera]]
        out.limited = bool(LIMITABLE.get(case.family, set()) & set(out.limited_by))
    timing = [f["evidence"].get("timing", {}).get("offset_frames") for f in verdict["faults"] if f["kind"] == "timing"]
    out.offset_frames = timing[0] if timing else None
    out.at_limit = at_limit_lines(verdict)
    cams_named = {cam for kind, cam in named if cam is not None and (kind, cam) not in clean.faults}
    if case.expected is None:  # a subsample of a clean session
        out.right = not cams_named and LEVEL_ORDER.index(out.level) <= LEVEL_ORDER.index(clean.level)
        out.outcome = "right" if out.right else ("wrong camera" if cams_named else "called poor")
        out.right_before = out.right
        return out
    target = ids[case.camera] if case.camera is not None else None
    hit = (case.expected, target) in named
    others = cams_named - {target}
    out.right = hit and not others
    if case.family in ABSORBABLE and not out.right and not cams_named and out.level != "poor" \
            and out.displacement_mm is not None and out.sigma_mm \
            and out.displacement_mm <= ABSORBED_SIGMAS * out.sigma_mm:
        out.right = out.absorbed = True
    if case.family in LIMITABLE and not out.right and not others and out.limited and covered(out):
        out.right = out.limited_right = True
    if case.expected == "noise" and not out.right and not cams_named and noise_at_limit_named(out, target):
        out.right = out.at_limit_right = True
    out.right_before = _right_before(out, others)
    if out.right:
        out.outcome = ("limited" if out.limited_right else "absorbed" if out.absorbed
                       else "at the limit" if out.at_limit_right else "right")
    elif others:
        out.outcome = "wrong camera"
    elif target in cams_named or (target is None and named):
        out.outcome = "wrong kind"
    else:
        out.outcome = "missed"
    return out


def _sigmas_mm(camera: dict) -> tuple[float | None, float | None]:
    """The camera's geometry sigma and honest sigma in the units of :func:`aligned_centres_mm`'s
    displacement: mm, or, for a result without a scale (no wand: MultiCamSelfCal), its rig units
    times 1000, as the displacement of a rig aligned onto the clean run's units is (session 18: the
    scale-less sigmas were read as absent, so such a camera could be neither absorbed nor limited)."""
    def pick(mm_key: str, rig_key: str) -> float | None:
        if camera.get(mm_key) is not None:
            return camera[mm_key]
        return 1000 * camera[rig_key] if camera.get(rig_key) is not None else None
    return pick("geometry_std_mm", "geometry_std"), pick("geometry_std_honest_mm", "geometry_std_honest")


def _right_before(out: Outcome, others: set) -> bool:
    """The case scored as session 15 did: as today but for *limited*, then only for the focal
    families (:data:`LIMITABLE_BEFORE`) and with the camera named in any limit."""
    if out.right and not out.limited_right:
        return True
    return out.case.family in LIMITABLE_BEFORE and not others and bool(out.limited_by) and covered(out)


def run_suite(sessions: list[Session], families: tuple[str, ...] = FAMILIES, progress=None,
              on_clean=None, cases_of=None, injector=None) -> list[Outcome]:
    """Every case of every session in ``families``; progress(outcome) after each, on_clean(session,
    clean) after each session's clean run. cases_of(session) and injector (:func:`run_case`): the
    cases and how their faults are made (:func:`cases` and :func:`inject` by default)."""
    outcomes = []
    for session in sessions:
        clean = clean_run(session)
        if on_clean is not None:
            on_clean(session, clean)
        for case in (cases_of or cases)(session):
            if case.family not in families:
                continue
            out = run_case(session, clean, case, injector)
            outcomes.append(out)
            if progress is not None:
                progress(out)
    return outcomes
