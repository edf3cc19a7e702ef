"""The refinement step: from labelled wand pairs, point tracks and start poses to a problem, the
chosen method on it, the outlier cleanup, and back to poses (and refined intrinsics)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.geometry import camera_centers, undistort_by_camera
from wandcal.calib.judge import quality
from wandcal.calib.observations import PointTracks, WandPairs, robust_sigma
from wandcal.calib.rig import PINHOLE, Camera, Rig
from wandcal.calib.run.options import CalibrationOptions
from wandcal.calib.solve.ba import DEFAULT_LOSS, STOP_SE, IntrinsicsFit, bundle_adjust_points
from wandcal.calib.solve.reprojection import INTRINSICS
from wandcal.calib.solve.sync import TimeColumns
from wandcal.calib.solve.uncertainty import PoseCovariance
from wandcal.calib.solve.wandmodel import WandModel, WandProblem
from wandcal.calib.start.labels import flatten, label_ends
from wandcal.calib.triangulate import reprojection_errors, triangulate_points
from wandcal.calib.wandlayout import is_planar

TRACK_FRAME_HALF = np.array([0.5, 0.0, 0.0])  # a point track's frame in with_tracks: any unit direction

GAUGE_CAMERA = 0
MAX_OUTLIER_PASSES = 3  # reject-and-refine passes; the kept set settles after two on simulated rigs
# A robust ba that a least squares polish follows stops this close to its optimum (in standard
# errors): near enough to tell outliers (5 sigma) from noise, and the polish then converges in
# two steps. Run to the end, the reweighted loss converges only linearly: 42 iterations against
# 14 on the MultiCamSelfCal tracks, whose 6% outliers leave many weights in between.
ROBUST_STAGE_SE = 0.5
# Every stage of ba stops on the cameras (and point tracks) alone: the wand frames are nuisance
# parameters. On sparse rigs a frame two cameras see with its wand nearly across both rays is held
# in one direction by the wand's foreshortening alone, a curvature Gauss-Newton leaves out: it
# converges at 0.93 a step and kept the robust stage (25-90 iterations) or the polish (61) going
# long after the cameras had settled (decision 0032). The frames the stop's rule still counts as
# moving are then settled with the cameras held (calib/solve/ba/frames.py), so relabelling and the
# outlier pass judge every frame at its optimum. True: the stop waits for every frame too, the rule
# before decision 0032 (bench_shapes' reference).
WAND_FRAMES_IN_STOP = False

Progress = Callable[[dict], None]


@dataclass(frozen=True, eq=False)
class Setup:
    """A refinement problem and the bookkeeping to map its frames back to the capture.

    frames: (F,) capture frame numbers of the problem's wand frames; pair_index: (M,) the row
    of the labelled pairs each observation came from; uv: (M, 2) its raw pixels.
    """

    problem: WandProblem
    model: WandModel
    frames: np.ndarray
    pair_index: np.ndarray
    uv: np.ndarray


def build_problem(rig: Rig, pairs: WandPairs, R: np.ndarray, t: np.ndarray, gauge: int | np.ndarray = 0) -> Setup:
    """Triangulate the labelled pairs at the given poses and set up the wand model.

    Frames seen by fewer than two cameras are left out. The camera ``gauge`` is held fixed (or,
    given an (N,) bool array, every camera it marks).
    """
    point, camera, xy = flatten(pairs)
    X = triangulate_points(R, t, point, camera, xy, 2 * len(pairs.frames)).reshape(-1, 2, 3)
    ok = np.all(np.isfinite(X), axis=(1, 2))
    new_index = np.cumsum(ok) - 1
    P = len(pairs)
    obs_pair = np.concatenate([np.arange(P), np.arange(P)])
    end = np.repeat([0, 1], P)
    sel = ok[pairs.frame][obs_pair]
    order = np.argsort(obs_pair[sel] * 2 + end[sel], kind="stable")
    pair_index = obs_pair[sel][order]
    problem = WandProblem(
        camera=camera[sel][order],
        frame=new_index[pairs.frame[pair_index]],
        end=end[sel][order],
        xy=xy[sel][order],
        focal=np.array([c.focal for c in rig.cameras]),
        length=rig.wand_length if rig.wand_length is not None else 0.0,
        n_frames=int(ok.sum()),
    )
    if isinstance(gauge, np.ndarray):
        fixed = gauge.astype(bool)
    else:
        fixed = np.zeros(len(rig.cameras), bool)
        fixed[gauge] = True
    model = WandModel(problem, R, t, X[ok], fixed)
    uv = np.concatenate([pairs.uv[:, 0], pairs.uv[:, 1]])[sel][order]
    return Setup(problem=problem, model=model, frames=pairs.frames[ok], pair_index=pair_index, uv=uv)


def restarted(setup: Setup, keep: np.ndarray, R: np.ndarray, t: np.ndarray, wand: np.ndarray) -> Setup:
    """The setup restricted to the labelled pairs where ``keep`` (P,) is true and started at the
    given poses and wand (F, 2, 3), with no new triangulation: as :func:`build_problem` on
    ``pairs.subset(keep)``, frames left with fewer than two cameras dropped."""
    p = setup.problem
    obs = keep[setup.pair_index]
    views = np.bincount(p.frame[obs], minlength=p.n_frames) // 2
    frame_ok = views >= 2
    obs &= frame_ok[p.frame]
    new_frame = np.cumsum(frame_ok) - 1
    problem = WandProblem(p.camera[obs], new_frame[p.frame[obs]], p.end[obs], p.xy[obs], p.focal, p.length, int(frame_ok.sum()))
    model = WandModel(problem, R, t, wand[frame_ok], setup.model.fixed)
    pair_index = (np.cumsum(keep) - 1)[setup.pair_index[obs]]
    return Setup(problem=problem, model=model, frames=setup.frames[frame_ok], pair_index=pair_index, uv=setup.uv[obs])


@dataclass(frozen=True, eq=False)
class Refined:
    """A refinement's outcome. R (N, 3, 3), t (N, 3) gauge-frame poses; wand (F, 2, 3) ends; X
    (T, 3) points or None; rig: with refined intrinsics where asked; labelled, tracks and setup:
    the observations as used (undistorted with the rig's intrinsics, outliers left out);
    camera_std: (N, c) standard errors of (w, t, refined intrinsics) from ``ba``, else None;
    covariance: the free poses' covariance in the gauge frame, from the information matrix at the
    final poses (every method's, when ``final``)."""

    rig: Rig
    setup: Setup
    labelled: WandPairs
    tracks: PointTracks | None
    R: np.ndarray
    t: np.ndarray
    wand: np.ndarray
    X: np.ndarray | None
    info: dict
    camera_std: np.ndarray | None = None
    covariance: PoseCovariance | None = None
    outliers: int = 0
    point_outliers: int = 0
    final: bool = True
    dt: np.ndarray | None = None  # (N,) time offsets refined by ``ba`` (frames; refine's ``columns``)


def check_intrinsics_request(rig: Rig, refine: tuple[str, ...]) -> None:
    """Raise a CalibrationError naming the camera when the rig cannot refine ``refine`` (the
    names and the method: :meth:`CalibrationOptions.check`)."""
    fisheye = [c.id for c in rig.cameras if c.model != PINHOLE]
    if refine and fisheye:
        raise CalibrationError(f"--refine-intrinsics supports the pinhole model only; {fisheye[0]} is {rig.cameras[0].model}")


def refine(rig: Rig, labelled: WandPairs, setup: Setup, tracks: PointTracks | None, X: np.ndarray | None, method: str,
           options: CalibrationOptions, tell: Progress, up: np.ndarray, final: bool = True,
           warm: bool = False, *, columns: TimeColumns | None = None) -> Refined:
    """Run ``method`` on the problem with ``options`` (``options.method`` is the calibration's,
    ``method`` this solve's). Not ``final`` (an outlier pass follows): a robust
    ``ba`` stops at ``ROBUST_STAGE_SE``, and ``lp`` and ``paper`` run that robust ``ba`` in their
    place (their passes then start from it, ``warm``); ``paper``'s passes leave out the pose
    covariance (:func:`finished` completes such an outcome). ``warm``: the start is the solution
    of nearly the same problem (an outlier pass), so ``lp`` skips its first phase on a subset of
    frames and linearises its phase once. A final ``ba`` refines the time offsets too when
    ``columns`` (a :class:`wandcal.calib.solve.sync.joint.TimeColumns`) gives their columns for
    the setup."""
    tell({"stage": "refine", "message": f"refining with method {method!r}"})
    if method in ("lp", "paper") and not final and not warm:
        # the solve before the outlier pass only tells the outliers and starts the method's passes,
        # each of which solves the method's own problem from there: a robust ba (Cauchy, to
        # ROBUST_STAGE_SE) does both at a third of the cost of lp's first phases (decision 0024),
        # and paper's own least-squares rotation step is not robust (decision 0028)
        # (its own loss, the intrinsics held, and the time offsets too: no ``columns``)
        # It waits for every wand frame (the stop before decision 0032): the method's passes start from
        # it and do not settle frames of their own (Brown 1's paper, from the cameras-only stop: a wand 10% short)
        robust = replace(options, loss=DEFAULT_LOSS, refine_intrinsics=())
        first = _refine_ba(rig, labelled, setup, tracks, X, robust, tell, False, None, judge_frames=True)
        return replace(first, info={k: v for k, v in first.info.items() if k != "loss"})
    if method == "paper":
        return _refine_paper(rig, labelled, setup, tracks, X, options, tell, up, final)
    if method == "lp":
        return _refine_lp(rig, labelled, setup, tracks, X, options, tell, final, warm)
    return _refine_ba(rig, labelled, setup, tracks, X, options, tell, final, columns)


def _refine_paper(rig: Rig, labelled: WandPairs, setup: Setup, tracks: PointTracks | None, X: np.ndarray | None,
                  options: CalibrationOptions, tell: Progress, up: np.ndarray, final: bool) -> Refined:
    # the LP methods load scipy.optimize and HiGHS (0.2 s of start-up) only when they run
    from wandcal.calib.solve.paper import MAX_ROUNDS, refine_paper

    model = setup.model
    R, t, wand, info = refine_paper(
        model.R0, model.t0, model.wand(model.x0()), setup.problem, model.fixed, up,
        max_rounds=int(options.max_rounds or MAX_ROUNDS), time_limit=options.time_limit, progress=tell,
    )
    return Refined(rig, setup, labelled, tracks, R, t, wand, X, info, covariance=_information(setup, R, t, wand, final),
                   final=final)


def _refine_lp(rig: Rig, labelled: WandPairs, setup: Setup, tracks: PointTracks | None, X: np.ndarray | None,
               options: CalibrationOptions, tell: Progress, final: bool, warm: bool) -> Refined:
    from wandcal.calib.solve.lp import refine_lp, refine_lp_covariance

    joint = with_tracks(setup.model, tracks, X)
    covariance = None
    if final and setup.problem.n_frames:  # the covariance from the LP's own last linearisation
        x, info, covariance = refine_lp_covariance(joint, setup.problem.n_frames, progress=tell,
                                                   time_limit=options.time_limit, warm=warm)
    else:
        x, info = refine_lp(joint, progress=tell, time_limit=options.time_limit, certify=final, warm=warm)
    R, t = joint.poses(x)
    frames = joint.wand(x)
    wand, X = frames[: setup.problem.n_frames], (frames[setup.problem.n_frames :].mean(axis=1) if X is not None else X)
    return Refined(rig, setup, labelled, tracks, R, t, wand, X, info, covariance=covariance, final=final)


def _refine_ba(rig: Rig, labelled: WandPairs, setup: Setup, tracks: PointTracks | None, X: np.ndarray | None,
               options: CalibrationOptions, tell: Progress, final: bool, columns: TimeColumns | None, *,
               judge_frames: bool = WAND_FRAMES_IN_STOP) -> Refined:
    model = setup.model
    names = tuple(name for name in INTRINSICS if name in options.refine_intrinsics)
    fit = None
    if names:
        fit = IntrinsicsFit(_intrinsics(rig), names, setup.uv, tracks.uv if tracks is not None else None)
    timing = columns(setup) if columns is not None and final else None
    # standard errors and the pose covariance cost one more linearisation and solve: final stage only
    out = bundle_adjust_points(model, tracks, X, progress=tell, loss=options.loss, intrinsics=fit,
                               stop_se=STOP_SE if final else ROBUST_STAGE_SE, standard_errors=final, timing=timing,
                               judge_frames=judge_frames)
    info = out.info | ({"refined_intrinsics": list(names)} if names else {})
    R, t = model.poses(out.x)
    refined = Refined(rig, setup, labelled, tracks, R, t, model.wand(out.x), out.X, info, out.camera_std, out.covariance,
                      final=final, dt=out.dt)
    if names and out.intr is not None:
        refined = _with_intrinsics(refined, out.intr)
    return refined


def _information(setup: Setup, R: np.ndarray, t: np.ndarray, wand: np.ndarray, final: bool) -> PoseCovariance | None:
    """The pose covariance of ``paper``'s solution: the information matrix of the wand model at its
    poses and wand (one linearisation, no step taken)."""
    if not final or not setup.problem.n_frames:
        return None
    model = WandModel(setup.problem, R, t, wand, setup.model.fixed)
    return bundle_adjust_points(model, None, None, loss="linear", max_iter=0).covariance


def with_tracks(model: WandModel, tracks: PointTracks | None, X: np.ndarray | None) -> WandModel:
    """The wand model with each point track as one more frame whose observations sit at the
    frame's midpoint (``along`` 0): its 3D point is the midpoint and its direction is left free
    (the frame's normal matrix is then singular in it, which the LP's elimination regularises),
    so ``lp`` refines point tracks beside the wand with no new kind of unknown. ``model`` itself
    without tracks. X: (T, 3) the tracks' start points, metres."""
    if tracks is None or X is None or not len(tracks):
        return model
    p = model.p
    F = p.n_frames
    problem = WandProblem(
        camera=np.concatenate([p.camera, tracks.camera]), frame=np.concatenate([p.frame, F + tracks.track]),
        end=np.concatenate([p.end, np.zeros(len(tracks), dtype=p.end.dtype)]), xy=np.concatenate([p.xy, tracks.xy]),
        focal=p.focal, length=p.length, n_frames=F + tracks.n_tracks,
        along=np.concatenate([p.offsets, np.zeros(len(tracks))]),
    )
    # any direction starts a point's frame: its observations do not depend on it
    ends = np.stack([X - TRACK_FRAME_HALF, X + TRACK_FRAME_HALF], axis=1)
    wand0 = model.wand(model.x0()) if F else np.zeros((0, 2, 3))
    return WandModel(problem, model.R0, model.t0, np.concatenate([wand0, ends]), model.fixed)


def _intrinsics(rig: Rig) -> np.ndarray:
    """(N, 9) fx, fy, cx, cy, k1, k2, p1, p2, k3."""
    return np.array([[c.K[0, 0], c.K[1, 1], c.K[0, 2], c.K[1, 2], *c.dist] for c in rig.cameras])


def _with_intrinsics(refined: Refined, intr: np.ndarray) -> Refined:
    """The outcome re-expressed with the refined intrinsics: the rig's cameras, and every
    observation undistorted again with them."""
    cams = []
    for cam, (fx, fy, cx, cy, *dist) in zip(refined.rig.cameras, intr):
        K = np.array([[fx, cam.K[0, 1], cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        cams.append(Camera(cam.id, cam.width, cam.height, K, np.array(dist), cam.model))
    rig = replace(refined.rig, cameras=tuple(cams))
    labelled = refined.labelled
    labelled = replace(labelled, xy=undistort_by_camera(rig.cameras, labelled.camera, labelled.uv))
    tracks = refined.tracks
    if tracks is not None:
        tracks = replace(tracks, xy=undistort_by_camera(rig.cameras, tracks.camera, tracks.uv))
    s = refined.setup
    pxy = undistort_by_camera(rig.cameras, s.problem.camera, s.uv)
    problem = replace(s.problem, xy=pxy, focal=np.array([c.focal for c in rig.cameras]))
    return replace(refined, rig=rig, labelled=labelled, tracks=tracks, setup=replace(s, problem=problem))


def triangulated(R, t, tracks: PointTracks):
    """The tracks that triangulate at the given poses, and their points (T, 3)."""
    X = triangulate_points(R, t, tracks.track, tracks.camera, tracks.xy, tracks.n_tracks)
    ok = np.all(np.isfinite(X), axis=1)
    if ok.all():
        return tracks, X
    return tracks.subset(ok[tracks.track]), X[ok]


def reject_outliers(r: Refined, method: str, options: CalibrationOptions, tell: Progress, *,
                    columns: TimeColumns | None = None) -> Refined:
    """Drop the camera-frames and point observations that are gross outliers and refine again,
    until the kept set settles.

    At each pass every camera-frame is judged against the current cameras, worst first within
    each frame (least squares spreads an outlier over its frame, so only the worst is sure to
    be one); camera-frames dropped earlier are re-admitted when they fit the cleaner solution.
    After a robust ``ba`` the outliers have had no pull on the cameras, so one pass over its own
    residuals finds them all, and plain least squares on the rest (a few iterations from the
    robust solution, which :data:`ROBUST_STAGE_SE` let stop early) gives the fully efficient
    estimate. ``lp``'s and ``paper``'s first solve is that robust ``ba`` (:func:`refine`), so their
    outliers are judged as ``ba``'s, in one pass, and each then solves its own problem on the rest
    (``lp`` to its certified optimum). ``paper``'s pass leaves out the pose covariance, which
    :func:`finished` adds after it. ``options`` and ``columns`` as :func:`refine`'s."""
    robust_ba = method == "ba" and options.loss != "linear"
    if robust_ba:
        options = replace(options, loss="linear")
    one_pass = robust_ba or method in ("lp", "paper")  # their first solve: a robust ba (refine)
    keep = np.ones(len(r.labelled), bool)
    point_drops = 0
    for k in range(1 if one_pass else MAX_OUTLIER_PASSES):
        limit, errors, point_err = _outlier_limit(r)
        new_keep = keep
        if one_pass:
            # a camera-frame whose ends fit the solved rig the other way round was labelled
            # wrongly (a frame two cameras see can fit both ways at the start): relabel it
            # instead of dropping it
            r, errors = relabelled(r, errors, limit)
            # the robust fit's own residuals: no outlier pulled it, so none hides in its frame,
            # and a bent wand shows, its length being built in
            new_keep = np.ones(len(r.labelled), bool)
            new_keep[r.setup.pair_index[errors > limit]] = False
        elif len(r.labelled):
            if k == 0:  # the first solve's rig relabels a frame it fits the other way round, as above
                r, _ = relabelled(r, errors, limit)
            new_keep = quality.reject_worst_per_frame(r.R, r.t, r.labelled, r.setup.problem.focal, limit)
            if r.rig.wand_length is not None:
                new_keep &= ~quality.length_outlier_frames(r.R, r.t, r.labelled, new_keep, r.rig.wand_length)[r.labelled.frame]
        starved = _starved(r.labelled, new_keep, len(r.rig.cameras))
        if starved.any():
            # dropping these would leave a camera without a frame to refine it from
            if not one_pass:
                break  # keep the last set
            new_keep = new_keep | starved[r.labelled.camera]  # the polish still runs, on them too
        tracks, X, bad_points = r.tracks, r.X, point_err > limit
        if tracks is not None and bad_points.any():
            point_drops += int(bad_points.sum())
            tracks, X = triangulated(r.R, r.t, tracks.subset(~bad_points))
        if np.array_equal(new_keep, keep) and not bad_points.any() and not one_pass:
            break
        keep = new_keep
        dropped = int((~keep).sum())
        without = [f"{dropped} outlying camera-frame" + "s" * (dropped != 1)] if dropped else []
        without += [f"{point_drops} point observation" + "s" * (point_drops != 1)] if point_drops else []
        tell({"stage": "outliers", "message": f"refining without {' and '.join(without)}" if without
              else "refining once more on every camera-frame (none is an outlier)"})
        if one_pass:  # one pass from the full setup: restart it where the robust solve ended
            setup = restarted(r.setup, keep, r.R, r.t, r.wand)
        else:
            setup = build_problem(r.rig, r.labelled.subset(keep), r.R, r.t, GAUGE_CAMERA)
        before = r.info
        r = refine(r.rig, r.labelled, setup, tracks, X, method, options, tell, up_direction(r.rig, r.R, r.t, setup),
                   final=method != "paper", warm=True, columns=columns)
        r = replace(r, info=r.info | _carried(before, r.info) | {"loss": before.get("loss", r.info.get("loss"))})
    if not r.final:
        r = finished(r, keep, method, options, tell, columns=columns)
    # the labelled pairs stay whole; the setup holds the kept ones
    return replace(r, outliers=int((~keep).sum()), point_outliers=point_drops)


def finished(r: Refined, keep: np.ndarray, method: str, options: CalibrationOptions, tell: Progress, *,
             columns: TimeColumns | None = None) -> Refined:
    """The final outcome of a refinement that was not ``final``: ``paper``'s with its pose
    covariance; another method's refined once more, from its own solution, on the camera-frames
    ``keep`` (P,) bool of ``r.labelled``."""
    if method == "paper":
        return replace(r, covariance=_information(r.setup, r.R, r.t, r.wand, True), final=True)
    setup = build_problem(r.rig, r.labelled.subset(keep), r.R, r.t, GAUGE_CAMERA)
    again = refine(r.rig, r.labelled, setup, r.tracks, r.X, method, options, tell, up_direction(r.rig, r.R, r.t, setup),
                   warm=True, columns=columns)
    return replace(again, info=again.info | _carried(r.info, again.info))


def _carried(before: dict, after: dict) -> dict:
    """What a refinement's info keeps from the solve before it: the iterations and seconds
    summed, and the camera-frames relabelled on the way."""
    return ({"iterations": before["iterations"] + after["iterations"], "seconds": before["seconds"] + after["seconds"]}
            | ({"relabelled": before["relabelled"]} if "relabelled" in before else {}))


def relabelled(r: Refined, errors: np.ndarray, limit: float) -> tuple[Refined, np.ndarray]:
    """The outcome with the wand ends of every frame that holds an outlying camera-frame
    labelled again at the solved rig (:func:`wandcal.calib.start.labels.label_ends`), the
    frame's majority keeping its end order, and the observations' errors (M,) after it;
    ``info["relabelled"]`` counts the camera-frames swapped. ``r.setup`` must hold every
    labelled pair (its ``pair_index`` indexes ``r.labelled``)."""
    p, rows = r.setup.problem, r.setup.pair_index
    if not len(p.camera) or p.along is not None or r.rig.wand_length is None:
        return r, errors
    if r.rig.wand_markers is not None and is_planar(r.rig.wand_markers):
        return r, errors  # a planar wand's ends are labelled from its layout in each image, not by their order
    P = len(r.labelled)
    # only a camera-frame that fits the solved wand better the other way round can be a swap
    # (a gross outlier, one blob tens of pixels off, fits worse turned): the others' frames need
    # no relabelling (label_ends on every outlier's frame cost 12% of calibrate at 8% outliers)
    swapped_errors = quality.pixel_errors(r.R, r.t, r.wand, replace(p, end=1 - p.end))
    worse = np.zeros(P)
    np.maximum.at(worse, rows, errors - swapped_errors)  # > 0: a row's end fits better turned
    outlying = (np.bincount(rows, errors > limit, minlength=P) > 0) & (worse > 0)
    doubtful = np.isin(r.labelled.frame, r.labelled.frame[outlying])
    if not doubtful.any():
        return r, errors
    sub = r.labelled.subset(doubtful)
    again, _ = label_ends(r.R, r.t, sub, np.ones(len(r.rig.cameras), bool), r.rig.wand_length)
    turned = ~np.all(np.isclose(again.uv, sub.uv), axis=(1, 2))
    # a frame turned as a whole is the same labelling: keep its majority's order
    share = np.bincount(sub.frame, turned, minlength=len(sub.frames)) / np.maximum(
        np.bincount(sub.frame, minlength=len(sub.frames)), 1)
    turned ^= share[sub.frame] > 0.5
    swap = np.zeros(P, bool)
    swap[np.flatnonzero(doubtful)[turned]] = True
    if not swap.any():
        return r, errors
    flip = swap[rows]
    problem = replace(p, end=np.where(flip, 1 - p.end, p.end))
    # the relabelled frames judged afresh: their ends triangulated with the new labels (the
    # robust fit's wand there followed the old ones)
    X = triangulate_points(r.R, r.t, problem.point, p.camera, p.xy, 2 * p.n_frames)
    fresh = np.linalg.norm(reprojection_errors(r.R, r.t, problem.point, p.camera, p.xy, X) * p.focal[p.camera], axis=1)
    again_frames = np.isin(p.frame, p.frame[flip])
    setup = replace(r.setup, problem=problem, model=WandModel(problem, r.R, r.t, r.wand, r.setup.model.fixed))
    info = r.info | {"relabelled": int(r.info.get("relabelled", 0)) + int(swap.sum())}
    return replace(r, setup=setup, labelled=r.labelled.swapped(swap), info=info), np.where(again_frames, fresh, errors)


def labelled_rows(r: Refined) -> np.ndarray:
    """(M,) the row of ``r.labelled`` each observation of ``r.setup`` came from. After outlier
    rejection the setup's own ``pair_index`` counts the kept rows only; the raw pixels (camera,
    u, v) of a row's end name it whatever was dropped."""
    p = r.setup.problem
    row_of = {(int(c), e, float(uv[0]), float(uv[1])): k for e in (0, 1)
              for k, (c, uv) in enumerate(zip(r.labelled.camera, r.labelled.uv[:, e]))}
    return np.array([row_of[(int(c), int(e), float(uv[0]), float(uv[1]))]
                     for c, e, uv in zip(p.camera, p.end, r.setup.uv)], dtype=np.int64)


def _starved(labelled: WandPairs, keep: np.ndarray, n_cams: int) -> np.ndarray:
    """(N,) bool: the cameras that had wand frames shared with another camera and would have none
    if only ``keep`` (P,) of the labelled pairs were kept (on a sparse rig of ~30 frames the
    worst-per-frame passes can strip a whole camera)."""
    def shared(mask):
        views = np.bincount(labelled.frame[mask], minlength=len(labelled.frames))
        ok = mask & (views[labelled.frame] >= 2)
        return np.bincount(labelled.camera[ok], minlength=n_cams)
    before, after = shared(np.ones(len(labelled), bool)), shared(keep)
    return (before > 0) & (after == 0)


def _outlier_limit(r: Refined) -> tuple[float, np.ndarray, np.ndarray]:
    """The outlier limit in pixels (``OUTLIER_SIGMAS`` robust sigmas of all residuals, at least
    ``MIN_OUTLIER_PX``), the wand observations' errors (M,) and the point observations' (Q,)."""
    errors = quality.pixel_errors(r.R, r.t, r.wand, r.setup.problem)
    point_err = np.zeros(0)
    if r.tracks is not None and r.X is not None and len(r.tracks):
        res = reprojection_errors(r.R, r.t, r.tracks.track, r.tracks.camera, r.tracks.xy, r.X)
        point_err = np.linalg.norm(res * r.setup.problem.focal[r.tracks.camera], axis=1)
    sigma = robust_sigma(np.concatenate([errors, point_err]))
    return max(quality.OUTLIER_SIGMAS * sigma, quality.MIN_OUTLIER_PX), errors, point_err


def up_direction(rig: Rig, R: np.ndarray, t: np.ndarray, setup: Setup) -> np.ndarray:
    """World up for the paper's height constraints: +z of the static object's frame; without one,
    from the wand's centroid towards the cameras' centroid (cameras on a ring above the volume)."""
    if rig.static_markers is not None or not len(setup.model.m0):
        return np.array([0.0, 0.0, 1.0])
    v = camera_centers(R, t).mean(0) - setup.model.m0.mean(0)
    return v / np.linalg.norm(v)
