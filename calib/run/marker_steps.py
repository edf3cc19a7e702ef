"""A wand of three markers or more in a run (rig.json ``wand.markers_m``): its blobs ordered along
the wand's image, its rows aligned with the labelled ends, every marker labelled at the refined
poses and, with ``ba`` or ``lp``, the refinement again with the wand model's interior markers;
the interior markers handed to the judgement as point tracks (decision 0057).
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from wandcal.calib.judge import quality
from wandcal.calib.observations import PointTracks, WandPairs, robust_sigma
from wandcal.calib.rig import Rig, WandObservations
from wandcal.calib.run.options import CalibrationOptions
from wandcal.calib.run.refine import Progress, Refined, labelled_rows

if TYPE_CHECKING:
    from wandcal.calib.start.markerlabels import MarkerBlobs


def aligned_markers(blobs: MarkerBlobs, labelled: WandPairs) -> tuple[np.ndarray, np.ndarray]:
    """(xy, uv) (P, K, 2) a multi-marker wand's rows with their end 0 first as the ends of
    ``labelled`` (the same rows, their ends maybe swapped)."""
    swapped = ~np.all(np.isclose(labelled.uv[:, 0], blobs.uv[:, 0]), axis=1)
    xy, uv = blobs.xy.copy(), blobs.uv.copy()
    xy[swapped], uv[swapped] = xy[swapped, ::-1], uv[swapped, ::-1]
    return xy, uv


def marker_blobs(rig: Rig, wand: WandObservations) -> MarkerBlobs | None:
    """A wand of three or more markers (rig.json ``wand.markers_m``): its camera-frames ordered
    along the wand's image (wandcal.calib.start.markerlabels); None for two markers."""
    if rig.wand_markers is None or len(rig.wand_markers) == 2:
        return None
    from wandcal.calib.start.markerlabels import order_markers

    return order_markers(rig, wand)


def with_markers(rig: Rig, blobs: MarkerBlobs, r: Refined, options: CalibrationOptions, tell: Progress,
                  warnings: list[str]) -> tuple[Refined, list[dict], PointTracks]:
    """Label every marker at the refined poses and, with ``ba`` or ``lp``, refine again with the
    interior markers' known positions in the wand model; the refinement, each marker pair's
    lengths (wandcal.calib.solve.markerwand) and the interior markers as point tracks
    (wandcal.calib.start.markerlabels.interior_tracks, outliers included, for the judgement)."""
    from wandcal.calib.solve.markerwand import marker_model, marker_pair_lengths
    from wandcal.calib.start.markerlabels import interior_tracks, label_interior

    method, markers = options.method, rig.wand_markers
    assert markers is not None  # blobs: a wand of three markers or more
    labels = label_interior(rig, blobs, r.labelled, r.R, r.t, (r.setup.frames, r.wand))
    pair_index = labelled_rows(r)
    fit = labels if method != "lp" else labels.on_axis()  # lp's frames have no roll: the markers on the axis
    model, rows = marker_model(r.setup.problem, pair_index, r.labelled.camera, fit.xy, fit.along, r.R, r.t,
                               r.wand, r.setup.model.fixed, fit.across)
    if fit.across is not None:  # a planar wand's ends as the labels at the solved rig name them
        ends = np.where(r.setup.problem.end == 1, fit.xy.shape[1] - 1, 0)
        r = replace(r, setup=replace(r.setup, problem=replace(r.setup.problem, xy=fit.xy[pair_index, ends]),
                                     uv=fit.uv[pair_index, ends]))
    x = model.x0()
    if method == "paper" or r.info.get("refined_intrinsics"):
        warnings.append(f"the wand's interior markers label its frames; only --method ba or lp without "
                        f"--refine-intrinsics refines with them ({method} did not)")
    else:
        r, x = _refined_with_markers(r, model, options, tell)
    # an interior blob the fit leaves far off is an outlier: its camera-frame stays out of the
    # marker pairs' lengths, as the ends' outliers stay out of the wand's
    err = np.linalg.norm(model.residuals(x).reshape(-1, 2), axis=1)
    limit = max(quality.OUTLIER_SIGMAS * robust_sigma(err), quality.MIN_OUTLIER_PX)
    kept = np.zeros(len(r.labelled), bool)
    kept[pair_index] = True
    kept[rows[err[len(r.setup.problem.camera):] > limit]] = False
    return r, marker_pair_lengths(r.R, r.t, r.labelled.frame[kept], r.labelled.camera[kept], labels.xy[kept],
                                  labels.marker[kept], markers), interior_tracks(labels, r.labelled)


def _refined_with_markers(r: Refined, model, options: CalibrationOptions, tell: Progress) -> tuple[Refined, np.ndarray]:
    """``ba`` or ``lp`` again on the wand model with every marker; the outcome and its parameters."""
    from wandcal.calib.solve.ba import bundle_adjust_points

    tell({"stage": "refine", "message": "refining with every wand marker"})
    if options.method == "lp":
        from wandcal.calib.solve.lp import refine_lp

        x, lp_info = refine_lp(model, progress=tell, time_limit=options.time_limit)
        out = bundle_adjust_points(model, None, None, x0=x, loss="linear", max_iter=0)  # its covariance only
        out = replace(out, x=x, X=r.X, info=lp_info)
    else:
        out = bundle_adjust_points(model, r.tracks, r.X, progress=tell, loss=options.loss)
    x = out.x
    info = r.info | {"iterations": r.info.get("iterations", 0) + out.info.get("iterations", 0),
                     "seconds": r.info.get("seconds", 0.0) + out.info.get("seconds", 0.0)}
    R, t = model.poses(x)
    r = replace(r, R=R, t=t, wand=model.wand(x), X=out.X, camera_std=out.camera_std, covariance=out.covariance,
                info=info)
    return r, x
