"""Each camera against every point the others triangulate without it: which camera is at fault
in a rig of few cameras, and how (its lens, or a knock partway through).

In a rig of three or four cameras a fault bends every pose, and each point is seen by two to four
cameras, so a camera's residual in the solve holds the others' errors too: the weakest camera
(the most outliers, the fewest views) takes the blame. Here each camera ``c`` is judged on its own
observations of every point the *other* cameras triangulate (wand ends and point tracks, two or
more other views), with its pose refitted to them (:func:`wandcal.calib.judge.faults.screen.resect`), so
what remains is c's own. Two patterns of what remains name a fault:

- **the lens** (:func:`wandcal.calib.judge.faults.screen._lens_fit`): a focal length, k1 or principal
  point that the pose cannot take up, and fy alone (the aspect ratio) where that is significant
  (decision 0058), named only where its coefficients stand out of their own scatter over blocks of
  the capture (:func:`blocks_p_value`: residuals run on along a track, decision 0069);
- **a knock**: the camera turned by a rotation ``w`` after frame k, ``r ~ J_rot w`` on its
  observations after k and 0 before, with ``J_rot`` its projection's derivative in its own rotation:
  least squares of the residual on those three columns beside the pose's six, at every candidate
  k, the best k kept. Only the observations with a time (the wand's, or the point tracks where
  there is no wand: a moving marker) take part; background points digitised once would put a
  step where there is none.

Where several cameras show a pattern, the one whose pattern is by far the strongest (its F
:data:`COMPARE_MARGIN` times any other camera's) is named: the others show the error it spread
through the points; a tie names nobody. docs/verdict.md gives the limits.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from wandcal.calib.geometry import rotvec_to_matrix
from wandcal.calib.judge.faults.f_distribution import f_survival
from wandcal.calib.judge.faults.own_errors import in_wand_time
from wandcal.calib.judge.faults.screen import POSE_STEP, Lens, _lens_fit, _pose_columns, _share, lens_columns, resect
from wandcal.calib.observations import PointTracks, WandPairs
from wandcal.calib.start.labels import flatten
from wandcal.calib.triangulate import triangulate_points

MAX_CAMERAS = 5  # "few": beyond this every point has views enough that the suspect screen works
MIN_VIEWS = 20  # observations of c with two other views before c is judged
# a lens pattern names a fault at this F statistic and share of the residual beyond the pose: on
# the clean real sessions (Brown 1, 2, Ushichka) the largest was F = 19 at 15%; a focal length 8%
# off or k1 left out gave F = 48-460 at 28-90%
LENS_F = 40.0
LENS_SHARE = 0.25
# ... and its coefficients stand out of their own scatter over blocks of the capture
# (:func:`blocks_p_value`) at this level, the pose step's (pose_steps.STEP_ALPHA): real residuals run
# on along a track, so the F's independent-rows null overstates it many times (MultiCamSelfCal's
# Basler_21275577, a real +1.3% focal pattern: F 43-59 on subsamples, at p 0.007-0.04 against its
# blocks; decision 0069). About a thousand camera tests in bench_real_subsamples: 0.1 false expected
LENS_ALPHA = 1e-4
# the lens pattern fits fy alone too: an aspect ratio off (fy 3% off on one camera of four) is
# half a focal error and half a stretch along y that the camera's pose cannot take up; fitted
# without it, the stretch spread through the points showed more strongly in another camera (F 97
# there against 23 on the camera at fault, MultiCamSelfCal), which was named instead
LENS_ASPECT = True
MESSAGE_ASPECT = 0.005  # an aspect error the message names: half a per cent of fy
# a knock: F of the three step columns at the best split, and their share: clean sessions stay
# under F = 15 (the split's choice among STEP_SPLITS is a search, so the limit is well above 25)
KNOCK_F = 40.0
KNOCK_SHARE = 0.25
STEP_SPLITS = 15  # candidate splits, evenly spaced in the timed observations
STEP_MARGIN = 0.15  # no split within this share of either end: a step needs observations on both sides
# the camera named must stand out: its pattern's F this many times the next camera's strongest. In
# three cameras a knock of one shows as a step in all (each is judged against points the knocked
# one helped triangulate): F 417, 362 and 266 on Ushichka with the third knocked, where the knocked
# camera of four stood out by 5-7 times (MultiCamSelfCal); such a tie names nobody
COMPARE_MARGIN = 1.5


@dataclass(frozen=True, eq=False)
class HeldOut:
    """Camera c's observations of points the others triangulated: X (K, 3) the points (world
    frame), xy (K, 2) observed, normalised; frame (K,) capture frame numbers; timed (K,) bool,
    the observations that have a time (see the module's docstring); picks: which of the wand's and
    the point tracks' observations these are (each group's rows of c with two other views, then the
    finite points among them), so that :func:`seen_again` reads c's observations again."""

    X: np.ndarray
    xy: np.ndarray
    frame: np.ndarray
    timed: np.ndarray
    picks: tuple | None = field(default=None, repr=False)


@dataclass(frozen=True)
class Knock:
    """A step in a camera's pose: after capture frame ``frame`` it turned by ``degrees``;
    explained: the share of its residual beyond the pose the step explains; f_stat its F."""

    frame: int
    degrees: float
    explained: float
    f_stat: float


@dataclass(frozen=True)
class CameraPatterns:
    """One camera's patterns against the others: lens, knock (None when too few observations);
    lens_p: the lens pattern's p-value against its own scatter over blocks of the capture
    (:func:`blocks_p_value`)."""

    camera: int
    observations: int
    lens: Lens | None
    knock: Knock | None
    lens_p: float = 0.0


def held_out_views(R: np.ndarray, t: np.ndarray, labelled: WandPairs, tracks: PointTracks | None, c: int) -> HeldOut:
    """Camera c's wand ends and point-track observations, each against its point triangulated by
    the other cameras alone (those with two other views). R, t: (N, 3, 3), (N, 3) poses. The
    wand's ends have a time, and the point tracks in the wand's time
    (:func:`wandcal.calib.judge.faults.own_errors.in_wand_time`: a multi-marker wand's interior markers,
    a moving marker; all of them without a wand), so that they enter the knock test."""
    Xs, xys, frames, timed, mines = [], [], [], [], []
    for point, camera, xy, n, frame, has_time in _groups(labelled, tracks):
        others = camera != c
        views = np.bincount(point[others], minlength=n)
        mine = (camera == c) & (views[point] >= 2)
        mines.append(mine)
        if not mine.any():
            continue
        X = triangulate_points(R, t, point[others], camera[others], xy[others], n)
        Xs.append(X[point[mine]])
        xys.append(xy[mine])
        frames.append(frame[mine])
        timed.append(np.broadcast_to(has_time, mine.shape)[mine])
    if not Xs:
        return HeldOut(np.zeros((0, 3)), np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros(0, bool), (tuple(mines), None))
    X = np.concatenate(Xs)
    ok = np.all(np.isfinite(X), axis=1)
    return HeldOut(X[ok], np.concatenate(xys)[ok], np.concatenate(frames)[ok], np.concatenate(timed)[ok],
                   (tuple(mines), ok))


def _groups(labelled: WandPairs, tracks: PointTracks | None) -> list[tuple]:
    """The observations :func:`held_out_views` reads, in its order: the wand's ends, then the point
    tracks, each as (point (M,), camera (M,), xy (M, 2), points, capture frame (M,), has a time
    (bool, or (M,) bool))."""
    groups = []
    if len(labelled):
        point, camera, xy = flatten(labelled)
        groups.append((point, camera, xy, 2 * len(labelled.frames), labelled.frames[point // 2], True))
    if tracks is not None and len(tracks):
        # a track has a time where it is in the wand's (every one without a wand), as own_errors times them
        track_timed = in_wand_time(tracks.frames, labelled.frames[labelled.frame] if len(labelled) else np.zeros(0))
        groups.append((tracks.track, tracks.camera, tracks.xy, tracks.n_tracks, tracks.frames[tracks.track],
                       track_timed[tracks.track]))
    return groups


def seen_again(held: HeldOut, labelled: WandPairs, tracks: PointTracks | None) -> HeldOut:
    """``held`` (:func:`held_out_views` of camera c) with c's observations read again from
    ``labelled`` and ``tracks``: the same observations of the same points, normalised otherwise (another
    camera's lens: :func:`wandcal.calib.judge.faults.swapped.screened_pairs`), and only camera c's
    changed. The points the other cameras triangulate do not read c's views, so they are held's as
    they are: what :func:`held_out_views` of these observations gives, without triangulating again."""
    if held.picks is None:
        raise ValueError("seen_again reads the rows held_out_views picked: give it held_out_views' answer")
    mines, ok = held.picks
    xys = [xy[mine] for (_, _, xy, *_), mine in zip(_groups(labelled, tracks), mines, strict=True) if mine.any()]
    xy = np.concatenate(xys)[ok] if xys else np.zeros((0, 2))
    return replace(held, xy=xy)


def _turn_columns(R: np.ndarray, t: np.ndarray, X: np.ndarray) -> np.ndarray:
    """(2K, 3) the projection's derivative in a turn of the camera about its own centre
    (``x_cam -> exp(w) x_cam``), at points X (K, 3); the pose columns' rotation turns it about the
    world's origin, which moves its centre too."""
    Xc = X @ R.T + t
    base = Xc[:, :2] / Xc[:, 2:]
    cols = []
    for j in range(3):
        w = np.zeros(3)
        w[j] = POSE_STEP
        turned = Xc @ rotvec_to_matrix(w).T
        cols.append(((turned[:, :2] / turned[:, 2:] - base) / POSE_STEP).ravel())
    return np.stack(cols, axis=1)


def _knock(y: np.ndarray, pose: np.ndarray, turn: np.ndarray, frame: np.ndarray, timed: np.ndarray) -> Knock | None:
    """The best step of the turn columns (2K, 3) in residual y (2K,) beside the pose columns
    (2K, 6), over the timed observations' frames (K,)."""
    times = np.sort(frame[timed])
    if len(times) < MIN_VIEWS:
        return None
    lo, hi = int(STEP_MARGIN * len(times)), int((1 - STEP_MARGIN) * len(times))
    best = None
    for k in np.unique(times[np.linspace(lo, hi, STEP_SPLITS).astype(int)]):
        after = np.repeat(timed & (frame > k), 2)
        if after.sum() < MIN_VIEWS or (~after).sum() < MIN_VIEWS:
            continue
        share, coef, f_stat = _share(y, pose, turn * after[:, None])
        if best is None or f_stat > best.f_stat:
            best = Knock(int(k), float(np.degrees(np.linalg.norm(coef))), float(share), float(f_stat))
    return best


def camera_patterns(R: np.ndarray, t: np.ndarray, labelled: WandPairs, tracks: PointTracks | None,
                    c: int, held: HeldOut | None = None) -> CameraPatterns:
    """Camera c's lens and knock patterns against the points the others triangulate, its pose
    refitted. held: :func:`held_out_views` of these R, t, observations and c, where already made."""
    held = held_out_views(R, t, labelled, tracks, c) if held is None else held
    if len(held.X) < MIN_VIEWS:
        return CameraPatterns(c, len(held.X), None, None)
    Rc, tc, r, keep = resect(R[c], t[c], held.X, held.xy)
    if keep.sum() < MIN_VIEWS:
        return CameraPatterns(c, int(keep.sum()), None, None)
    pose = _pose_columns(Rc, tc, held.X[keep])
    y = r[keep].ravel()
    lens = _lens_fit(y, pose, held.xy[keep], aspect=LENS_ASPECT)
    blocks = capture_blocks(held.frame[keep], held.timed[keep])
    return CameraPatterns(c, int(keep.sum()), lens,
                          _knock(y, pose, _turn_columns(Rc, tc, held.X[keep]), held.frame[keep], held.timed[keep]),
                          blocks_p_value(y, pose, lens_columns(held.xy[keep], aspect=lens.aspect_error != 0.0), blocks))


def capture_blocks(frame: np.ndarray, timed: np.ndarray) -> np.ndarray:
    """(K,) each observation's block: the timed observations in capture order, then the others
    (background points, in their order), cut into about sqrt(K) blocks of consecutive ones (as
    :func:`wandcal.calib.judge.faults.pose_steps._inflation`'s batch means): a block holds a stretch
    of a track, whose residuals run on from one frame to the next."""
    K = len(frame)
    order = np.lexsort((np.arange(K), frame, ~timed))
    n_blocks = max(int(np.sqrt(K)), 2)
    block = np.empty(K, np.int64)
    block[order] = np.arange(K) * n_blocks // K
    return block


def blocks_p_value(y: np.ndarray, base: np.ndarray, extra: np.ndarray, block: np.ndarray) -> float:
    """The p-value of the columns ``extra`` (2K, q) beside ``base`` (2K, b) in y (2K,), their
    coefficients tested against their own scatter over the capture's blocks ``block`` (K,; each
    observation's two rows together): the delete-a-block jackknife's covariance of the q
    coefficients, V = (G - 1) / G sum (c_g - mean)(c_g - mean)^T over the G blocks each left out,
    and Hotelling's T^2 = c^T V^-1 c, taken as (G - q) / (q (G - 1)) T^2 ~ F(q, G - q).

    Unlike :func:`wandcal.calib.judge.faults.screen._share`'s F, which takes rows as independent,
    this holds its level where residuals run on along a track (decision 0069). 1 where there are
    fewer than q + 2 blocks (too few to say). From each block's normal equations: G small solves."""
    both = np.concatenate([base, extra], axis=1)
    scale = np.linalg.norm(both, axis=0)
    scale[scale == 0] = 1.0
    A = both / scale
    k, q = base.shape[1], extra.shape[1]
    n_blocks = int(block.max()) + 1 if len(block) else 0
    if n_blocks < q + 2:
        return 1.0
    rows = np.repeat(block, 2)
    order = np.argsort(rows, kind="stable")
    starts = np.searchsorted(rows[order], np.arange(n_blocks + 1))
    G = np.empty((n_blocks, A.shape[1], A.shape[1]))
    b = np.empty((n_blocks, A.shape[1]))
    for g in range(n_blocks):
        Ag, yg = A[order[starts[g]:starts[g + 1]]], y[order[starts[g]:starts[g + 1]]]
        G[g], b[g] = Ag.T @ Ag, Ag.T @ yg
    G_all, b_all = G.sum(axis=0), b.sum(axis=0)
    coef = np.linalg.lstsq(G_all, b_all, rcond=None)[0][k:]
    left = np.array([np.linalg.lstsq(G_all - G[g], b_all - b[g], rcond=None)[0][k:] for g in range(n_blocks)])
    d = left - left.mean(axis=0)
    V = (n_blocks - 1) / n_blocks * d.T @ d
    t2 = float(coef @ np.linalg.lstsq(V, coef, rcond=None)[0])
    return f_survival(q, n_blocks - q, t2 * (n_blocks - q) / (q * (n_blocks - 1)))


def _lens_found(p: CameraPatterns) -> float:
    """The lens pattern's share where it names a fault, else 0: its F at least :data:`LENS_F`, its
    share at least :data:`LENS_SHARE`, and its coefficients beyond their own scatter over the
    capture's blocks (``p.lens_p`` under :data:`LENS_ALPHA`)."""
    lens = p.lens
    return (lens.explained if lens is not None and lens.f_stat >= LENS_F and lens.explained >= LENS_SHARE
            and p.lens_p < LENS_ALPHA else 0.0)


def _knock_found(p: CameraPatterns) -> float:
    knock = p.knock
    return knock.explained if knock is not None and knock.f_stat >= KNOCK_F and knock.explained >= KNOCK_SHARE else 0.0


def _corrected(xy: np.ndarray, lens: Lens) -> np.ndarray:
    """Observations xy (K, 2), normalised, as the camera's lens would give them with its fitted
    error ``lens`` taken out (``r = projected - observed ~ a x + dk1 |x|^2 x + p``, so the observed
    point moves by that)."""
    radius2 = np.sum(xy**2, axis=-1, keepdims=True)
    return (xy + lens.focal_error * xy + lens.k1_error * radius2 * xy + np.asarray(lens.principal_error)
            + lens.aspect_error * xy * [0.0, 1.0])


def _with_lens_taken_out(R: np.ndarray, t: np.ndarray, labelled: WandPairs, tracks: PointTracks | None, c: int,
                         lens: Lens):
    """(R, t, labelled, tracks) with camera c's observations corrected by ``lens`` and its pose
    refitted to them against the points the others triangulate."""
    xy = labelled.xy.copy()
    mine = labelled.camera == c
    xy[mine] = _corrected(xy[mine], lens)
    labelled = WandPairs(labelled.frame, labelled.camera, xy, labelled.uv, labelled.frames, labelled.dropped)
    if tracks is not None and len(tracks):
        txy = tracks.xy.copy()
        txy[tracks.camera == c] = _corrected(txy[tracks.camera == c], lens)
        tracks = replace(tracks, xy=txy)
    held = held_out_views(R, t, labelled, tracks, c)
    R, t = R.copy(), t.copy()
    if len(held.X) >= MIN_VIEWS:
        R[c], t[c], _, _ = resect(R[c], t[c], held.X, held.xy)
    return R, t, labelled, tracks


def by_correction(R: np.ndarray, t: np.ndarray, labelled: WandPairs, tracks: PointTracks | None,
                  patterns: list[CameraPatterns], candidates: list[int]) -> int | None:
    """Which of the ``candidates`` (cameras whose lens pattern names a fault, none by far the
    strongest) is at fault, by comparison: each one's fitted lens error taken out of its
    observations in turn, and the other cameras' lens patterns judged again. Taking out the
    culprit's error leaves the others none; taking out an innocent camera's (which only fitted the
    culprit's error spread through the points) leaves the culprit's. The candidate after whose
    correction the strongest other pattern is below :data:`LENS_F` and :data:`COMPARE_MARGIN` times
    weaker than after any other candidate's is named; else None (a tie names nobody). In three
    cameras this tells a focal length 8% off from its spread (F 4 left against 13 and 56 on the
    easyWand C++ sample), not a k1 left out (10 against 8)."""
    left = {}
    for c in candidates:
        lens = patterns[c].lens
        if lens is None:
            continue
        R2, t2, lab2, tr2 = _with_lens_taken_out(R, t, labelled, tracks, c, lens)
        others = [camera_patterns(R2, t2, lab2, tr2, d) for d in range(len(R)) if d != c]
        left[c] = max((p.lens.f_stat for p in others if p.lens is not None), default=0.0)
    if len(left) < 2:
        return None
    order = sorted(left, key=lambda c: left[c])
    first, second = order[0], order[1]
    if left[first] < LENS_F and COMPARE_MARGIN * left[first] <= left[second]:
        return first
    return None


def leave_one_out_faults(ids: list[str], R: np.ndarray, t: np.ndarray, labelled: WandPairs,
                         tracks: PointTracks | None, at_fault: tuple[int, ...] = (),
                         held: list[HeldOut] | None = None) -> list[dict]:
    """The camera at fault in a rig of at most :data:`MAX_CAMERAS` cameras, by comparison of every
    camera's patterns against the others (``{"kind", "camera", "message", "evidence"}``; at most
    one: the others' patterns are its error spread through the points). Empty when no camera's
    pattern names a fault, or the rig is larger (the suspect screen judges it). ``at_fault``: cameras
    already named (a camera out of time, brought in time): left out of the comparison, their own
    error is no evidence against another camera. held: every camera's :func:`held_out_views` of
    these R, t and observations, where already made (the swap screen's: one triangulation each)."""
    if not 3 <= len(ids) <= MAX_CAMERAS:
        return []
    patterns = [camera_patterns(R, t, labelled, tracks, c, None if held is None else held[c]) for c in range(len(ids))]
    strongest = [0.0 if c in at_fault else max(p.lens.f_stat if p.lens else 0.0, p.knock.f_stat if p.knock else 0.0)
                 for c, p in enumerate(patterns)]
    found = [p for p in patterns if p.camera not in at_fault and max(_lens_found(p), _knock_found(p)) > 0]
    if not found:
        return []
    best = max(found, key=lambda p: strongest[p.camera])
    runner_up = max((f for c, f in enumerate(strongest) if c != best.camera), default=0.0)
    if strongest[best.camera] < COMPARE_MARGIN * runner_up:
        compared = by_correction(R, t, labelled, tracks, patterns, [p.camera for p in found if _lens_found(p)])
        if compared is None:
            return []
        best = patterns[compared]
    cam = ids[best.camera]
    if _knock_found(best) >= _lens_found(best):
        # a camera moved: named by wandcal.calib.judge.faults.own_errors (every view, the split search's
        # multiple testing, and only where leaving the camera out explains the others' steps)
        return []
    lens = best.lens
    assert lens is not None  # best was found, by its lens here (_lens_found > _knock_found >= 0)
    radial = abs(lens.k1_error) / 4 > abs(lens.focal_error)
    stretched = abs(lens.aspect_error) >= MESSAGE_ASPECT and abs(lens.aspect_error) > max(abs(lens.focal_error),
                                                                                         abs(lens.k1_error) / 4)
    shape = "stretched along y" if stretched else "radial" if radial else "scaled"
    aspect = f", fy {100 * lens.aspect_error:+.1f}% beyond that" if abs(lens.aspect_error) >= MESSAGE_ASPECT else ""
    check = "fy (its aspect ratio) and focal length" if stretched else "focal length and distortion"
    return [{"kind": "intrinsics", "camera": cam, "evidence": {
        "intrinsics": {"focal_error": round(lens.focal_error, 5), "k1_error": round(lens.k1_error, 5),
                       "aspect_error": round(lens.aspect_error, 5),
                       "explained_share": round(lens.explained, 3), "f_stat": round(lens.f_stat, 1)}},
        "message": f"{cam}'s intrinsics do not fit its images against the points the other cameras see: its residuals "
                   f"are {shape} about the image centre (focal length "
                   f"{100 * lens.focal_error:+.1f}% in rig.json against the data, k1 {lens.k1_error:+.3f}"
                   f"{aspect}); check its {check}, or run with --refine-intrinsics focal,k1"}]
