"""First poses of every camera, before refinement.

With a static object, cameras whose PnP pose is unique start from it. Without one (or when
fewer than two cameras have a unique PnP pose) the start is wand-only, as in easyWand and Argus:
the essential matrix of the best-linked camera pair, its wand points triangulated and scaled by
the wand length. Every remaining camera is then added by robust resection from the wand points
it shares with the cameras already placed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from calib.errors import CalibrationError
from calib.labels import flatten, label_ends
from calib.observations import WandPairs
from calib.rig import Rig
from calib.static import StaticPose, resect
from calib.triangulate import triangulate_points

ESSENTIAL_THRESHOLD_PX = 2.0  # RANSAC inlier threshold; blob noise is well under a pixel
MIN_SHARED_FRAMES = 8  # a camera needs this many wand frames shared with placed cameras


@dataclass(frozen=True, eq=False)
class Initial:
    """Starting poses R (N, 3, 3), t (N, 3) and how each camera was placed."""

    R: np.ndarray
    t: np.ndarray
    source: list[str]
    notes: list[str] = field(default_factory=list)


def initial_poses(rig: Rig, pairs: WandPairs, static_poses: list | None = None) -> Initial:
    """Place every camera (see module docstring).

    Args:
        rig: the rig.
        pairs: unlabeled two-blob camera-frames.
        static_poses: output of :func:`calib.static.solve_static`, or None.

    Raises:
        CalibrationError: a camera shares too few frames with the others to be placed.
    """
    n = len(rig.cameras)
    R = np.tile(np.eye(3), (n, 1, 1))
    t = np.zeros((n, 3))
    known = np.zeros(n, bool)
    source = ["" for _ in range(n)]
    notes: list[str] = []
    if static_poses is not None:
        for c, pose in enumerate(static_poses):
            if isinstance(pose, StaticPose) and pose.unique:
                R[c], t[c], known[c] = pose.R, pose.t, True
                source[c] = "static PnP"
            elif isinstance(pose, StaticPose):
                notes.append(f"{rig.cameras[c].id}: static-object pose is ambiguous (planar flip); placed from the wand")
    if known.sum() < 2:
        R, t, known, source = _essential_start(rig, pairs)
    while not known.all():
        c = _resect_next(rig, pairs, R, t, known)
        known[c] = True
        source[c] = "wand resection"
    return Initial(R=R, t=t, source=source, notes=notes)


def shared_frames(pairs: WandPairs, n_cams: int) -> np.ndarray:
    """(N, N) number of frames in which both cameras see both wand ends."""
    seen = np.zeros((len(pairs.frames), n_cams), dtype=np.int64)
    seen[pairs.frame, pairs.camera] = 1
    return seen.T @ seen


def _essential_start(rig: Rig, pairs: WandPairs) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    n = len(rig.cameras)
    shared = shared_frames(pairs, n)
    np.fill_diagonal(shared, 0)
    a, b = np.unravel_index(np.argmax(shared), shared.shape)
    a, b = int(min(a, b)), int(max(a, b))
    if shared[a, b] < MIN_SHARED_FRAMES:
        raise CalibrationError(
            f"no two cameras share {MIN_SHARED_FRAMES} wand frames (best: {rig.cameras[a].id} and "
            f"{rig.cameras[b].id}, {shared[a, b]}); wave the wand where several cameras see it"
        )
    xa, xb = _common(pairs, a, b)
    # each frame offers two matchings of its ends; give RANSAC all four candidate matches
    p1 = np.concatenate([xa[:, 0], xa[:, 1], xa[:, 0], xa[:, 1]])
    p2 = np.concatenate([xb[:, 0], xb[:, 1], xb[:, 1], xb[:, 0]])
    focal = float(np.mean([rig.cameras[a].focal.mean(), rig.cameras[b].focal.mean()]))
    E, mask = cv2.findEssentialMat(p1, p2, np.eye(3), cv2.RANSAC, 0.9999, ESSENTIAL_THRESHOLD_PX / focal)
    if E is None or E.shape != (3, 3):
        raise CalibrationError(
            f"cameras {rig.cameras[a].id} and {rig.cameras[b].id}: no essential matrix fits their wand "
            "blobs; check the intrinsics in rig.json"
        )
    _, Rb, tb, _ = cv2.recoverPose(E, p1, p2, np.eye(3), mask=mask.copy())
    R = np.tile(np.eye(3), (n, 1, 1))
    t = np.zeros((n, 3))
    R[b], t[b] = Rb, tb.ravel()
    known = np.zeros(n, bool)
    known[[a, b]] = True
    labelled, _ = label_ends(R, t, pairs, known)
    point, camera, xy = flatten(labelled)
    X = triangulate_points(R, t, point, camera, xy, 2 * len(pairs.frames)).reshape(-1, 2, 3)
    lengths = np.linalg.norm(X[:, 0] - X[:, 1], axis=1)
    lengths = lengths[np.isfinite(lengths)]
    scale = rig.wand_length / np.median(lengths)
    t[b] *= scale
    source = ["" for _ in range(n)]
    source[a] = source[b] = "essential matrix"
    return R, t, known, source


def _common(pairs: WandPairs, a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
    """(S, 2, 2) blobs of cameras a and b in the frames both see, frame-aligned."""
    ia = np.flatnonzero(pairs.camera == a)
    ib = np.flatnonzero(pairs.camera == b)
    fa, fb = pairs.frame[ia], pairs.frame[ib]
    _, ja, jb = np.intersect1d(fa, fb, return_indices=True)
    return pairs.xy[ia[ja]], pairs.xy[ib[jb]]


def _resect_next(rig: Rig, pairs: WandPairs, R: np.ndarray, t: np.ndarray, known: np.ndarray) -> int:
    """Resect the unplaced camera sharing the most triangulated frames; returns its index."""
    labelled, _ = label_ends(R, t, pairs, known)
    point, camera, xy = flatten(labelled)
    X = triangulate_points(R, t, point, camera, xy, 2 * len(pairs.frames)).reshape(-1, 2, 3)
    have = np.all(np.isfinite(X), axis=(1, 2))
    counts = {}
    for c in np.flatnonzero(~known):
        sel = (pairs.camera == c) & have[pairs.frame]
        counts[int(c)] = int(sel.sum())
    c = max(counts, key=counts.get)
    cam = rig.cameras[c]
    if counts[c] < MIN_SHARED_FRAMES:
        raise CalibrationError(
            f"camera {cam.id!r} shares only {counts[c]} wand frames with the placed cameras "
            f"({', '.join(rig.cameras[k].id for k in np.flatnonzero(known))}); it cannot be placed. "
            f"Wave the wand where {cam.id} and the others see it at the same time"
        )
    sel = np.flatnonzero((pairs.camera == c) & have[pairs.frame])
    ends = X[pairs.frame[sel]]
    obs = pairs.xy[sel]
    # both matchings of each frame's ends: RANSAC keeps the right one
    Xc = np.concatenate([ends[:, 0], ends[:, 1], ends[:, 0], ends[:, 1]])
    xc = np.concatenate([obs[:, 0], obs[:, 1], obs[:, 1], obs[:, 0]])
    found = resect(Xc, xc, float(cam.focal.mean()))
    if not found:
        raise CalibrationError(f"camera {cam.id!r}: {found}; check its intrinsics in rig.json")
    R[c], t[c], _ = found
    return c
