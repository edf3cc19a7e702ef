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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.geometry import undistort_by_camera
from wandcal.calib.observations import WandPairs
from wandcal.calib.rig import Rig, WandObservations
from wandcal.calib.triangulate import triangulate_points
from wandcal.calib.wandlayout import axial_offsets

# a blob farther than this from both readings' interior marker is an outlier (a reflection, a
# merged blob) and must not outvote the frame's other cameras: its error counts at most this
# much. 4 px is 8 sigma of a 0.5 px blob centre, and far below the 20-100 px that the two
# readings of a real layout put the interior markers apart
CAP_PX = 4.0


class MarkerBlobs(WandPairs):
    """Camera-frames showing every marker, each row's blobs ordered along the wand's image: the
    fields of :class:`WandPairs` with K blobs a row, xy (P, K, 2) normalised and uv (P, K, 2) raw
    pixels; ``dropped`` counts camera-frames with fewer or more blobs."""

    def ends(self) -> WandPairs:
        """The end markers as a two-marker wand's pairs (rows in this order)."""
        return WandPairs(self.frame, self.camera, self.xy[:, [0, -1]], self.uv[:, [0, -1]], self.frames, self.dropped)


@dataclass(frozen=True, eq=False)
class MarkerLabels:
    """Every blob of the labelled rows named.

    marker: (P, K) the layout index of each blob, in the row's order from the labelled end 0;
    xy: (P, K, 2) the blobs in that order, uv: (P, K, 2) their raw pixels; along: (P, K) each blob's marker position on the
    axis from the ends' midpoint, metres, end 0 at -L/2; reversed: (F,) frames whose end 0 is
    the layout's last marker on its axis.
    """

    marker: np.ndarray
    xy: np.ndarray
    uv: np.ndarray
    along: np.ndarray
    reversed: np.ndarray


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
    return MarkerBlobs(frame_idx, camera, np.take_along_axis(xy, ranked[..., None], 1),
                       np.take_along_axis(uv, ranked[..., None], 1), frames, dropped)


def label_interior(rig: Rig, blobs: MarkerBlobs, labelled: WandPairs, R: np.ndarray, t: np.ndarray) -> MarkerLabels:
    """Name every blob of ``blobs`` given its ends labelled consistently across cameras.

    Args:
        blobs: :func:`order_markers`' rows; labelled: ``blobs.ends()`` labelled by
            :func:`wandcal.calib.start.labels.label_ends` (the same rows, ends maybe swapped).
        R: (N, 3, 3), t: (N, 3) approximate poses, metres.
    """
    if rig.wand_markers is None or rig.wand_length is None:
        raise CalibrationError("the rig's wand has no 'markers_m': label_interior is for multi-marker wands")
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
