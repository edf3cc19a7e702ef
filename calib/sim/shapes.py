"""Rigs of the shapes real rigs have, with known truth: rings of 3-15 m radius, domes, two tiers
at different heights and long hallways (cameras on two walls), 8-256 cameras.

What sets them apart from :func:`wandcal.calib.sim.simulate.simulate_capture`'s small ring, and
makes them look like real sessions (STYLE.md habit 13):

- the wand's volume grows with the rig, so a far camera sees the wand and the L-frame small;
- lenses with |k1| up to 0.1 of either sign;
- sparse visibility: each wand frame is seen by 2-4 of the cameras that could see it, the
  nearer ones more often (people, stands and focus hide it from the rest);
- gross outliers (one blob of a camera-frame moved 20-60 px) on a share of the kept camera-frames;
- the L-frame's blobs only where they fall inside a camera's image, so a camera that does not see
  it whole is placed from the wand, and a far one sees it as a small, possibly ambiguous, pose.
- a point is seen only inside the lens's one-to-one range (:func:`unfolded_radius`): beyond it
  the polynomial lens model folds points from far outside the field of view back into the image,
  blobs no real lens would make (a hallway's end camera "saw" the wand 30 m down the corridor).

Seeded: the same :class:`RigShape`, frames and seed give the same capture.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.geometry import camera_centers, depth, distort_points, project_normalized
from wandcal.calib.rig import Camera, Rig, StaticObservations, WandObservations
from wandcal.calib.sim.simulate import (
    BORDER_PX,
    IMAGE_SIZE,
    L_FRAME_M,
    STATIC_FRAMES_AVERAGED,
    SimulatedCapture,
    Truth,
    look_at,
    observe_wand,
    wand_path,
)

SHAPES = ("ring", "dome", "tiers", "hallway")
MIN_CAMERAS, MAX_CAMERAS = 8, 256
SIZE_RANGE_M = {"ring": (3.0, 15.0), "dome": (3.0, 15.0), "tiers": (3.0, 15.0), "hallway": (10.0, 120.0)}
MAX_K1 = 0.1  # the strongest radial distortion of the mocap lenses the simulator stands in for
HALLWAY_WIDTH_M = 4.0  # a corridor's width: the cameras on one wall look across it at the other
HALLWAY_CAMERAS_SHARE = 0.42  # the cameras stand along this share of the length each side of its middle
HALLWAY_WALK_PAST_M = 2.0  # the wand is walked this far past the last camera at each end: a camera looks
# across at a stretch of about 4 m of the far wall, so the end ones see the wand on both sides of their aim
HALLWAY_SWAY_M = 1.0  # the wand's midpoint sways this far along the corridor about the walk
HALLWAY_SWEEP_M = 1.0  # the wand is swept once per metre walked, as a person waves it while walking: with
# wand_path's sweeps (150 frames) the 3000 frames' two walks moved it in near-straight lines across
# several cameras' views, and two cameras sharing 10 such frames were placed 48 degrees off
VOLUME_SHARE = 0.4  # the wand's volume reaches this share of a round rig's radius from its centre
VOLUME_HEIGHT_M = (0.45, 1.55)  # the wand's midpoint between these heights: a person waving it
# wand_path's own volume: midpoints within +/-0.9 m of the centre in x and y (its normalised path
# is rescaled to the shape's volume)
PATH_HALF_M = 0.9
FOCAL_PX = (1000.0, 1150.0)  # as the default ring's lenses: about 60 degrees across the image
TIER_HEIGHTS_M = (1.2, 0.5)  # the lower tier at 1.2 m; the upper at half the radius above 2.5 m


def default_size(kind: str) -> float:
    """A shape's size when none is given: a 10 m radius, or a 40 m hallway."""
    return 40.0 if kind == "hallway" else 10.0


@dataclass(frozen=True)
class RigShape:
    """A rig's shape.

    Args:
        kind: one of ``SHAPES``.
        cameras: 8 to 256.
        size_m: the radius of a ring, dome or two tiers (3-15 m), or a hallway's length (10-120 m).
        max_k1: each lens's k1 is drawn from [-max_k1, max_k1], 0 to 0.1.
        views: (lo, hi) each wand frame is kept in lo to hi of the cameras that see it whole.
    """

    kind: str = "ring"
    cameras: int = 32
    size_m: float = 10.0
    max_k1: float = MAX_K1
    views: tuple[int, int] = (2, 4)

    def __post_init__(self) -> None:
        if self.kind not in SHAPES:
            raise ValueError(f"rig shape {self.kind!r}: choose one of {', '.join(SHAPES)}")
        if not MIN_CAMERAS <= self.cameras <= MAX_CAMERAS:
            raise ValueError(f"a {self.kind} of {self.cameras} cameras: give {MIN_CAMERAS} to {MAX_CAMERAS}")
        lo, hi = SIZE_RANGE_M[self.kind]
        if not lo <= self.size_m <= hi:
            raise ValueError(f"a {self.kind} of {self.size_m} m: give {lo} to {hi} m")
        if not 0.0 <= self.max_k1 <= MAX_K1:
            raise ValueError(f"max_k1 {self.max_k1}: give 0 to {MAX_K1}")
        if not 2 <= self.views[0] <= self.views[1]:
            raise ValueError(f"views {self.views}: give (lo, hi) with 2 <= lo <= hi")

    @property
    def half_volume(self) -> np.ndarray:
        """(2,) the wand midpoints' half extent in x and y, metres."""
        if self.kind == "hallway":
            return np.array([HALLWAY_CAMERAS_SHARE * self.size_m + HALLWAY_WALK_PAST_M, HALLWAY_WIDTH_M / 2 - 0.8])
        return np.full(2, VOLUME_SHARE * self.size_m)


def simulate_shape(shape: RigShape, frames: int = 3000, noise_px: float = 0.3, outliers: float = 0.02, seed: int = 0,
                   static: bool = True, wand_length: float = 0.5, occlusion: float = 0.03) -> SimulatedCapture:
    """Simulate a wand capture of a rig of ``shape``.

    Args:
        frames: wand frames (frame sets), before the sparse visibility thins each.
        noise_px: Gaussian blob-centre noise, pixels (std per axis).
        outliers: share of the kept camera-frames whose one blob is moved 20-60 px.
        static: an L-frame at the world origin (static blobs where they fall inside the image).
        seed: random seed.
        wand_length: metres.
        occlusion: probability that a marker is hidden from a camera in a kept frame.
    """
    rng = np.random.default_rng(seed)
    cams, R, t = shaped_cameras(shape, rng)
    wand = shaped_wand_path(shape, frames, wand_length, rng)
    keep = sparse_views(cams, R, t, wand, shape.views, rng)
    obs = _observe_kept(cams, R, t, wand, keep, noise_px, outliers, occlusion, rng)
    static_obs = None
    if static:
        static_obs = _observe_static_in_view(cams, R, t, noise_px / np.sqrt(STATIC_FRAMES_AVERAGED), rng)
    rig = Rig(cameras=tuple(cams), wand_length=wand_length, static_markers=L_FRAME_M.copy() if static else None)
    return SimulatedCapture(rig=rig, wand=obs, static=static_obs, truth=Truth(R=R, t=t, wand=wand))


def shaped_cameras(shape: RigShape, rng: np.random.Generator) -> tuple[list[Camera], np.ndarray, np.ndarray]:
    """The rig's cameras (intrinsics with k1 in +/-max_k1) and their world->camera poses R (N, 3, 3),
    t (N, 3), each aimed at a point of the wand's volume."""
    centres, targets = _PLACES[shape.kind](shape, rng)
    w, h = IMAGE_SIZE
    cams, Rs, ts = [], [], []
    for i, (centre, target) in enumerate(zip(centres, targets)):
        R, t = look_at(centre, target, roll=rng.uniform(-0.1, 0.1))
        f = rng.uniform(*FOCAL_PX)
        K = np.array([[f, 0, w / 2 + rng.uniform(-10, 10)], [0, f, h / 2 + rng.uniform(-10, 10)], [0, 0, 1]])
        k1 = rng.uniform(-shape.max_k1, shape.max_k1)
        dist = np.array([k1, -0.3 * k1 * rng.uniform(0, 1), 0.0, 0.0, 0.0])
        cams.append(Camera(id=f"cam{i + 1}", width=w, height=h, K=K, dist=dist))
        Rs.append(R)
        ts.append(t)
    return cams, np.array(Rs), np.array(ts)


def _aim(shape: RigShape, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) aim points spread over the inner half of the wand's volume."""
    half = np.r_[0.5 * shape.half_volume, 0.3]
    return np.array([0.0, 0.0, np.mean(VOLUME_HEIGHT_M)]) + rng.uniform(-1, 1, (n, 3)) * half


def _ring(shape: RigShape, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    n, r = shape.cameras, shape.size_m
    az = 2 * np.pi * (np.arange(n) + rng.uniform(-0.3, 0.3, n)) / n
    height = 2.3 + 0.1 * r + rng.uniform(0, 0.6, n)
    centres = np.stack([r * np.cos(az), r * np.sin(az), height], 1)
    return centres, _aim(shape, n, rng)


def _dome(shape: RigShape, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Cameras spread evenly over a hemisphere's band from 15 to 65 degrees of elevation
    (a Fibonacci lattice), the sphere's centre on the floor."""
    n, r = shape.cameras, shape.size_m
    lo, hi = np.sin(np.radians([15.0, 65.0]))
    el = np.arcsin(lo + (hi - lo) * (np.arange(n) + 0.5) / n)
    az = np.arange(n) * np.pi * (3 - np.sqrt(5)) + rng.uniform(-0.05, 0.05, n)
    centres = r * np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], 1)
    return centres, _aim(shape, n, rng)


def _tiers(shape: RigShape, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Half the cameras on a low ring at the volume's height, half on a high one above it
    (a stadium's lower and upper stands), their azimuths interleaved."""
    n, r = shape.cameras, shape.size_m
    upper = np.arange(n) % 2 == 1
    az = 2 * np.pi * (np.arange(n) + rng.uniform(-0.3, 0.3, n)) / n
    radius = np.where(upper, 1.1 * r, r)
    height = np.where(upper, 2.5 + TIER_HEIGHTS_M[1] * r, TIER_HEIGHTS_M[0]) + rng.uniform(0, 0.3, n)
    centres = np.stack([radius * np.cos(az), radius * np.sin(az), height], 1)
    return centres, _aim(shape, n, rng)


def _hallway(shape: RigShape, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Cameras on the two walls of a corridor along x, alternating walls, each looking across
    at the far half of the corridor a little ahead or behind."""
    n, length = shape.cameras, shape.size_m
    x = ((np.arange(n) + 0.5) / n - 0.5) * 2 * HALLWAY_CAMERAS_SHARE * length + rng.uniform(-0.2, 0.2, n)
    side = np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
    centres = np.stack([x, side * HALLWAY_WIDTH_M / 2, rng.uniform(2.4, 2.8, n)], 1)
    targets = np.stack([x + rng.uniform(-1.0, 1.0, n), -side * HALLWAY_WIDTH_M / 6, rng.uniform(0.8, 1.2, n)], 1)
    return centres, targets


_PLACES = {"ring": _ring, "dome": _dome, "tiers": _tiers, "hallway": _hallway}


def shaped_wand_path(shape: RigShape, frames: int, length: float, rng: np.random.Generator) -> np.ndarray:
    """(F, 2, 3) wand ends, metres: :func:`wandcal.calib.sim.simulate.wand_path`'s smooth path with
    its midpoints stretched over the shape's volume (a hallway's walked from end to end twice, past
    its last cameras), the wand's direction and length as they were."""
    sweep = 150.0  # wand_path's default
    if shape.kind == "hallway":  # the frames of a metre walked (the walk's 4 lengths of 2 reaches)
        sweep = HALLWAY_SWEEP_M * frames / (8 * shape.half_volume[0])
    ends = wand_path(frames, length, rng, sweep_frames=sweep)
    mid, half = ends.mean(axis=1), 0.5 * (ends[:, 1] - ends[:, 0])
    mid[:, :2] *= shape.half_volume / PATH_HALF_M
    if shape.kind == "hallway":
        s = np.arange(frames) / max(frames - 1, 1)
        walk = 2 / np.pi * np.arcsin(np.sin(2 * np.pi * 2 * s - np.pi / 2))  # a triangle wave, -1 to 1
        reach = shape.half_volume[0]
        mid[:, 0] = (reach - HALLWAY_SWAY_M) * walk + HALLWAY_SWAY_M * np.clip(mid[:, 0] / reach, -1, 1)
    return np.stack([mid - half, mid + half], axis=1)


def sparse_views(cams: list[Camera], R: np.ndarray, t: np.ndarray, wand: np.ndarray, views: tuple[int, int],
                 rng: np.random.Generator) -> np.ndarray:
    """(F, N) bool: of the cameras that see both wand ends of a frame inside their image, keep
    ``views`` (lo, hi) of them at random (as many as there are, when fewer), a camera drawn with a
    weight of 1 / distance^2 to the wand; none for a frame that fewer than two cameras see."""
    F, N = len(wand), len(cams)
    seen = np.ones((F, N), bool)
    for c, cam in enumerate(cams):
        seen[:, c] = in_view(cam, R[c], t[c], wand.reshape(-1, 3)).reshape(F, 2).all(1)
    distance = np.linalg.norm(camera_centers(R, t)[None] - wand.mean(axis=1)[:, None], axis=2)
    # the Gumbel top-k trick: the k largest of log(weight) + Gumbel noise are a weighted draw of k
    # without replacement
    key = np.where(seen, -2 * np.log(distance) + rng.gumbel(size=(F, N)), -np.inf)
    k = np.minimum(rng.integers(views[0], views[1] + 1, F), seen.sum(1))
    rank = np.argsort(np.argsort(-key, axis=1), axis=1)
    keep = (rank < k[:, None]) & seen
    keep[seen.sum(1) < 2] = False
    return keep


def unfolded_radius(camera: Camera) -> float:
    """The normalised radius (tan of the angle off the optical axis) up to which ``camera``'s radial
    model r (1 + k1 r^2 + k2 r^4 + k3 r^6) still grows with r, inf if it always does. Past it the
    model turns back and images points from outside the field of view inside it."""
    k1, k2 = camera.dist[0], camera.dist[1]
    k3 = camera.dist[4] if len(camera.dist) > 4 else 0.0
    # d/dr of the model, in s = r^2: 1 + 3 k1 s + 5 k2 s^2 + 7 k3 s^3
    roots = np.roots(np.trim_zeros([7 * k3, 5 * k2, 3 * k1, 1.0], "f"))
    s = roots[(np.abs(roots.imag) < 1e-12) & (roots.real > 0)].real
    return float(np.sqrt(s.min())) if len(s) else np.inf


def in_view(camera: Camera, R: np.ndarray, t: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(M,) bool: which world points (M, 3), metres, ``camera`` at pose R (3, 3), t (3,) images:
    in front of it, inside its lens's one-to-one range (:func:`unfolded_radius`) and inside the
    image, ``BORDER_PX`` from its edge."""
    xy = project_normalized(R, t, points)
    uv = distort_points(camera, xy)
    return ((depth(R, t, points) > 0.1) & (np.linalg.norm(xy, axis=1) < unfolded_radius(camera))
            & (uv[:, 0] > BORDER_PX) & (uv[:, 0] < camera.width - BORDER_PX)
            & (uv[:, 1] > BORDER_PX) & (uv[:, 1] < camera.height - BORDER_PX))


def _observe_kept(cams, R, t, wand, keep, noise_px, outliers, occlusion, rng) -> WandObservations:
    """:func:`wandcal.calib.sim.simulate.observe_wand` of each camera on its kept frames only."""
    frame, camera, uv = [], [], []
    for c in range(len(cams)):
        mine = np.flatnonzero(keep[:, c])
        if not len(mine):
            continue
        o = observe_wand(cams[c : c + 1], R[c : c + 1], t[c : c + 1], wand[mine], noise_px, outliers, occlusion, rng)
        frame.append(mine[o.frame])
        camera.append(np.full(len(o), c))
        uv.append(o.uv)
    if not frame:
        return WandObservations(np.zeros(0), np.zeros(0), np.zeros((0, 2)))
    order = np.argsort(np.concatenate(frame), kind="stable")
    return WandObservations(np.concatenate(frame)[order], np.concatenate(camera)[order], np.concatenate(uv)[order])


def _observe_static_in_view(cams, R, t, sigma_px, rng) -> StaticObservations:
    """:func:`wandcal.calib.sim.simulate.observe_static` of the L-frame (the same draws), keeping
    only the blobs of markers each camera has in view (:func:`in_view`)."""
    cameras, uvs = [], []
    for c, cam in enumerate(cams):
        uv = distort_points(cam, project_normalized(R[c], t[c], L_FRAME_M)) + rng.normal(0, sigma_px, (len(L_FRAME_M), 2))
        order = rng.permutation(len(uv))
        seen = in_view(cam, R[c], t[c], L_FRAME_M)[order]
        uvs.append(uv[order][seen])
        cameras += [c] * int(seen.sum())
    return StaticObservations(camera=np.array(cameras, dtype=np.int64), uv=np.concatenate(uvs).reshape(-1, 2))
