"""The chosen method on a built problem (:mod:`wandcal.calib.run.refine.problem`): ``ba``, ``lp`` or
``paper``, the robust ``ba`` that stands in for ``lp`` and ``paper`` before the outlier pass, the
pose covariance, and the refined intrinsics carried back into the rig and the observations."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.geometry import undistort_by_camera
from wandcal.calib.observations import PointTracks, WandPairs
from wandcal.calib.rig import PINHOLE, Camera, Rig
from wandcal.calib.run.options import CalibrationOptions
from wandcal.calib.run.refine.problem import Setup, with_tracks
from wandcal.calib.solve.ba import DEFAULT_LOSS, STOP_SE, IntrinsicsFit, bundle_adjust_points
from wandcal.calib.solve.reprojection import INTRINSICS
from wandcal.calib.solve.sync import TimeColumns
from wandcal.calib.solve.uncertainty import PoseCovariance
from wandcal.calib.solve.wandmodel import WandModel

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
    covariance (:func:`wandcal.calib.run.refine.outliers.finished` completes such an outcome).
    ``warm``: the start is the solution of nearly the same problem (an outlier pass), so ``lp``
    skips its first phase on a subset of frames and linearises its phase once. A final ``ba`` refines the time offsets too when
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
    return Refined(rig, setup, labelled, tracks, R, t, wand, X, info, covariance=paper_covariance(setup, R, t, wand, final),
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
               judge_frames: bool | None = None) -> Refined:
    # judge_frames None: WAND_FRAMES_IN_STOP, read here so that bench_shapes' reference can patch it
    model = setup.model
    names = tuple(name for name in INTRINSICS if name in options.refine_intrinsics)
    fit = None
    if names:
        fit = IntrinsicsFit(_intrinsics(rig), names, setup.uv, tracks.uv if tracks is not None else None)
    timing = columns(setup) if columns is not None and final else None
    # standard errors and the pose covariance cost one more linearisation and solve: final stage only
    out = bundle_adjust_points(model, tracks, X, progress=tell, loss=options.loss, intrinsics=fit,
                               stop_se=STOP_SE if final else ROBUST_STAGE_SE, standard_errors=final, timing=timing,
                               judge_frames=WAND_FRAMES_IN_STOP if judge_frames is None else judge_frames)
    info = out.info | ({"refined_intrinsics": list(names)} if names else {})
    R, t = model.poses(out.x)
    refined = Refined(rig, setup, labelled, tracks, R, t, model.wand(out.x), out.X, info, out.camera_std, out.covariance,
                      final=final, dt=out.dt)
    if names and out.intr is not None:
        refined = _with_intrinsics(refined, out.intr)
    return refined


def paper_covariance(setup: Setup, R: np.ndarray, t: np.ndarray, wand: np.ndarray, final: bool) -> PoseCovariance | None:
    """The pose covariance of ``paper``'s solution: the information matrix of the wand model at its
    poses and wand (one linearisation, no step taken)."""
    if not final or not setup.problem.n_frames:
        return None
    model = WandModel(setup.problem, R, t, wand, setup.model.fixed)
    return bundle_adjust_points(model, None, None, loss="linear", max_iter=0).covariance


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
