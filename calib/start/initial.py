"""First poses of every camera, before refinement.

With a static object, cameras whose PnP pose is unique start from it. The others (all of them
without a static object) are placed one at a time, best-linked first, as a spanning tree grows
over the camera graph (:mod:`wandcal.calib.start.chain`): a camera's links are the wand frames and single-point
tracks it shares with the cameras already placed. With no camera placed yet, the best-linked
pair whose wand frames can scale it starts: its essential matrix, scaled by the wand length
(easyWand and Argus start the same way). Where no pair shares the wand frames its scale needs, the
best-linked pair that can be placed starts at a unit baseline, the others follow with the scale
the points carry, and the wand's median length over every camera scales the whole rig at the end
(decision 0073: a sparse capture's wand frames are seen two cameras at a time). Each further camera is placed by whichever is better
constrained, counting two equations per resected point and one per epipolar correspondence:

- resection (PnP inside RANSAC, :mod:`wandcal.calib.start.resection`) against the wand ends and point tracks
  that the placed cameras triangulate, which ties it to all of them at once ("wand resection",
  or "point resection" when it sees no wand end); or
- chaining from one placed camera by their pair's essential matrix ("essential matrix"),
  composing the relative pose, with the pair's baseline from the wand length when the pair
  shares wand frames, or else from points the placed cameras have triangulated.

A camera that neither can place waits until others are placed; when none can be, the error
names it, the placed cameras it is linked to and how many more shared wand frames it needs.
The work is capped (subsamples of at most a few hundred frames per pair or camera) so the start
costs about the same at any capture length.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from wandcal.calib.errors import CalibrationError, Failure
from wandcal.calib.observations import PointTracks, WandPairs
from wandcal.calib.rig import Rig, camera_list
from wandcal.calib.start.chain import (
    MIN_PAIR_MATCHES,
    MIN_SCALE_FRAMES,
    PairPose,
    Views,
    camera_groups,
    camera_views,
    pair_pose,
    points_scale,
    wand_scale,
)
from wandcal.calib.start.labels import label_ends, wand_lengths
from wandcal.calib.start.resection import (
    MAX_RESECT_FRAMES,
    MAX_RESECT_TRACKS,
    MIN_RESECT_POINTS,
    UNPLACED,
    placed_points,
    resect_camera,
)
from wandcal.calib.start.static import StaticPose

WEAK_LINK = 40  # correspondences below which a chained camera's start is worth a note


class UnplacedCamera(CalibrationError):
    """The start placed some cameras and could not place ``camera`` (its index) from them: the
    best-linked cameras that agree were placed first, so it is the one that disagrees."""

    def __init__(self, message: str, camera: int) -> None:
        super().__init__(message)
        self.camera = camera


@dataclass(frozen=True, eq=False)
class Initial:
    """Starting poses R (N, 3, 3), t (N, 3) and how each camera was placed."""

    R: np.ndarray
    t: np.ndarray
    source: list[str]
    notes: list[str] = field(default_factory=list)


@dataclass(eq=False)
class _State:
    """The poses placed so far, R (N, 3, 3), t (N, 3); rank (N,) the order in which the cameras
    were placed (``UNPLACED`` for the others); whether the poses carry a scale yet; and the pair
    poses estimated so far."""

    rig: Rig
    pairs: WandPairs
    points: PointTracks | None
    views: Views
    R: np.ndarray
    t: np.ndarray
    rank: np.ndarray
    source: list[str]
    notes: list[str] = field(default_factory=list)
    scaled: bool = False
    provisional: bool = False  # a unit baseline stands for the wand's scale until every camera is placed
    edges: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.links = self.views.links()
        self.used = self.views.links(capped=True)
        # kept up to date as cameras are placed (:meth:`mark`), where each placement counted them
        # again over the whole (F, N) tables (0.75 ms a camera at 128 cameras x 3000 frames):
        # how many placed cameras see each wand frame (F,) and track (T,), and per camera (N,) how
        # many of its wand frames and tracks two or more placed cameras see
        self.seen = (self.views.wand >= 0, self.views.track >= 0)
        self.placed_views = tuple(seen[:, self.placed].sum(1) for seen in self.seen)
        self.triangulable = tuple((seen & (v >= 2)[:, None]).sum(0) for seen, v in zip(self.seen, self.placed_views))

    @property
    def placed(self) -> np.ndarray:
        return self.rank != UNPLACED

    def mark(self, c: int) -> None:
        self.rank[c] = self.placed.sum()
        for seen, views, tri in zip(self.seen, self.placed_views, self.triangulable):
            was = views >= 2
            np.add(views, seen[:, c], out=views)  # in place: the arrays are the state's
            np.add(tri, seen[(views >= 2) & ~was].sum(0), out=tri)  # the frames or tracks camera c made triangulable

    def focal(self, c: int) -> float:
        return float(self.rig.cameras[c].focal.mean())

    def edge(self, a: int, b: int) -> PairPose | Failure:
        """The pair's relative pose, estimated once."""
        if (a, b) not in self.edges:
            self.edges[(a, b)] = pair_pose(self.pairs, self.points, self.views, a, b, 0.5 * (self.focal(a) + self.focal(b)))
        return self.edges[(a, b)]

    def seen_points(self, c: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """What the placed cameras triangulate of what camera c sees (:func:`wandcal.calib.start.resection.placed_points`)."""
        length = None if self.provisional else self.rig.wand_length  # no metres to settle two-view frames by yet
        return placed_points(self.pairs, self.points, self.views, self.R, self.t, self.rank, c, length,
                             placed_views=self.placed_views)


def initial_poses(
    rig: Rig, pairs: WandPairs | None, static_poses: list | None = None, points: PointTracks | None = None
) -> Initial:
    """Place every camera (see module docstring).

    Without a wand (``rig.wand_length`` None, or no wand frames) the scale is arbitrary: the
    first pair placed from its essential matrix gets a baseline of 1, and a note says so.

    Args:
        rig: the rig.
        pairs: unlabeled two-blob camera-frames (may be empty, or None, for a capture with point
            tracks only).
        static_poses: output of :func:`wandcal.calib.start.static.solve_static`, or None.
        points: single-point tracks (:func:`wandcal.calib.observations.point_tracks`), or None.

    Raises:
        CalibrationError: a camera shares too few observations with the others to be placed; the
            message names it, the cameras it is linked to and how many more frames it needs.
    """
    n = len(rig.cameras)
    if pairs is None:
        pairs = WandPairs.empty()
    st = _State(
        rig=rig, pairs=pairs, points=points, views=camera_views(pairs, points, n),
        R=np.tile(np.eye(3), (n, 1, 1)), t=np.zeros((n, 3)), rank=np.full(n, UNPLACED), source=["" for _ in range(n)],
    )
    if static_poses is not None:
        for c, pose in enumerate(static_poses):
            if isinstance(pose, StaticPose) and pose.unique:
                st.R[c], st.t[c] = pose.R, pose.t
                st.mark(c)
                st.source[c] = "static PnP"
            # an ambiguous pose (the planar flip) is left to the wand or the points, which place the
            # camera below or refuse the capture, naming it: nothing is left for the user to do
    st.scaled = st.placed.sum() >= 2
    if st.placed.any():
        _refuse_split(st)
    if not st.placed.any():
        _start_pair(st)
    while not st.placed.all():
        _place_next(st)
    if st.provisional:
        _scale_by_the_wand(st)
    return Initial(R=st.R, t=st.t, source=st.source, notes=st.notes)


def shared_frames(pairs: WandPairs, n_cams: int) -> np.ndarray:
    """(N, N) number of frames in which both cameras see both wand ends."""
    seen = np.zeros((len(pairs.frames), n_cams), dtype=np.int64)
    seen[pairs.frame, pairs.camera] = 1
    # einsum, not seen.T @ seen: NumPy's integer matmul is a plain loop 5x slower (a fifth of the
    # guidance at 128 cameras x 3000 frames), and a float one wakes BLAS's threads, whose waiting
    # costs more CPU than the product
    return np.einsum("fa,fb->ab", seen, seen)


def _start_pair(st: _State) -> None:
    """Place the best-linked pair that can be placed: the first camera at the origin, the second
    from their essential matrix, scaled by the wand (baseline 1 without one). Where no pair shares
    the wand frames its scale needs but one can be placed (from point tracks, or points and the
    wand), it starts with a unit baseline that :func:`_scale_by_the_wand` turns into metres once
    every camera is placed: a sparse capture's wand frames are seen two cameras at a time, by
    different pairs (Brown's 40% subsamples: 0-2 fitting frames a pair, 131-144 shared tracks)."""
    rig, n = st.rig, st.views.n_cams
    links = st.links.copy()
    np.fill_diagonal(links, 0)
    wand = (st.views.wand >= 0).astype(np.int64)
    # with a wand, the pairs whose own wand frames give the scale come first
    scalable = (wand.T @ wand >= MIN_SCALE_FRAMES) & (rig.wand_length is not None)
    priority = links + (links.max() + 1) * scalable
    ia, ib = np.triu_indices(n, 1)
    reasons = []
    unscaled: PairPose | None = None  # the best-linked pair placed without its scale
    for k in np.argsort(-priority[ia, ib], kind="stable"):
        a, b = int(ia[k]), int(ib[k])
        if links[a, b] < MIN_PAIR_MATCHES:
            continue
        pose = st.edge(a, b)
        if isinstance(pose, Failure):
            reasons.append(f"{rig.cameras[a].id} and {rig.cameras[b].id}: {pose}")
            continue
        scale = _scale_of_start(st, pose)
        if isinstance(scale, Failure):
            reasons.append(f"{rig.cameras[a].id} and {rig.cameras[b].id}: {scale}")
            if unscaled is None or pose.inliers > unscaled.inliers:
                unscaled = pose
            continue
        _place_pair(st, pose, scale)
        return
    if unscaled is not None and rig.wand_length is not None:
        st.provisional = st.scaled = True
        _place_pair(st, unscaled, 1.0)
        return
    a, b = map(int, np.unravel_index(np.argmax(links), links.shape))
    raise CalibrationError(
        f"no two cameras can be placed from what they see together (best linked: {rig.cameras[a].id} and "
        f"{rig.cameras[b].id}, {_describe(st.views, a, b)}"
        + (f"; {'; '.join(reasons[:3])}" if reasons else f", {MIN_PAIR_MATCHES} correspondences needed")
        + "); wave the wand where several cameras see it at the same time"
    )


def _place_pair(st: _State, pose: PairPose, scale: float) -> None:
    st.mark(pose.a)
    st.mark(pose.b)
    st.R[pose.b], st.t[pose.b] = pose.R, scale * pose.u
    st.source[pose.a] = st.source[pose.b] = "essential matrix"


def _scale_by_the_wand(st: _State) -> None:
    """Every camera placed at a provisional scale: their wand frames (ends ordered with these poses,
    each end triangulated by every camera that saw it) give the scale, the wand's length over
    their median length. Raises when fewer than :data:`MIN_SCALE_FRAMES` frames triangulate."""
    length = st.rig.wand_length
    assert length is not None  # provisional only with a wand (_start_pair)
    labelled = label_ends(st.R, st.t, st.pairs, np.ones(st.views.n_cams, bool))[0]
    lengths = wand_lengths(st.R, st.t, labelled)
    lengths = lengths[np.isfinite(lengths) & (lengths > 0)]
    if len(lengths) < MIN_SCALE_FRAMES:
        raise CalibrationError(
            f"every camera was placed from what the cameras see together, but only {len(lengths)} wand frames are "
            f"seen by two or more cameras, {MIN_SCALE_FRAMES} needed for the scale; wave the wand where two or more "
            "cameras see it at the same time")
    st.t *= length / float(np.median(lengths))
    st.notes.append(f"no pair of cameras shared {MIN_SCALE_FRAMES} wand frames: the cameras were placed from their "
                    f"shared point tracks and wand frames, and scaled by the wand's median length in {len(lengths)} frames")


def _scale_of_start(st: _State, pose: PairPose) -> float | Failure:
    if st.rig.wand_length is not None and len(st.pairs):
        scale = wand_scale(st.pairs, st.views, pose, st.rig.wand_length)
        if scale:
            st.scaled = True
        return scale
    st.notes.append(
        f"no wand: the scale is arbitrary, fixed by a baseline of 1 between {st.rig.cameras[pose.a].id} and "
        f"{st.rig.cameras[pose.b].id}"
    )
    st.scaled = True
    return 1.0


def _place_next(st: _State) -> None:
    """Place the unplaced camera with the most constraints from the placed ones (a resected point
    gives two equations, an epipolar correspondence one); when it cannot be placed yet, the
    next one; raise when none can."""
    tri_w, tri_t = st.triangulable  # each camera's wand frames and tracks two placed cameras see
    points = np.minimum(2 * tri_w, 2 * MAX_RESECT_FRAMES)
    points += np.minimum(tri_t, MAX_RESECT_TRACKS)
    link = np.where(st.placed[:, None], st.used, 0).max(0)
    score = np.where(st.placed, -1, np.maximum(2 * points, link))
    failures = []
    for order in np.argsort(-score, kind="stable"):
        c = int(order)
        if st.placed[c]:
            break
        resect_first = points[c] >= MIN_RESECT_POINTS and 2 * points[c] >= link[c]
        steps = (_by_resection, _by_chain) if resect_first else (_by_chain, _by_resection)
        reasons = []
        for step in steps:
            done = step(st, c)
            if done:
                st.mark(c)
                return
            reasons.append(str(done))
        failures.append((c, reasons))
    raise UnplacedCamera(_cannot_place(st, failures[0][0], failures[0][1]), failures[0][0])


def _by_chain(st: _State, c: int) -> bool | Failure:
    """Chain camera c from its best-linked placed camera whose pair can be placed and scaled."""
    links = st.links[:, c]
    tried = []
    for order in np.argsort(-links, kind="stable"):
        a = int(order)
        if not st.placed[a] or links[a] < MIN_PAIR_MATCHES:
            continue
        pose = st.edge(a, c)
        scale = _chain_scale(st, pose) if pose else pose
        if not pose or not scale:  # scale is the pose's Failure when there is no pose
            tried.append(f"with {st.rig.cameras[a].id}: {scale}")
            continue
        st.R[c] = pose.R @ st.R[a]
        st.t[c] = pose.R @ st.t[a] + scale * pose.u
        st.source[c] = "essential matrix"
        if pose.inliers < WEAK_LINK:
            st.notes.append(
                f"{st.rig.cameras[c].id}: placed from only {pose.inliers} correspondences shared with "
                f"{st.rig.cameras[a].id}; check its residuals after refinement"
            )
        return True
    return Failure("; ".join(tried) if tried else f"no placed camera shares {MIN_PAIR_MATCHES} correspondences with it")


def _chain_scale(st: _State, pose: PairPose) -> float | Failure:
    """The baseline of a pair whose first camera is placed: from their own wand frames, else
    from points the placed cameras triangulated, else (nothing scaled yet) 1."""
    rig = st.rig
    # at a provisional scale a pair's own metres would not match the others': the points carry it
    by_wand = (wand_scale(st.pairs, st.views, pose, rig.wand_length) if rig.wand_length is not None and not st.provisional
               else Failure("no wand" if rig.wand_length is None else "the scale is provisional"))
    if by_wand:
        st.scaled = True
        return by_wand
    seen = st.seen_points(pose.b)
    by_points = points_scale(st.R[pose.a], st.t[pose.a], pose, *seen, st.focal(pose.b))
    if by_points:
        return by_points
    if not st.scaled and (rig.wand_length is None or not len(st.pairs)):
        return _scale_of_start(st, pose)
    return Failure(f"its scale: {by_wand}; {by_points}")


def _by_resection(st: _State, c: int) -> bool | Failure:
    """Resect camera c from the wand ends and point tracks the placed cameras triangulate."""
    ends, ends_xy, X, xy = st.seen_points(c)
    found = resect_camera(ends, ends_xy, X, xy, st.focal(c))
    if not found:
        return found
    st.R[c], st.t[c] = found
    st.source[c] = "wand resection" if len(ends) else "point resection"
    return True


def _refuse_split(st: _State) -> None:
    """Refuse a rig whose cameras form groups that share no wand frame or point track, even when
    the static object placed cameras of each: the groups' poses relative to each other would
    rest on the static object alone, and the refinement could neither check nor move them. The
    message names a camera of each group apart from the largest."""
    groups = camera_groups(st.links > 0)
    if len(groups) < 2:
        return
    ids = [c.id for c in st.rig.cameras]
    main = camera_list([ids[c] for c in groups[0]], len(ids))
    cam = ids[groups[1][0]]
    apart = "; ".join(camera_list([ids[c] for c in g], len(ids)) for g in groups[1:])
    raise CalibrationError(
        f"camera {cam!r} cannot be placed: no wand frame or point track ties it to the cameras {main} "
        f"(the camera groups apart from them: {apart}); the static object alone would place the groups, "
        f"and nothing would check their poses against each other; it needs at least {(MIN_PAIR_MATCHES + 1) // 2} "
        f"wand frames shared with one of {main}. Wave the wand where {cam} and the others see it at the same time"
    )


def _describe(views: Views, a: int, b: int) -> str:
    frames, tracks = views.shared(a, b)
    return f"{len(frames)} wand frames and {len(tracks)} point tracks"


def _cannot_place(st: _State, c: int, reasons: list[str]) -> str:
    """The message for a camera that cannot be placed: what links it has and what it needs (in
    points, for a capture without a wand: a point gives one match, a wand frame two)."""
    rig, views = st.rig, st.views
    cam = rig.cameras[c].id
    linked = [int(a) for a in np.flatnonzero(st.placed) if sum(map(len, views.shared(int(a), c)))]
    links = st.links[:, c]
    wandless = not len(st.pairs)
    seen, per, act = ("points", 1, "Show points") if wandless else ("wand frames", 2, "Wave the wand")
    if linked:
        best = max(linked, key=lambda a: links[a])
        short = max(MIN_PAIR_MATCHES - int(links[best]), 0)
        need = (
            f"it needs {(short + per - 1) // per} more {seen} shared with {rig.cameras[best].id}"
            if short else
            f"the frames it shares with {rig.cameras[best].id} do not fix its pose ({'; '.join(reasons)}); "
            f"it needs more {seen} seen by {cam} and {rig.cameras[best].id} together, "
            "a few of them also by a third camera"
        )
        with_whom = ", ".join(f"{rig.cameras[a].id} ({_describe(views, a, c)})" for a in linked)
    else:
        need = f"it needs at least {(MIN_PAIR_MATCHES + per - 1) // per} {seen} shared with one of them"
        with_whom = "none of them"
    placed = ", ".join(rig.cameras[a].id for a in np.flatnonzero(st.placed))
    return (
        f"camera {cam!r} cannot be placed: of the placed cameras ({placed}) it is linked to {with_whom}; {need}. "
        f"{act} where {cam} and the others see {'them' if wandless else 'it'} at the same time"
    )
