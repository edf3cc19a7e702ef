"""Captures that cannot calibrate, or calibrate only weakly, told apart before the solve.

Each case gets a message that names it and says what to record instead (docs/reliability.md,
"Degenerate rigs", has the measurements behind each answer):

| case | answer |
|---|---|
| the wand never moved, in every camera or in one | error: its poses follow from nothing |
| the wand stayed in one plane (one depth) | error: a plane fixes a pair's pose only up to a mirror image |
| the static object identified in one camera only | warning: the world frame falls back |
| cameras linked to the others only through one camera | warning: that camera's error carries into them |

All cameras on one line is not among them: the wand's 3D points fix every pose whatever the
cameras' layout, and such a rig calibrates to the same accuracy (tests/reliability).
"""

from __future__ import annotations

import cv2
import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.observations import PointTracks, WandPairs
from wandcal.calib.rig import Rig, camera_list
from wandcal.calib.start.chain import (
    ESSENTIAL_THRESHOLD_PX,
    MIN_PAIR_MATCHES,
    Views,
    camera_groups,
    camera_views,
    spread,
)

# A hand-held wand held still wobbles by a pixel or two; RANSAC's 2 px inlier threshold cannot
# tell positions a few thresholds apart, so a wand whose image moved less than five thresholds
# (RMS about its mean) carries no geometry. A wand waved through a volume moves 100-200 px RMS.
STILL_PX = 5 * ESSENTIAL_THRESHOLD_PX
STILL_MIN_FRAMES = 10  # fewer frames say nothing about motion; the start's own errors name them
# A plane's two views are related by a homography. Waved through a volume, 0-16% of a pair's
# frames fit one (both ends within the 2 px threshold; 2 cm of depth is 7 px of parallax at 3 m);
# swept in a plane, 97-100% do (tests/reliability/test_degenerate.py). Half-way between decides.
PLANAR_SHARE = 0.6
PLANAR_MIN_FRAMES = 20  # a pair needs this many shared frames for its share to mean anything
PLANAR_PAIRS = 4  # the best-linked pairs judged; the median of their shares decides
PLANAR_FRAMES = 60  # frames per pair: a share of 0-16% against 97-100% needs no more to tell apart
# half the candidate matches are the wrong end order, so 1/16 of 4-samples are clean: 300 draws miss
# every clean one with probability (15/16)^300 ~ 4e-9 (2000 draws over 150 frames cost 0.3 s at 8 x 1500)
HOMOGRAPHY_ITERATIONS = 300


def check_capture(rig: Rig, pairs: WandPairs, tracks: PointTracks | None, static_poses: list | None) -> list[str]:
    """Refuse a capture from which no calibration follows; return warnings for weak ones.

    Args:
        rig: the rig.
        pairs: the wand's two-blob camera-frames (may be empty without a wand).
        tracks: single-point tracks, or None.
        static_poses: :func:`wandcal.calib.start.static.solve_static`'s answer per camera, or None.

    Raises:
        CalibrationError: the wand never moved, or stayed in one plane.
    """
    if len(pairs):
        _check_motion(rig, pairs)
        _check_planar(rig, pairs, camera_views(pairs, None, len(rig.cameras)))
    warnings = []
    if static_poses is not None:
        warnings += _static_in_one_camera(rig, static_poses)
    warnings += weak_links(rig, camera_views(pairs, tracks, len(rig.cameras)))
    return warnings


def wand_motion_px(pairs: WandPairs, n_cams: int) -> tuple[np.ndarray, np.ndarray]:
    """Per camera: (N,) RMS distance in pixels of the wand's image midpoint from its mean, NaN for
    a camera without wand frames; and (N,) its number of wand frames."""
    frames = np.bincount(pairs.camera, minlength=n_cams)
    mid = pairs.uv.mean(axis=1)
    # per camera by sums, not a mask over every pair per camera (cameras x pairs); the spread about
    # the mean is taken about a sample of it, so that the sums do not cancel away its digits
    with np.errstate(invalid="ignore", divide="ignore"):
        ref = np.zeros((n_cams, 2))
        ref[pairs.camera[::-1]] = mid[::-1]  # each camera's first midpoint
        d = mid - ref[pairs.camera]
        mean = np.stack([np.bincount(pairs.camera, d[:, k], minlength=n_cams) for k in range(2)], 1) / frames[:, None]
        square = np.bincount(pairs.camera, np.sum(d**2, axis=1), minlength=n_cams) / frames
        motion = np.sqrt(np.maximum(square - np.sum(mean**2, axis=1), 0.0))
    return np.where(frames > 0, motion, np.nan), frames


def _check_motion(rig: Rig, pairs: WandPairs) -> None:
    motion, frames = wand_motion_px(pairs, len(rig.cameras))
    judged = np.flatnonzero(frames >= STILL_MIN_FRAMES)
    still = [c for c in judged if motion[c] < STILL_PX]
    if not still:
        return
    per_camera = ", ".join(f"{rig.cameras[c].id} {motion[c]:.1f} px over {frames[c]} frames" for c in still)
    if len(still) == len(judged):
        raise CalibrationError(
            f"the wand never moved: its image stayed in one place in every camera ({per_camera}; a wand waved "
            f"through the volume moves over {STILL_PX:g} px), and two fixed points cannot place a camera. Record "
            "again, waving the wand through the whole volume"
        )
    ids = camera_list([rig.cameras[c].id for c in still], len(rig.cameras))
    raise CalibrationError(
        f"camera(s) {ids} saw the wand in one place only ({per_camera}), which cannot place a camera: wave the "
        f"wand through {ids}'s view as well, or remove {ids} from rig.json"
    )


def homography_share(pairs: WandPairs, views: Views, a: int, b: int, focal_px: float) -> float:
    """The share of the wand frames cameras a and b share whose two ends fit one homography
    between their images (in either end order): 1 for a wand swept in a plane."""
    frames = spread(np.flatnonzero((views.wand[:, a] >= 0) & (views.wand[:, b] >= 0)), PLANAR_FRAMES)
    xa, xb = pairs.xy[views.wand[frames, a]], pairs.xy[views.wand[frames, b]]
    p1 = np.concatenate([xa[:, 0], xa[:, 1], xa[:, 0], xa[:, 1]])
    p2 = np.concatenate([xb[:, 0], xb[:, 1], xb[:, 1], xb[:, 0]])
    threshold = ESSENTIAL_THRESHOLD_PX / focal_px
    H, _ = cv2.findHomography(p1, p2, cv2.RANSAC, threshold, maxIters=HOMOGRAPHY_ITERATIONS, confidence=0.999)
    if H is None:
        return 0.0
    h = np.concatenate([p1, np.ones((len(p1), 1))], axis=1) @ H.T
    with np.errstate(divide="ignore", invalid="ignore"):
        fit = np.linalg.norm(h[:, :2] / h[:, 2:] - p2, axis=1) < threshold
    S = len(frames)
    both = (fit[:S] & fit[S : 2 * S]) | (fit[2 * S : 3 * S] & fit[3 * S :])
    return float(both.mean())


def _check_planar(rig: Rig, pairs: WandPairs, views: Views) -> None:
    shared = views._shared[0]  # the wand frames each pair shares
    ia, ib = np.triu_indices(len(rig.cameras), 1)
    order = [k for k in np.argsort(-shared[ia, ib], kind="stable") if shared[ia[k], ib[k]] >= PLANAR_MIN_FRAMES]
    judged = []
    for k in order[:PLANAR_PAIRS]:
        a, b = int(ia[k]), int(ib[k])
        focal = 0.5 * (rig.cameras[a].focal.mean() + rig.cameras[b].focal.mean())
        judged.append((homography_share(pairs, views, a, b, focal), a, b))
    if not judged or np.median([s for s, _, _ in judged]) < PLANAR_SHARE:
        return
    share, a, b = max(judged)
    raise CalibrationError(
        f"the wand stayed in one plane (one depth): {share:.0%} of the frames {rig.cameras[a].id} and "
        f"{rig.cameras[b].id} share fit one plane-to-image mapping (a homography), as do most frames of the other "
        f"camera pairs. From a flat sweep a camera's pose cannot be told from its mirror image. Record again, "
        "waving the wand at several heights and depths through the volume"
    )


def _static_in_one_camera(rig: Rig, static_poses: list) -> list[str]:
    found = [c for c, pose in enumerate(static_poses) if pose]
    if len(found) != 1:
        return []
    cam = rig.cameras[found[0]].id
    return [(f"the static object was identified in {cam} only; its frame needs it in two or more cameras, so the "
             "result is not in the static object's frame (world.frame says which it is): make sure a second camera "
             "sees all of its markers")]


def weak_links(rig: Rig, views: Views) -> list[str]:
    """A warning for each group of cameras linked to the rest only through one camera (a cut
    vertex of the camera graph, whose edges are pairs sharing ``MIN_PAIR_MATCHES``
    correspondences): that camera's pose error carries into the group unchecked."""
    n = len(rig.cameras)
    linked = views.links() >= MIN_PAIR_MATCHES
    np.fill_diagonal(linked, False)
    if n < 3 or len(camera_groups(linked)) != 1:
        return []  # a disconnected rig cannot be placed at all: the initial poses say which camera
    out = []
    for v in _cut_cameras(linked):
        keep = np.ones(n, bool)
        keep[v] = False
        parts = camera_groups(linked, keep)
        for part in parts[1:]:
            ids = [rig.cameras[c].id for c in part]
            names = camera_list(ids, n)
            out.append(f"{names} {'is' if len(ids) == 1 else 'are'} linked to the other cameras only through "
                       f"{rig.cameras[v].id}: an error in {rig.cameras[v].id}'s pose carries into "
                       f"{'it' if len(ids) == 1 else 'them'} unchecked; wave the wand where {names} and a camera other "
                       f"than {rig.cameras[v].id} see it at the same time")
    return out


def _cut_cameras(linked: np.ndarray) -> list[int]:
    """The cut vertices of the connected graph ``linked`` (N, N) bool, ascending, by Hopcroft and
    Tarjan's low points: one depth-first search whose steps each look at a camera's whole row at
    once (2N NumPy steps), where removing each camera in turn and regrouping the rest costs N
    groupings (0.5 s at 128 cameras), and a search edge by edge ~N^2 Python steps (0.14 s)."""
    n = len(linked)
    depth, parent = np.full(n, -1), np.full(n, -1)
    order = [0]  # the search's preorder
    depth[0] = 0
    stack = [0]
    while stack:
        v = stack[-1]
        new = np.flatnonzero(linked[v] & (depth < 0))
        if len(new):
            u = int(new[0])
            depth[u], parent[u] = depth[v] + 1, v
            order.append(u)
            stack.append(u)
        else:
            stack.pop()
    # a vertex's low point: the shallowest vertex one non-tree link from it or its subtree (in an
    # undirected search every non-tree link joins an ancestor to a descendant)
    reach = np.where(linked, depth[None, :], n)
    has_parent = parent >= 0
    reach[np.flatnonzero(has_parent), parent[has_parent]] = n  # the tree link to the parent does not count
    low = np.minimum(depth, reach.min(axis=1))
    cut = np.zeros(n, bool)
    for v in reversed(order[1:]):  # children before their parents
        p = parent[v]
        low[p] = min(low[p], low[v])
        if p != 0 and low[v] >= depth[p]:
            cut[p] = True
    cut[0] = int((parent == 0).sum()) > 1
    return np.flatnonzero(cut).tolist()
