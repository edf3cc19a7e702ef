"""Label the blobs of a collinear multi-marker wand (rig.json ``wand.markers_m``) without labels in the data.

1. Order (:func:`order_markers`): in a camera-frame that shows all K markers, the blobs lie on
   the image of the wand's line (after undistortion), and perspective keeps their order along
   it. The first and last are the end markers, the rest interior markers counted from the first.
2. Ends (:func:`wandcal.calib.start.labels.label_ends` on :meth:`MarkerBlobs.ends`): the ends are
   a two-marker wand, whose end order is made consistent across cameras exactly as for a
   two-marker wand (including the end-swap of frames only two cameras see).
3. Which end is which marker (:func:`label_interior`): with the ends triangulated, the two
   readings of the layout (end 0 is the first marker of the layout's axis, or the last) put the
   interior markers at different 3D points for an asymmetric layout; the reading whose points
   reproject nearer the frame's interior blobs, summed over every camera (each blob's error
   capped at :data:`CAP_PX`, so that an outlier cannot outvote the rest), wins. Multi-view, it
   does not rest on one image's foreshortened spacing (3 markers have no projective invariant;
   with 4 or more the cross-ratio would tell the ends apart in one image too).

A planar wand (a T) is labelled in each image by the pose that fits
(wandcal.calib.start.planarlabels): its rows come ordered [end 0, the other markers in layout
order, end 1], the ends being the layout's own (no end-swap to resolve). At the refined rig
(:func:`label_interior`) each frame's markers are triangulated from its confidently labelled
camera-frames and every camera-frame is labelled again by the assignment of its blobs to those
markers' images, which mends the views a single image cannot label (the plane seen edge on).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.geometry import undistort_by_camera
from wandcal.calib.observations import PointTracks, WandPairs, wand_pairs
from wandcal.calib.rig import Rig, WandObservations
from wandcal.calib.start.planarlabels import label_planar
from wandcal.calib.triangulate import triangulate_points
from wandcal.calib.wandlayout import axial_offsets, end_markers, is_planar, plane_offsets

# a blob farther than this from both readings' interior marker is an outlier (a reflection, a
# merged blob) and must not outvote the frame's other cameras: its error counts at most this
# much. 4 px is 8 sigma of a 0.5 px blob centre, and far below the 20-100 px that the two
# readings of a real layout put the interior markers apart
CAP_PX = 4.0
# a planar wand's roll about its axis is searched in 72 steps of 5 degrees, then in steps of 1 degree
# about the best: a marker 0.3 m off the axis moves 5 mm a fine step, ~1.5 px at 3 m, within the cap;
# a coarse step's half, 13 mm, ~5 px, within the coarse cap. The assignment that follows is exact
ROLL_COARSE = 72
ROLL_FINE = 5  # fine steps each side of the coarse best: one coarse step
DOUBT_PX = 2 * CAP_PX  # a row whose blobs lie this far (in sum) from its frame's solved markers casts doubt on them
ROLL_COARSE_CAP_PX = 4 * CAP_PX  # the coarse roll is up to half a step off: its markers' images ~5 px off


@dataclass(frozen=True, eq=False)
class MarkerBlobs(WandPairs):
    """Camera-frames showing every marker, each row's blobs ordered along the wand's image: the
    fields of :class:`WandPairs` with K blobs a row, xy (P, K, 2) normalised and uv (P, K, 2) raw
    pixels; ``dropped`` counts camera-frames with fewer or more blobs. A planar wand's rows are
    labelled instead (:func:`planar_order`), and ``fit_px`` (P,) holds each one's pose error."""

    fit_px: np.ndarray | None = None

    def ends(self) -> WandPairs:
        """The end markers as a two-marker wand's pairs (rows in this order)."""
        return WandPairs(self.frame, self.camera, self.xy[:, [0, -1]], self.uv[:, [0, -1]], self.frames, self.dropped)


@dataclass(frozen=True, eq=False)
class MarkerLabels:
    """Every blob of the labelled rows named.

    marker: (P, K) the layout index of each blob, in the row's order from the labelled end 0;
    xy: (P, K, 2) the blobs in that order, uv: (P, K, 2) their raw pixels; along: (P, K) each blob's marker position on the
    axis from the ends' midpoint, metres, end 0 at -L/2; reversed: (F,) frames whose end 0 is
    the layout's last marker on its axis; across: (P, K) a planar wand's offsets across the axis
    in its plane, metres (wandcal.calib.wandlayout.plane_offsets), else None.
    """

    marker: np.ndarray
    xy: np.ndarray
    uv: np.ndarray
    along: np.ndarray
    reversed: np.ndarray
    across: np.ndarray | None = None

    def on_axis(self) -> MarkerLabels:
        """These labels with only the markers on the wand's axis (all of a collinear wand's)."""
        if self.across is None:
            return self
        cols = np.flatnonzero(np.all(self.across == 0, axis=0))
        return MarkerLabels(self.marker[:, cols], self.xy[:, cols], self.uv[:, cols], self.along[:, cols], self.reversed)


def end_pairs(rig: Rig, wand: WandObservations) -> WandPairs:
    """Each camera-frame's two wand ends, undistorted, for a wand of any kind: a two-marker wand's
    two-blob camera-frames (:func:`wandcal.calib.observations.wand_pairs`), or the end markers of
    the camera-frames that show every marker of a multi-marker wand (:meth:`MarkerBlobs.ends`;
    a planar wand's come labelled by its layout). What the whole-frame sync, ``wandcal check`` and
    ``--solve-only`` read, so that they take every wand ``calibrate`` takes."""
    if rig.wand_markers is None or len(rig.wand_markers) == 2:
        return wand_pairs(rig, wand)
    return order_markers(rig, wand).ends()


def order_markers(rig: Rig, wand: WandObservations) -> MarkerBlobs:
    """Group blobs by camera-frame, keep those with exactly the wand's K blobs, undistort and
    order them along the wand's image line (from one extreme blob to the other)."""
    if rig.wand_markers is None:
        raise CalibrationError("the rig's wand has no 'markers_m': order_markers is for multi-marker wands")
    k, n_cams = len(rig.wand_markers), len(rig.cameras)
    key = wand.frame * n_cams + wand.camera
    order = np.argsort(key, kind="stable")
    uniq, start, count = np.unique(key[order], return_index=True, return_counts=True)
    full = count == k
    dropped = {"fewer_blobs": int((count < k).sum()), "extra_blobs": int((count > k).sum())}
    index = order[start[full][:, None] + np.arange(k)]  # (P, K)
    camera = uniq[full] % n_cams
    uv = wand.uv[index]
    xy = undistort_by_camera(rig.cameras, camera, uv)
    gaps = np.linalg.norm(xy[:, :, None] - xy[:, None], axis=3)  # (P, K, K)
    flat = gaps.reshape(len(xy), -1).argmax(axis=1)
    i, j = flat // k, flat % k
    rows = np.arange(len(xy))
    axis = xy[rows, j] - xy[rows, i]
    position = np.einsum("pkd,pd->pk", xy - xy[rows, i][:, None], axis)
    ranked = np.argsort(position, axis=1)
    frames, frame_idx = np.unique(uniq[full] // n_cams, return_inverse=True)
    fit = None
    if is_planar(rig.wand_markers):
        focal = np.array([c.focal for c in rig.cameras]).mean(axis=1)[camera]
        ranked, fit = planar_order(xy, rig.wand_markers, focal)
    return MarkerBlobs(frame_idx, camera, np.take_along_axis(xy, ranked[..., None], 1),
                       np.take_along_axis(uv, ranked[..., None], 1), frames, dropped, fit)


def planar_order(xy: np.ndarray, layout: np.ndarray, focal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(P, K) each row's blob indices in the order [end 0, the other markers, end 1] of the layout
    (K, 3), and (P,) the labelling's pose error, pixels (wandcal.calib.start.planarlabels)."""
    blob_of, fit = label_planar(xy, plane_offsets(layout), focal)
    return blob_of[:, _column_markers(layout)], fit


def _column_markers(layout: np.ndarray) -> np.ndarray:
    """(K,) the layout index of each column of a planar wand's rows: end 0, the others, end 1."""
    a, b = end_markers(layout)
    return np.array([a, *[k for k in range(len(layout)) if k not in (a, b)], b])


def label_interior(rig: Rig, blobs: MarkerBlobs, labelled: WandPairs, R: np.ndarray, t: np.ndarray,
                   wand: tuple[np.ndarray, np.ndarray] | None = None) -> MarkerLabels:
    """Name every blob of ``blobs`` given its ends labelled consistently across cameras.

    Args:
        blobs: :func:`order_markers`' rows; labelled: ``blobs.ends()`` labelled by
            :func:`wandcal.calib.start.labels.label_ends` (the same rows, ends maybe swapped).
        R: (N, 3, 3), t: (N, 3) approximate poses, metres.
        wand: a planar wand's solved frames, (frame numbers (F',), ends (F', 2, 3)) (its labels are mended in 3D).
    """
    if rig.wand_markers is None or rig.wand_length is None:
        raise CalibrationError("the rig's wand has no 'markers_m': label_interior is for multi-marker wands")
    if blobs.fit_px is not None:
        if wand is None:
            raise CalibrationError("a planar wand is labelled again at its solved frames: give label_interior the wand")
        return _label_planar_at(rig, blobs, R, t, wand)
    offsets = axial_offsets(rig.wand_markers)
    by_axis = np.argsort(offsets)  # layout indices from one end of the axis to the other
    o = offsets[by_axis]
    swapped = ~np.all(np.isclose(labelled.uv[:, 0], blobs.uv[:, 0]), axis=1)
    xy, uv = blobs.xy.copy(), blobs.uv.copy()
    xy[swapped] = xy[swapped, ::-1]
    uv[swapped] = uv[swapped, ::-1]
    n_frames = len(blobs.frames)
    point = np.concatenate([2 * labelled.frame, 2 * labelled.frame + 1])
    camera2 = np.concatenate([labelled.camera, labelled.camera])
    X = triangulate_points(R, t, point, camera2, np.concatenate([labelled.xy[:, 0], labelled.xy[:, 1]]),
                           2 * n_frames).reshape(-1, 2, 3)
    mid, vec = X.mean(axis=1), X[:, 1] - X[:, 0]
    measured = np.linalg.norm(vec, axis=1)
    d = vec / np.where(measured > 0, measured, 1.0)[:, None]
    scale = measured / rig.wand_length  # the start's own scale, so that a scale error is not read as a label error
    along_a, along_b = o, -o[::-1]  # end 0 is the axis' first marker, or its last
    focal = np.array([c.focal for c in rig.cameras])[blobs.camera]  # (P, 2) pixels per normalised unit
    err = np.zeros((n_frames, 2))
    for h, along in enumerate((along_a, along_b)):
        P = mid[blobs.frame][:, None] + (scale[blobs.frame][:, None] * along[None])[..., None] * d[blobs.frame][:, None]
        xc = np.einsum("pij,pkj->pki", R[blobs.camera], P) + t[blobs.camera][:, None]
        px = np.linalg.norm((xc[..., :2] / xc[..., 2:3] - xy) * focal[:, None], axis=2)[:, 1:-1]
        e = np.minimum(np.where(np.isfinite(px), px, CAP_PX), CAP_PX).sum(axis=1)
        err[:, h] = np.bincount(blobs.frame, e, minlength=n_frames)
    reversed_ = err[:, 1] < err[:, 0]
    rev = reversed_[blobs.frame]
    marker = np.where(rev[:, None], by_axis[::-1][None], by_axis[None])
    along = np.where(rev[:, None], along_b[None], along_a[None])
    return MarkerLabels(marker, xy, uv, along, reversed_)


def interior_tracks(labels: MarkerLabels, labelled: WandPairs) -> PointTracks:
    """A multi-marker wand's interior markers as point tracks: each (frame, marker) a 3D point seen
    by the cameras whose row shows it, so that the judgement reads them as it reads any point
    (calib/run/judgement.py, issue 31); the ends stay ``labelled``'s.

    Args:
        labels: :func:`label_interior`'s names of every blob, rows as ``labelled``'s (K >= 3 columns,
            end 0 first, end 1 last).
        labelled: the wand ends told apart: frame (P,) into ``frames`` (capture frame numbers), camera (P,).

    Returns tracks whose ``frames`` are capture frame numbers and ``labels`` "wand marker m" (m the
    layout index); points seen by one camera only are left out.
    """
    k = labels.marker.shape[1]
    marker = labels.marker[:, 1:-1]
    key = (labelled.frame[:, None] * k + marker).ravel()
    camera = np.repeat(labelled.camera, k - 2)
    order = np.lexsort((camera, key))
    keys, track = np.unique(key[order], return_inverse=True)
    names = np.array([f"wand marker {m}" for m in range(k)])
    tracks = PointTracks(track, camera[order], labels.xy[:, 1:-1].reshape(-1, 2)[order],
                         labels.uv[:, 1:-1].reshape(-1, 2)[order], labelled.frames[keys // k], labels=names[keys % k])
    return tracks.subset(np.ones(len(track), bool))


def _label_planar_at(rig: Rig, blobs: MarkerBlobs, R: np.ndarray, t: np.ndarray,
                     wand: tuple[np.ndarray, np.ndarray]) -> MarkerLabels:
    """A planar wand's rows labelled again at the solved rig: R (N, 3, 3), t (N, 3) and ``wand``,
    (frame numbers (F',), ends (F', 2, 3)) of the frames the ends' refinement solved.

    Each frame's ends are known in 3D, so its markers are known up to the roll of the plane about
    the axis (and, should the frame's majority have mislabelled its ends, the axis' sense): the
    roll and sense whose markers' images lie nearest the blobs over every camera of the frame
    (each blob's distance capped at ``CAP_PX``) win, and each row's blobs are then assigned to
    those images by the least total distance. A frame the refinement left out, or one with a row
    that its solved ends do not fit (a mislabelled row can bend a frame that two cameras see), is
    tried again with the ends of every pair of its rows, and the best fit wins; a frame of one
    row keeps its own labelling."""
    layout = rig.wand_markers
    assert layout is not None
    k, n_frames = len(layout), len(blobs.frames)
    columns = _column_markers(layout)
    offsets = plane_offsets(layout)[columns]  # (K, 2) (along, across) of each column
    numbers, ends = wand
    where = {int(f): i for i, f in enumerate(numbers)}
    solved = np.array([where.get(int(f), -1) for f in blobs.frames])
    has = solved >= 0
    fit = _fit_frames(rig, blobs, R, t, offsets, ends[solved[has]], np.flatnonzero(has))
    doubtful = ~has
    doubtful[np.unique(blobs.frame[fit.rows[fit.row_cost > DOUBT_PX]])] = True
    pair_ends, pair_frame = _pair_ends(blobs, R, t, np.flatnonzero(doubtful))
    fit = fit.merged(_fit_frames(rig, blobs, R, t, offsets, pair_ends, pair_frame), n_frames)
    dist = np.linalg.norm(blobs.xy[fit.rows][:, :, None] - fit.images[:, None], axis=3) * fit.focal[:, None, None]
    dist = np.minimum(np.nan_to_num(dist, nan=CAP_PX), CAP_PX)  # (Q, blob, column)
    perms = np.array(list(itertools.permutations(range(k))))  # column -> blob
    order = np.tile(np.arange(k), (len(blobs), 1))  # rows of one-row frames keep their own order
    order[fit.rows] = perms[np.argmin(dist[:, perms, np.arange(k)].sum(axis=2), axis=1)]
    xy = np.take_along_axis(blobs.xy, order[..., None], 1)
    uv = np.take_along_axis(blobs.uv, order[..., None], 1)
    P = len(blobs)
    return MarkerLabels(np.tile(columns, (P, 1)), xy, uv, np.tile(offsets[:, 0], (P, 1)), np.zeros(n_frames, bool),
                        np.tile(offsets[:, 1], (P, 1)))


@dataclass(frozen=True, eq=False)
class _FrameFit:
    """Hypotheses of planar frames fitted to their rows: frame (H,) and cost (H,) of each, and
    for every row of every hypothesis: rows (Q,), hyp (Q,), images (Q, K, 2) of the markers in
    column order, normalised, focal (Q,), row_cost (Q,) its blobs' capped distances, px."""

    frame: np.ndarray
    cost: np.ndarray
    rows: np.ndarray
    hyp: np.ndarray
    images: np.ndarray
    focal: np.ndarray
    row_cost: np.ndarray

    def merged(self, other: _FrameFit, n_frames: int) -> _FrameFit:
        """Both sets of hypotheses, keeping each frame's cheapest only."""
        frame, cost = np.concatenate([self.frame, other.frame]), np.concatenate([self.cost, other.cost])
        best = np.full(n_frames, np.inf)
        np.minimum.at(best, frame, cost)
        first = np.zeros(len(frame), bool)
        for fr in np.unique(frame):  # one hypothesis a frame: the first of the cheapest
            cands = np.flatnonzero((frame == fr) & (cost == best[fr]))
            first[cands[0]] = True
        hyp = np.concatenate([self.hyp, other.hyp + len(self.frame)])
        keep = first[hyp]
        renumber = np.cumsum(first) - 1
        cat = [np.concatenate([getattr(self, f), getattr(other, f)])[keep] for f in ("rows", "images", "focal", "row_cost")]
        return _FrameFit(frame[first], cost[first], cat[0], renumber[hyp[keep]], cat[1], cat[2], cat[3])


def _fit_frames(rig: Rig, blobs: MarkerBlobs, R: np.ndarray, t: np.ndarray, offsets: np.ndarray, ends: np.ndarray,
                frame_of: np.ndarray) -> _FrameFit:
    """Each hypothesis (its ends (H, 2, 3) and frame (H,)) with the roll and sense of its plane
    that fit its frame's rows best: a coarse search over both senses, then a fine one."""
    k = len(offsets)
    if not len(frame_of):
        z = np.zeros(0, int)
        return _FrameFit(z, np.zeros(0), z, z, np.zeros((0, k, 2)), np.zeros(0), np.zeros(0))
    members = [np.flatnonzero(blobs.frame == fr) for fr in range(len(blobs.frames))]
    rows = np.concatenate([members[fr] for fr in frame_of] + [np.zeros(0, int)])
    h = np.repeat(np.arange(len(frame_of)), [len(members[fr]) for fr in frame_of]).astype(int)
    E = ends[h]  # (Q, 2, 3)
    m = E.mean(axis=1)
    d = (E[:, 1] - E[:, 0]) / np.linalg.norm(E[:, 1] - E[:, 0], axis=1, keepdims=True)
    u1 = np.cross(d, np.where(np.abs(d[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]]))
    u1 /= np.linalg.norm(u1, axis=1, keepdims=True)
    u2 = np.cross(d, u1)
    cam = blobs.camera[rows]
    focal = np.array([c.focal for c in rig.cameras]).mean(axis=1)[cam]
    n_hyp = len(frame_of)

    def images(phi: np.ndarray, sense: np.ndarray) -> np.ndarray:
        """(Q, S, K, 2) each row's images of its hypothesis' markers at rolls phi and senses (Q, S)."""
        e = np.cos(phi)[..., None] * u1[:, None] + np.sin(phi)[..., None] * u2[:, None]
        X = m[:, None, None] + sense[..., None, None] * (offsets[:, :1] * d[:, None, None] + offsets[:, 1:] * e[:, :, None])
        return _project(R[cam], t[cam], X)

    def row_costs(phi: np.ndarray, sense: np.ndarray, cap: float) -> np.ndarray:
        """(Q, S) each row's blobs' distances to their nearest marker image, each capped at ``cap`` px."""
        dist = np.linalg.norm(blobs.xy[rows][:, None, :, None] - images(phi, sense)[:, :, None], axis=4)
        return np.minimum(np.nan_to_num(dist * focal[:, None, None, None], nan=cap), cap).min(axis=3).sum(axis=2)

    def best(phi: np.ndarray, sense: np.ndarray, cap: float) -> np.ndarray:
        out = np.zeros((n_hyp, phi.shape[1]))
        np.add.at(out, h, row_costs(phi[h], sense[h], cap))
        return np.argmin(out, axis=1)

    coarse = np.arange(ROLL_COARSE) * (2 * np.pi / ROLL_COARSE)
    phi = np.tile(np.concatenate([coarse, coarse]), (n_hyp, 1))
    sense = np.tile(np.repeat([1.0, -1.0], ROLL_COARSE), (n_hyp, 1))
    pick = best(phi, sense, ROLL_COARSE_CAP_PX)
    fine = (np.arange(-ROLL_FINE, ROLL_FINE + 1) * (2 * np.pi / ROLL_COARSE / ROLL_FINE))[None]
    phi = phi[np.arange(n_hyp), pick][:, None] + fine
    sense = np.repeat(sense[np.arange(n_hyp), pick][:, None], fine.shape[1], axis=1)
    pick = best(phi, sense, CAP_PX)
    phi, sense = phi[np.arange(n_hyp), pick][h, None], sense[np.arange(n_hyp), pick][h, None]
    cost = row_costs(phi, sense, CAP_PX)[:, 0]
    return _FrameFit(np.asarray(frame_of, int), np.bincount(h, cost, minlength=n_hyp), rows, h,
                     images(phi, sense)[:, 0], focal, cost)


def _pair_ends(blobs: MarkerBlobs, R: np.ndarray, t: np.ndarray, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(H, 2, 3) the ends of each of ``frames`` triangulated from each pair of its rows (as their
    own labels name them), and (H,) the frame of each."""
    pr = np.array([(fr, i, j) for fr in frames for i, j in itertools.combinations(np.flatnonzero(blobs.frame == fr), 2)],
                  dtype=int).reshape(-1, 3)
    n = len(pr)
    both = np.concatenate([pr[:, 1], pr[:, 2]])  # (2n,) rows
    point = np.concatenate([2 * np.arange(n), 2 * np.arange(n)])
    xy = blobs.xy[both]  # (2n, K, 2)
    X = triangulate_points(R, t, np.concatenate([point, point + 1]), np.concatenate([blobs.camera[both]] * 2),
                           np.concatenate([xy[:, 0], xy[:, -1]]), 2 * n).reshape(n, 2, 3)
    ok = np.all(np.isfinite(X), axis=(1, 2))
    return X[ok], pr[ok, 0]


def _project(R: np.ndarray, t: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Normalised images (..., 2) of points X (Q, ..., 3) in cameras R (Q, 3, 3), t (Q, 3)."""
    shape = X.shape
    Xf = X.reshape(len(X), -1, 3)
    xc = np.einsum("qij,qkj->qki", R, Xf) + t[:, None]
    return (xc[..., :2] / xc[..., 2:3]).reshape(*shape[:-1], 2)
