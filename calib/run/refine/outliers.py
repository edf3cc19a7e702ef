"""The outlier passes after a refinement's first solve: camera-frames and point observations that
are gross outliers dropped (or, where a wand's ends fit the solved rig the other way round,
relabelled) and the method run again on the rest (:func:`wandcal.calib.run.refine.methods.refine`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from wandcal.calib.judge import quality
from wandcal.calib.observations import WandPairs, robust_sigma
from wandcal.calib.run.options import CalibrationOptions
from wandcal.calib.run.refine.methods import Progress, Refined, paper_covariance, refine
from wandcal.calib.run.refine.problem import GAUGE_CAMERA, build_problem, restarted, triangulated, up_direction
from wandcal.calib.solve.sync import TimeColumns
from wandcal.calib.solve.wandmodel import WandModel
from wandcal.calib.start.labels import label_ends
from wandcal.calib.triangulate import reprojection_errors, triangulate_points
from wandcal.calib.wandlayout import is_planar

MAX_OUTLIER_PASSES = 3  # reject-and-refine passes; the kept set settles after two on simulated rigs


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
        return replace(r, covariance=paper_covariance(r.setup, r.R, r.t, r.wand, True), final=True)
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
