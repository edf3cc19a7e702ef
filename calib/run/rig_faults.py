"""The cameras at fault, by the rig's size: the paths of the judgement step
(:mod:`wandcal.calib.run.judgement`) that name a camera.

A rig of few cameras (:data:`wandcal.calib.judge.faults.leave_one_out.MAX_CAMERAS` or fewer) is
judged by comparison (:func:`few_camera_faults`): a camera out of time from every pair of cameras,
a lens by comparing each camera with the points the others triangulate, then a camera that moved
and a camera whose own noise stands out, each with the points eliminated; else the suspect screen.
A larger rig (:func:`many_camera_faults`) is screened for suspects first (a camera whose residuals
stand out of the rig's, :func:`suspects`), each suspect judged against the rig solved without it
(:func:`isolate`), then each camera's own errors at a bounded cost (:func:`wandcal.calib.run.own_error_faults.own_faults`).
"""

from __future__ import annotations

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.judge.faults.f_distribution import binomial_tail
from wandcal.calib.judge.faults.rejected_runs import rejected_moved
from wandcal.calib.judge.faults.screen import Lens, TimingFault, analyse_camera, classify, lens_screen, offset_text
from wandcal.calib.judge.quality import OUTLIER_SIGMAS
from wandcal.calib.judge.residuals import Residuals, held_out
from wandcal.calib.judge.verdict import NOISE_RATIO, share_std
from wandcal.calib.observations import PointTracks, WandPairs
from wandcal.calib.rig import Rig
from wandcal.calib.run.own_error_faults import own_faults, points_eliminated
from wandcal.calib.solve.sync.fit import why_untimeable
from wandcal.calib.solve.sync.report import sync_advice

SUSPECT_NOISE_RATIO = 1.5  # a camera this much noisier than the median camera is looked into
SUSPECT_OUTLIER_SHARE = 0.03  # ... or with this share of its camera-frames gross outliers
SUSPECT_OUTLIER_FACTOR = 3.0  # ... and that many times the median camera's share
# a lens pattern in a camera's residuals (no re-solve) that sends it to be isolated: on clean
# simulated rigs its share stays under 1% (F under 10); a camera whose focal length or k1 is
# wrong shows 30-70% (F 400-1700) even when its pose absorbed the error and its residual is
# hardly above the others'; real sessions (easyWand's) reach 15% on a few hundred points, F < 5;
# a lens error hidden in a poorly covered camera's pose showed 10% at F = 105 (faults.LENS_STRONG_F)
SCREEN_LENS_SHARE = 0.05
SCREEN_F_STAT = 100.0
# the worst cameras looked into, each at the cost of a re-solve without it; more at fault at once
# is a rig-wide problem, said in one line (:func:`also_patterned`) at no further cost (decision 0100)
MAX_SUSPECTS = 2
# ... and its outlier share more than binomial scatter about the median camera's explains: its
# outlier camera-frames' binomial upper tail under the median share below this level, shared out
# over the rig's cameras (Bonferroni), so that a clean rig has a camera looked into for its
# outliers alone once in twenty (a clean 128-camera rig's largest shares, 5-8 of 40-80 camera-
# frames against ~3%, lie at 1e-3-1e-2: binomial scatter; decision 0080)
SUSPECT_OUTLIER_LEVEL = 0.05
MIN_CAMERAS_TO_ISOLATE = 3  # two cameras left cannot say which of them is wrong



def _median_share(figures: list[dict]) -> float:
    shares = [f["outlier_share"] for f in figures if f["outlier_share"] is not None]
    return float(np.median(shares)) if shares else 0.0


def _concentrated(figures: list[dict], c: int, sure: bool = False) -> bool:
    """Camera c holds far more of the gross outliers than the median camera; ``sure``: by more than
    its share's standard error (binomial, over its observations), as a fault is named
    (docs/verdict.md, "At the limit")."""
    share = figures[c]["outlier_share"] or 0.0
    std = share_std(share, figures[c].get("observations") or 0) if sure else 0.0
    return share - std > SUSPECT_OUTLIER_SHARE and share - std > SUSPECT_OUTLIER_FACTOR * _median_share(figures)


def camera_frames(res: Residuals, n_cameras: int) -> tuple[np.ndarray, np.ndarray]:
    """(outliers (N,), camera-frames (N,)) each camera's camera-frames that are gross outliers, of
    all it has, as independent trials: a wand frame's two ends in a camera are one (flagged together,
    :func:`wandcal.calib.judge.residuals.observation_residuals`), a point track's observation one."""
    weight = np.where(res.point >= 0, 0.5, 1.0)  # wand ends (point >= 0) come in pairs
    total = np.bincount(res.camera, weight, n_cameras)
    bad = np.bincount(res.camera, weight * res.outlier, n_cameras)
    return np.ceil(bad - 1e-9).astype(np.int64), np.ceil(total - 1e-9).astype(np.int64)


def _scattered(figures: list[dict], c: int, frames: tuple[np.ndarray, np.ndarray], n_cameras: int) -> bool:
    """Camera c's outlier camera-frames within the binomial scatter of the median camera's share
    (:data:`SUSPECT_OUTLIER_LEVEL`, over ``n_cameras``)."""
    bad, total = frames
    return binomial_tail(int(bad[c]), int(total[c]), _median_share(figures)) >= SUSPECT_OUTLIER_LEVEL / max(n_cameras, 1)


def suspects(figures: list[dict], lens: list[Lens | None] | None = None,
             frames: tuple[np.ndarray, np.ndarray] | None = None) -> list[int]:
    """Cameras whose residuals stand out of the rig's, or hold a lens pattern (``lens``, from
    :func:`wandcal.calib.judge.faults.screen.lens_screen`), worst first. frames: each camera's
    outlier camera-frames and camera-frames (:func:`camera_frames`); given, a share of outliers makes
    a suspect only beyond the binomial scatter of the median camera's (:data:`SUSPECT_OUTLIER_LEVEL`)."""
    noise = np.array([f["noise_px"] if f["noise_px"] else np.nan for f in figures], float)
    share = np.array([f["outlier_share"] if f["outlier_share"] is not None else np.nan for f in figures], float)
    if np.isfinite(noise).sum() < MIN_CAMERAS_TO_ISOLATE:
        return []
    ratio = noise / np.nanmedian(noise)
    patterned = np.zeros(len(figures))
    for c, found in enumerate(lens or []):
        if found is not None and found.f_stat >= SCREEN_F_STAT and found.explained >= SCREEN_LENS_SHARE:
            patterned[c] = found.explained / SCREEN_LENS_SHARE
    judged = int(np.isfinite(noise).sum())

    def outlying(c: int) -> bool:
        return _concentrated(figures, c) and (frames is None or not _scattered(figures, c, frames, judged))
    out = [c for c in range(len(figures)) if ratio[c] > SUSPECT_NOISE_RATIO or patterned[c] or outlying(c)]
    return sorted(out, key=lambda c: -max(ratio[c] / SUSPECT_NOISE_RATIO, share[c] / SUSPECT_OUTLIER_SHARE, patterned[c]))


def isolate(rig: Rig, labelled: WandPairs, R: np.ndarray, t: np.ndarray, c: int,
            at_fault: list[int] | None = None) -> tuple[TimingFault | None, Lens | None]:
    """Camera c's timing and lens patterns against the rig solved without it, and without the
    cameras already found ``at_fault`` (whose error would otherwise show in c's residuals): the others
    refined without them, :func:`wandcal.calib.run.refine.without.without_cameras` (its steps bounded)."""
    from wandcal.calib.run.refine.without import without_cameras

    out = [c, *(at_fault or [])]
    if len(rig.cameras) - len(out) < 2 or rig.wand_length is None:
        return None, None
    try:
        R2, t2 = without_cameras(rig, labelled, R, t, out)
    except (CalibrationError, np.linalg.LinAlgError):  # the others alone may not solve: judge them as they are
        R2, t2 = R, t
    point, xy, X = held_out(R2, t2, labelled.subset(~np.isin(labelled.camera, at_fault or [])), c)
    return analyse_camera(R2[c], t2[c], labelled.frames, X, point, xy)


def camera_faults(rig: Rig, labelled: WandPairs, R: np.ndarray, t: np.ndarray, figures: list[dict],
                  res: Residuals) -> list[dict]:
    """The cameras at fault, each ``{"kind", "camera", "message", "evidence"}``."""
    faults: list[dict] = []
    noise = np.array([f["noise_px"] or np.nan for f in figures], float)
    median = float(np.nanmedian(noise)) if np.isfinite(noise).any() else np.nan
    screened = [lens_screen(R, t, res, c) for c in range(len(rig.cameras))] if len(labelled) else None
    suspected = suspects(figures, screened, camera_frames(res, len(rig.cameras)))
    for c in suspected[:MAX_SUSPECTS]:
        cam, fig = rig.cameras[c].id, figures[c]
        ratio = fig["noise_px"] / median if median > 0 else np.inf
        at_fault = [rig.index(f["camera"]) for f in faults]
        timing, lens = isolate(rig, labelled, R, t, c, at_fault) if len(labelled) else (None, None)
        kind, evidence = classify(timing, lens)
        evidence |= {"noise_px": round(fig["noise_px"], 4), "rig_noise_px": round(median, 4),
                     "outlier_share": round(fig["outlier_share"], 4)}
        if kind == "timing" and timing is not None:
            d = timing.offset_frames
            message = (f"{cam} is out of time: its frames show the wand {offset_text(d, timing.offset_std_frames)} "
                       f"against the other cameras (offset {d:+.2f}: positive is late); check its trigger cable and "
                       f"settings{sync_advice(why_untimeable(labelled, rig, c))}")
        elif kind == "intrinsics" and lens is not None:
            message = (f"{cam}'s intrinsics do not fit its images: its residuals are {'scaled' if abs(lens.focal_error) > abs(lens.k1_error) / 4 else 'radial'} about the "
                       f"image centre (focal length {100 * lens.focal_error:+.1f}% in rig.json against the data, k1 "
                       f"{lens.k1_error:+.3f}); check its focal length and distortion, or run with "
                       "--refine-intrinsics focal,k1")
        elif ratio > NOISE_RATIO[1]:
            kind = "noise"
            message = (f"{cam}'s blob centres are {ratio:.1f} times as noisy as the other cameras' "
                       f"({fig['noise_px']:.2f} px against {median:.2f} px) with no timing or lens pattern: check "
                       "its focus, exposure and the blob detection settings")
        elif _concentrated(figures, c, sure=True):
            kind = "outliers"
            message = (f"{cam} has {100 * fig['outlier_share']:.1f}% of its camera-frames off by more than "
                       f"{OUTLIER_SIGMAS:g} times the rig's noise while its other frames fit, against "
                       f"{100 * _median_share(figures):.1f}% in the median camera: a reflection or a second bright "
                       f"marker in its view; mask it (wandcal detect --mask) or cover the reflecting surface")
        else:
            continue  # no pattern, no concentrated outliers, and within the noise the verdict allows
        faults.append({"kind": kind, "camera": cam, "message": message, "evidence": evidence})
    return also_patterned(faults, [rig.cameras[c].id for c in suspected[MAX_SUSPECTS:]
                                   if screened is not None and _patterned(screened[c])])


def _patterned(lens: Lens | None) -> bool:
    """The lens screen's pattern strong enough to make a suspect (:data:`SCREEN_F_STAT`, :data:`SCREEN_LENS_SHARE`)."""
    return lens is not None and lens.f_stat >= SCREEN_F_STAT and lens.explained >= SCREEN_LENS_SHARE


def also_patterned(faults: list[dict], more: list[str]) -> list[dict]:
    """The faults with the suspects beyond :data:`MAX_SUSPECTS` whose own residuals hold a lens
    pattern (``more``, not re-solved without them) said in one rig-wide line on the first
    intrinsics fault: several cameras' given intrinsics off at once is the rig's lens
    calibration, and one instruction fixes them all."""
    first = next((f for f in faults if f["kind"] == "intrinsics"), None)
    if first is None or not more:
        return faults
    names = ", ".join(more[:-1]) + (" and " if len(more) > 1 else "") + more[-1]
    line = (f"; {names} {'shows' if len(more) == 1 else 'show'} the same lens pattern too: the given intrinsics "
            "of several cameras do not fit, so calibrate with --refine-intrinsics focal,k1 or give them from a lens "
            "calibration")
    return [f | {"message": f["message"] + line, "evidence": f["evidence"] | {"also_patterned": more}}
            if f is first else f for f in faults]


def few_camera_faults(rig: Rig, labelled: WandPairs, tracks: PointTracks | None, R: np.ndarray, t: np.ndarray,
                      figures: list[dict], res: Residuals) -> list[dict]:
    """The cameras at fault: in a rig of few cameras first a camera out of time, from every pair
    of cameras (:func:`wandcal.calib.judge.faults.timing_pairs.timing_faults`), then a lens by comparing
    every camera against the points the others triangulate
    (:func:`wandcal.calib.judge.faults.leave_one_out.leave_one_out_faults`), then a camera that moved, then
    cameras whose own noise stands out (:func:`wandcal.calib.run.own_error_faults.own_faults`), else by the suspect screen
    (:func:`camera_faults`). A larger rig: :func:`many_camera_faults`."""
    from wandcal.calib.judge.faults.leave_one_out import MAX_CAMERAS, held_out_views, leave_one_out_faults
    from wandcal.calib.judge.faults.swapped import swap_faults
    from wandcal.calib.judge.faults.timing_pairs import camera_timings, timing_faults, timing_instead

    if len(rig.cameras) > MAX_CAMERAS:
        return many_camera_faults(rig, labelled, tracks, R, t, figures, res)
    # every camera against the points the others triangulate: the swap screen's and the lens comparison's
    held = [held_out_views(R, t, labelled, tracks, c) for c in range(len(rig.cameras))] \
        if len(rig.cameras) >= 3 else None
    if swapped := swap_faults(rig, labelled, tracks, R, t, _solved_again, held):  # two cameras' columns exchanged
        return swapped
    noise_px, focal = [f["noise_px"] for f in figures], np.array([c.focal for c in rig.cameras], float)  # (fx, fy)
    timings = camera_timings(R, t, labelled, tracks, focal) if len(rig.cameras) >= 3 else []
    timing = timing_faults(list(rig.ids), R, t, labelled, tracks, focal, noise_px, timings) if timings else []
    if timing:
        return timing + beside_timing(rig, labelled, tracks, R, t, timing[0])
    lens = leave_one_out_faults(list(rig.ids), R, t, labelled, tracks, held=held)
    # a lens error bends a tracked marker's path: a step or noise there is its effect. A lens
    # pattern that needed fy's own column is weaker: a camera out of time spreads a stretch along
    # the wand's motion through the points, which that column fits in another camera (Brown 2,
    # cam4 0.5 frame late: F 124 on cam2's aspect); a camera's own errors that its offset explains
    # name the timing instead (decision 0058)
    if lens and not lens[0]["evidence"]["intrinsics"].get("aspect_error"):
        return lens
    moved, noisy = own_faults(rig, labelled, tracks, R, t)
    moved = moved or rejected_moved(list(rig.ids), res, R, t)  # a knock whose later views the outlier pass rejected
    # a camera out of time is noisy in its own residuals too: its offset, where it explains them, names the kind
    noisy = [timing_instead(list(rig.ids), timings, rig.index(f["camera"]), noise_px[rig.index(f["camera"])]) or f
             for f in noisy]
    if lens:
        return [f for f in noisy if f["kind"] == "timing"][:1] or lens
    return moved or noisy or _outliers_or_noise(rig, labelled, tracks, R, t, figures, res,
                                                camera_faults(rig, labelled, R, t, figures, res))


def in_time(labelled: WandPairs, n_cameras: int, c: int, offset: float) -> WandPairs:
    """The wand pairs with camera c's brought to the others' time: its frame f sampled at f -
    ``offset`` (docs/result-format.md's sign: c ``offset`` frames late), interpolated along its own
    track (:func:`wandcal.calib.solve.sync.fit.resample`); its rows without the frames around that
    time are left out."""
    from wandcal.calib.solve.sync.fit import Timing, resample

    phase = np.zeros(n_cameras)
    phase[c] = offset
    z = np.zeros(n_cameras)
    timing = Timing(phase, z, z, np.zeros((n_cameras, 2, 2)), 0.0, np.zeros(n_cameras, np.int64))
    return resample(labelled, timing)[0]


def _solved_again(rig: Rig, labelled: WandPairs, tracks: PointTracks | None, R: np.ndarray, t: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Every camera's pose refined again (``ba``, robust, from R, t) on these wand pairs and the
    point tracks: a sparse session's background points place its cameras as much as its wand."""
    from wandcal.calib.run.options import CalibrationOptions
    from wandcal.calib.run.refine import build_problem, refine, triangulated, up_direction

    setup = build_problem(rig, labelled, R, t, 0)
    X = None
    if tracks is not None and len(tracks):
        tracks, X = triangulated(R, t, tracks)
    r = refine(rig, labelled, setup, tracks, X, "ba", CalibrationOptions(), lambda event: None,
               up_direction(rig, R, t, setup), final=False)
    return r.R, r.t


def beside_timing(rig: Rig, labelled: WandPairs, tracks: PointTracks | None, R: np.ndarray, t: np.ndarray,
                  timing: dict) -> list[dict]:
    """The faults of the other cameras beside one out of time (``timing``, its fault): its samples
    brought to the others' time (:func:`in_time`) and the rig solved again with them, then each
    other camera's lens against the points the others triangulate, a camera that moved, and each
    camera's own noise, as :func:`few_camera_faults` judges a rig in time. A camera out of time
    bends the solve, so judged on the solve as it stands every camera would show its error. The
    timed camera is not named again. Only with a wand (whose samples have a time)."""
    c = rig.index(timing["camera"])
    offset = timing["evidence"]["timing"]["offset_frames"]
    if not len(labelled):
        return []
    synced = in_time(labelled, len(rig.cameras), c, offset)
    if len(synced) < len(labelled) // 2:  # too few of its frames interpolate: the others stay unjudged
        return []
    try:
        R2, t2 = _solved_again(rig, synced, tracks, R, t)
    except (CalibrationError, np.linalg.LinAlgError):
        return []
    from wandcal.calib.judge.faults.leave_one_out import camera_patterns, leave_one_out_faults

    found = leave_one_out_faults(list(rig.ids), R2, t2, synced, tracks, at_fault=(c,))
    if found and found[0]["kind"] == "intrinsics":
        # a lens error of its own stays when the timed camera is brought in time (it shows more
        # clearly, the timing's spread gone); the timing's spread through the points shrinks: a
        # pattern weaker now than on the solve as it stood is that spread, not a fault
        before = camera_patterns(R, t, labelled, tracks, rig.index(found[0]["camera"])).lens
        if before is not None and found[0]["evidence"]["intrinsics"]["f_stat"] < before.f_stat:
            found = []
    if not found:
        moved, noisy = own_faults(rig, synced, tracks, R2, t2)
        found = moved or noisy
    return [f for f in found if f["camera"] != timing["camera"]]


def _outliers_or_noise(rig: Rig, labelled: WandPairs, tracks: PointTracks | None, R: np.ndarray, t: np.ndarray,
                       figures: list[dict], res: Residuals, faults: list[dict]) -> list[dict]:
    """``faults`` with an ``outliers`` fault turned into ``noise`` where the camera's own noise
    (the points eliminated, :func:`wandcal.calib.judge.faults.own_errors.camera_noise`) is above the
    others' and its Gaussian tail explains its share of camera-frames beyond the rig's outlier
    limit (``res.limit_px``) within two of that share's standard errors: in a rig of few cameras a
    camera three times as noisy puts a fifth of its frames past a limit set by the others' noise,
    all of them its own noise, not reflections."""
    from wandcal.calib.judge.faults.own_errors import camera_noise, noise_fault

    if not any(f["kind"] == "outliers" for f in faults):
        return faults
    el = points_eliminated(R, t, labelled, tracks)[1]
    if el is None:
        return faults
    focal = np.array([c.focal.mean() for c in rig.cameras])
    noise = camera_noise(el, focal)
    out = []
    for fault in faults:
        c = rig.index(fault["camera"]) if fault["kind"] == "outliers" else -1
        n = noise[c] if c >= 0 else None
        if n is not None and n.ratio > 1:
            end = float(np.exp(-res.limit_px**2 / (2 * n.sigma_px**2)))  # a 2D Gaussian's radius beyond the limit
            expected = 1 - (1 - end) ** 2  # a camera-frame is an outlier by its worse end
            share = figures[c]["outlier_share"] or 0.0
            if share <= expected + 2 * share_std(share, figures[c].get("observations") or 0):
                noisy = noise_fault(fault["camera"], n)
                out.append(noisy | {"evidence": fault["evidence"] | noisy["evidence"]
                                    | {"expected_outlier_share": round(expected, 4)}})
                continue
        out.append(fault)
    return out


def many_camera_faults(rig: Rig, labelled: WandPairs, tracks: PointTracks | None, R: np.ndarray, t: np.ndarray,
                       figures: list[dict], res: Residuals) -> list[dict]:
    """The cameras at fault in a rig of more than a few cameras: the suspect screen
    (:func:`camera_faults`: timing and a lens by isolating each suspect), then each camera's own
    errors (:func:`wandcal.calib.run.own_error_faults.own_faults`): a camera that moved replaces what the screen named on it (a
    knock's later views look like a lens pattern), and a camera whose own noise stands out is
    named where the screen named nothing on it."""
    screened = camera_faults(rig, labelled, R, t, figures, res)
    named = [rig.index(f["camera"]) for f in screened if f["camera"] is not None]
    moved, noisy = own_faults(rig, labelled, tracks, R, t, named, res)
    moved = moved or rejected_moved(list(rig.ids), res, R, t)  # a knock whose later views the outlier pass rejected
    gone = {f["camera"] for f in moved}
    kept = [f for f in screened if f["camera"] not in gone]
    return moved + kept + [f for f in noisy if f["camera"] not in {g["camera"] for g in kept}]
