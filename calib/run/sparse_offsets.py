"""Whole-frame time offsets on a sparse rig, from every camera's triangulations together.

:func:`wandcal.calib.start.offsets.whole_frames.frame_offsets` times each camera against a few partners,
one pair's epipolar geometry at a time, and needs ``MIN_TIMING_FRAMES`` frames shared with one of
them. Where each frame is seen by only 2-4 of a hundred cameras, any two share a frame or two:
no pair can tell a shift. All the cameras together still see the wand in most frames, so here a
shift of camera c is scored against the wand as the *other* cameras triangulate it:

1. the start's poses (:func:`wandcal.calib.start.initial.initial_poses`) with the offsets so far
   (first the guess: a camera a few frames out of time still gets a pose near its own, fitted to
   a wand that moved a few centimetres; its neighbours' poses are not moved by it),
2. the wand ends labelled at those poses, and each camera-frame's ends triangulated by the other
   cameras alone (:func:`wandcal.calib.triangulate.triangulate_left_out`),
3. for each camera and each shift s within the search, the median over its frames k of the
   distance, in pixels, between its ends and the others' ends of frame k + s projected into it
   (the nearer of the two matchings), its pose first fitted again to those ends
   (:func:`refit_poses`: the start fitted it at the offsets so far, which it would favour). A
   camera in time fits at its noise at one shift and by the wand's motion (several pixels a
   frame) at every other; the best shift is taken when it stands out (``MAX_CONTRAST`` of the
   median shift's).

The offsets found renumber the frames and the poses are found again, until no offset changes
(``ROUNDS`` at most); a camera whose best shift never stands out is refused: it did not see the
others' wand (another session, another wand). Decision 0053. The sub-frame part is fitted afterwards, as after the pairwise search
(:mod:`wandcal.calib.solve.sync`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.geometry import rotvec_to_matrix, sum_by
from wandcal.calib.observations import WandPairs
from wandcal.calib.rig import Rig
from wandcal.calib.start.initial import Initial, UnplacedCamera, initial_poses
from wandcal.calib.start.labels import flatten, label_ends
from wandcal.calib.start.offsets.pair_fit import MIN_TIMING_FRAMES
from wandcal.calib.start.offsets.shift_search import MAX_CONTRAST
from wandcal.calib.start.offsets.whole_frames import FrameOffsets, shift_pairs
from wandcal.calib.triangulate import triangulate_left_out, triangulate_points

FIT_STEPS = 3  # Gauss-Newton steps of each camera's pose at each shift, from the start's
REFIT_SHIFTS = 3  # shifts a camera's pose is fitted again at: its best ones with the start's pose
FIT_SCALE_PX = 2.0  # the Cauchy loss's scale there: the noise and the wand's motion left in a frame
_ROW, _COL = np.triu_indices(6)  # a 6x6 symmetric matrix's distinct entries
ROUNDS = 4  # poses found again with the offsets found, until none moves: cameras out of time spoil the first poses


@dataclass(frozen=True, eq=False)
class SparseStart:
    """The start the offsets were found with: ``static_poses`` (as
    :func:`wandcal.calib.start.static.solve_static` gives them, or None), ``init``, the first
    poses at the offsets found, and ``labelled``, the pairs renumbered by those offsets with their
    ends labelled at those poses (:func:`wandcal.calib.start.labels.label_ends`); calibrate's start
    takes them instead of finding them again."""

    static_poses: list | None
    init: Initial
    labelled: WandPairs


def offsets_by_triangulation(rig: Rig, pairs: WandPairs, max_offset: int, start: np.ndarray | None = None,
                             reference: int = 0, *, static_poses: list | None = None,
                             ) -> tuple[FrameOffsets, SparseStart | None]:
    """Each camera's whole-frame offset (see module docstring), as
    :func:`wandcal.calib.start.offsets.whole_frames.frame_offsets` gives them, and the start at those
    offsets (None when the last round still moved an offset).

    Args:
        rig: the rig (intrinsics, wand length).
        pairs: two-blob camera-frames on each camera's own frame numbers (normalised coordinates).
        max_offset: frames searched either side of the offsets so far.
        start: (N,) int, a first guess of each camera's offset (timestamps); default zeros.
        reference: the camera of offset 0.
        static_poses: the static object's poses (:func:`wandcal.calib.start.static.solve_static`), or
            None: the start places the cameras that see it from it, as calibrate's start does.

    Raises:
        CalibrationError: the start cannot place the cameras at the offsets guessed, or a camera's
            wand agrees with the others' at no shift searched; the message names it and what to do.
    """
    n = len(rig.cameras)
    offsets = np.zeros(n, np.int64) if start is None else np.asarray(start, np.int64) - int(start[reference])
    shifts = np.arange(-max_offset, max_offset + 1)
    contrast = np.ones(n)
    found_at = None
    for _ in range(ROUNDS):
        shifted = shift_pairs(pairs, offsets)
        try:
            init = initial_poses(rig, shifted, static_poses)
        except UnplacedCamera as exc:
            c = exc.camera
            raise CalibrationError(
                f"camera {rig.cameras[c].id!r} does not move with the others: with its frames {int(offsets[c])} from the "
                f"first camera's it fits no pose against the wand the others triangulate, and no two cameras share "
                "enough frames to time it by itself; check that it recorded the same session and the same wand (a "
                "camera more than a frame or two out of time on so sparse a rig needs timestamps to start from)") from None
        labelled = label_ends(init.R, init.t, shifted, np.ones(n, bool), rig.wand_length)[0]
        scores = shift_scores(init.R, init.t, labelled, shifts, np.array([c.focal for c in rig.cameras], float))
        with np.errstate(all="ignore"):
            typical = np.nanmedian(scores, axis=1)
        best = np.array([int(np.nanargmin(row)) if np.isfinite(row).any() else max_offset for row in scores])
        contrast = scores[np.arange(n), best] / typical
        clear = contrast <= MAX_CONTRAST  # NaN too is unclear: no shift with enough frames
        # a camera out of time spoils its neighbours' first poses: the clear ones move first, and
        # a camera is refused only once no offset moves any more
        found = np.where(clear, offsets + shifts[best], offsets)
        found -= found[reference]
        if (found == offsets).all():
            _refuse_unclear(rig, ~clear, scores[np.arange(n), best], contrast, offsets, max_offset)
            found_at = SparseStart(static_poses, init, labelled)  # the start at the offsets returned
            break
        offsets = found
    else:
        _refuse_unclear(rig, ~clear, scores[np.arange(n), best], contrast, offsets, max_offset)
    timed = FrameOffsets(offsets=offsets, reference=reference, timed_against=np.full(n, -1, np.int64),
                         share=1.0 - np.minimum(contrast, 1.0),
                         notes=["each camera's time offset was found against the wand all the other cameras triangulate "
                                "(each pair of cameras shares too few frames to time it alone)"])
    return timed, found_at


def _refuse_unclear(rig: Rig, unclear: np.ndarray, best_px: np.ndarray, contrast: np.ndarray, offsets: np.ndarray,
                    max_offset: int) -> None:
    """Raise CalibrationError for the first camera whose best shift does not stand out: it did not
    see the wand the others saw (``unclear`` (N,) bool; its best fit ``best_px`` and ``contrast``
    (N,) against a typical shift's; the offsets searched around)."""
    for c in np.flatnonzero(unclear):
        what = (f"its best fit, {best_px[c]:.1f} px, is {contrast[c]:.0%} of a typical shift's"
                if np.isfinite(contrast[c]) else f"it shares fewer than {MIN_TIMING_FRAMES} frames with them at every shift")
        raise CalibrationError(
            f"camera {rig.cameras[c].id!r} does not move with the others: at no offset within +-{max_offset} frames "
            f"of {int(offsets[c])} does its wand agree with the wand the other cameras triangulate ({what}); check "
            "that it recorded the same session and the same wand, or search wider (sync_max_offset)")


def shift_scores(R: np.ndarray, t: np.ndarray, labelled: WandPairs, shifts: np.ndarray, focal: np.ndarray) -> np.ndarray:
    """(N, S) each camera's median error, px, with its frame k matched to the others' frame
    k + shift (``shifts`` (S,) int): its two ends against the ends the other cameras triangulate
    in that frame, projected with its pose, the nearer matching; NaN for a shift with fewer than
    :data:`MIN_TIMING_FRAMES` such frames. R (N, 3, 3), t (N, 3) world->camera, metres; focal
    (N,) or (N, 2) px."""
    n, F = len(R), len(labelled.frames)
    point, camera, xy = flatten(labelled)
    X_all = triangulate_points(R, t, point, camera, xy, 2 * F).reshape(F, 2, 3)
    X_out, _, _ = triangulate_left_out(R, t, point, camera, xy, 2 * F)
    P = len(labelled)
    X_own = np.stack([X_out[:P], X_out[P:]], axis=1)  # (P, 2, 3) each pair's ends without its camera
    row_of = np.full((F, n), -1)
    row_of[labelled.frame, labelled.camera] = np.arange(P)
    number = labelled.frames[labelled.frame]  # (P,) each pair's frame number
    focal_px = np.asarray(focal, float).reshape(n, -1).mean(axis=1)
    each = []  # (P, 2, 3) the others' ends each pair meets at each shift
    for s in shifts:
        at = np.searchsorted(labelled.frames, number + s)
        exists = (at < F) & (labelled.frames[np.minimum(at, F - 1)] == number + s)
        at = np.where(exists, at, 0)
        ends = np.where(exists[:, None, None], X_all[at], np.nan)
        # a frame the camera saw itself: the others' ends alone, never its own sighting's
        mine = row_of[at, labelled.camera]
        each.append(np.where((exists & (mine >= 0))[:, None, None], X_own[np.maximum(mine, 0)], ends))
    scale = FIT_SCALE_PX / focal_px
    scores = _medians(labelled.camera, np.stack([_pair_errors(R[labelled.camera], t[labelled.camera], e, labelled.xy)
                                                 for e in each]), n)
    # each camera's pose fitted again to the others' ends at its best few shifts: the start fitted
    # it at the offsets so far, and a camera out of time kept the pose that fits it best there
    with np.errstate(invalid="ignore"):
        rank = np.argsort(np.argsort(np.where(np.isfinite(scores), scores, np.inf), axis=1), axis=1)
    again = _medians(labelled.camera, _refitted_errors(R, t, labelled, each, rank < REFIT_SHIFTS, scale), n)
    scores = np.where(np.isfinite(again), again, scores) * focal_px[:, None]
    return scores


def _refitted_errors(R: np.ndarray, t: np.ndarray, labelled: WandPairs, each: list[np.ndarray], refit: np.ndarray,
                     scale: np.ndarray) -> np.ndarray:
    """(S, P) each pair's error (as :func:`_pair_errors`) against the others' ends it meets at each
    shift (``each``: S of (P, 2, 3)), its camera's pose first fitted again to them (:func:`refit_poses`)
    where ``refit`` (N, S) bool, else NaN. One fit for every shift: camera c at shift j is
    pose c + N j of one stack (each pose's normal equations sum its own rows, in their order, so
    the digits are those of one fit a shift)."""
    n, S, P = len(R), len(each), len(labelled)
    rows = refit[labelled.camera].T  # (S, P)
    which, pair = np.nonzero(rows)  # shift-major, each shift's pairs in their order
    stacked = np.stack(each)[which, pair]
    cam = labelled.camera[pair] + n * which
    Rs, ts = refit_poses(np.tile(R, (S, 1, 1)), np.tile(t, (S, 1)), cam, stacked, labelled.xy[pair], np.tile(scale, S))
    out = np.full((S, P), np.nan)
    out[which, pair] = _pair_errors(Rs[cam], ts[cam], stacked, labelled.xy[pair])
    return out


def _medians(camera: np.ndarray, errors: np.ndarray, n: int) -> np.ndarray:
    """(N, S) each camera's median of each shift's errors (``errors`` (S, P), ``camera`` (P,)
    each pair's), NaN where it has fewer than :data:`MIN_TIMING_FRAMES` finite ones. The median
    is NumPy's: the mean of the two middle values of the finite ones, sorted (the one middle
    value for an odd count)."""
    S, P = errors.shape
    finite = np.isfinite(errors)
    key = np.where(finite, errors, np.inf)
    order = np.lexsort((key, np.broadcast_to(camera, (S, P))), axis=-1)  # by camera, then value: the finite first
    ordered = np.take_along_axis(key, order, axis=1)
    first = np.concatenate([[0], np.cumsum(np.bincount(camera, minlength=n))[:-1]])  # (N,) each camera's first row
    count = np.stack([np.bincount(camera[f], minlength=n) for f in finite])  # (S, N) finite errors
    lo, hi = first + (count - 1) // 2, first + count // 2
    with np.errstate(invalid="ignore"):
        middle = (np.take_along_axis(ordered, np.clip(lo, 0, P - 1), axis=1)
                  + np.take_along_axis(ordered, np.clip(hi, 0, P - 1), axis=1)) / 2
    return np.where(count >= MIN_TIMING_FRAMES, middle, np.nan).T


def refit_poses(R: np.ndarray, t: np.ndarray, camera: np.ndarray, ends: np.ndarray, xy: np.ndarray,
                scale: np.ndarray, steps: int = FIT_STEPS) -> tuple[np.ndarray, np.ndarray]:
    """Every camera's pose R (N, 3, 3), t (N, 3) moved by ``steps`` Gauss-Newton steps (a Cauchy
    loss of ``scale`` (N,), normalised) towards its pairs' blobs xy (P, 2, 2) seen from the points
    ``ends`` (P, 2, 3) (NaN: none), the nearer matching each step; ``camera`` (P,) each pair's.
    The update is x_cam -> rot(w) x_cam + d, so d(x_cam) = -[x_cam]x w + d."""
    n = len(R)
    R, t = R.copy(), t.copy()
    ok = np.isfinite(ends).all(axis=(1, 2))
    cam, ends, xy = camera[ok], ends[ok], xy[ok]
    cam2 = np.repeat(cam, 2)
    for _ in range(steps):
        xc = np.einsum("pij,pej->pei", R[cam], ends) + t[cam][:, None, :]  # (P, 2, 3)
        proj = xc[..., :2] / xc[..., 2:3]
        cross = np.linalg.norm(proj[:, ::-1] - xy, axis=2).sum(1) < np.linalg.norm(proj - xy, axis=2).sum(1)
        target = np.where(cross[:, None, None], xy[:, ::-1], xy)
        x, r = xc.reshape(-1, 3), (proj - target).reshape(-1, 2)  # (2P, 3), (2P, 2)
        iz = 1.0 / x[:, 2]
        dp = np.zeros((len(x), 2, 3))
        dp[:, 0, 0] = dp[:, 1, 1] = iz
        dp[:, 0, 2], dp[:, 1, 2] = -x[:, 0] * iz**2, -x[:, 1] * iz**2
        skew = np.zeros((len(x), 3, 3))
        skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -x[:, 2], x[:, 1], -x[:, 0]
        skew -= np.swapaxes(skew, 1, 2)
        J = np.concatenate([-dp @ skew, dp], axis=2)  # (2P, 2, 6)
        w = 1.0 / (1.0 + (r**2).sum(1) / scale[cam2] ** 2)
        # each camera's normal equations, every entry summed by one bincount (np.add.at was most of it);
        # the 21 distinct entries of J^T J only (the sums einsum "kai,kaj->kij" forms, term by term)
        H = _normal_matrices(J, w, cam2, n)
        g = sum_by(cam2, w[:, None] * np.einsum("kai,ka->ki", J, r), n)
        damp = 1e-9 * np.trace(H, axis1=1, axis2=2)[:, None, None] * np.eye(6) + 1e-12 * np.eye(6)
        step = -np.linalg.solve(H + damp, g[..., None])[..., 0]
        for c in np.flatnonzero(np.isfinite(step).all(1) & (np.abs(step).sum(1) > 0)):
            rot = rotvec_to_matrix(step[c, :3])
            R[c], t[c] = rot @ R[c], rot @ t[c] + step[c, 3:]
    return R, t


def _normal_matrices(J: np.ndarray, w: np.ndarray, group: np.ndarray, n: int) -> np.ndarray:
    """(n, 6, 6) the sums of w J^T J over the rows of each ``group`` (K,) in [0, n); J (K, 2, 6), w (K,).
    Its 21 distinct entries only, each row's product as einsum "kai,kaj->kij" forms it (two terms)
    and summed by one bincount in the rows' order: the digits of summing the whole products."""
    Jt = np.ascontiguousarray(J.transpose(1, 2, 0))  # (2, 6, K): each entry's products contiguous
    products = (Jt[0, _ROW] * Jt[0, _COL] + Jt[1, _ROW] * Jt[1, _COL]) * w  # (21, K)
    index = (np.arange(len(_ROW))[:, None] * n + group).ravel()
    upper = np.bincount(index, products.ravel(), minlength=len(_ROW) * n).reshape(len(_ROW), n).T
    H = np.empty((n, 6, 6))
    H[:, _ROW, _COL] = upper
    H[:, _COL, _ROW] = upper
    return H


def _pair_errors(R: np.ndarray, t: np.ndarray, ends: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """(P,) the mean distance, normalised, between each pair's blobs xy (P, 2, 2) and its ends
    (P, 2, 3) projected with R (P, 3, 3), t (P, 3), the nearer of the two matchings."""
    xc = np.einsum("pij,pej->pei", R, ends) + t[:, None, :]
    proj = xc[..., :2] / xc[..., 2:3]
    same = np.linalg.norm(proj - xy, axis=2).mean(axis=1)
    cross = np.linalg.norm(proj[:, ::-1] - xy, axis=2).mean(axis=1)
    return np.fmin(same, cross)
