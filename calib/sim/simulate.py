"""Seeded synthetic rigs with known truth: the workhorse of tests, benchmarks and the demo.

The rig follows the seed paper's assumptions: cameras on a ring above the volume, an L-frame on
the floor at the world origin (z up), and a smooth wand path that starts low.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.geometry import camera_centers, depth, distort_points, project_normalized
from wandcal.calib.rig import Camera, Rig, StaticObservations, WandObservations

# An L-frame like the common commercial ones: three collinear markers with unequal spacing on
# the long arm (x) and one on the short arm (y), all on the floor.
L_FRAME_M = np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 0.35, 0.0]])
IMAGE_SIZE = (1280, 1024)
STATIC_FRAMES_AVERAGED = 100  # static blobs are averaged over a 1 s recording at 100 fps
BORDER_PX = 4  # blobs closer than this to the image edge are cut off by the detector


@dataclass(frozen=True, eq=False)
class Truth:
    """Ground truth of a simulated capture.

    R: (N, 3, 3), t: (N, 3) world->camera poses; wand: (F, 2, 3) marker positions, metres;
    cameras: the true intrinsics where rig.json gives them off (``simulate --intrinsics-error``,
    :mod:`wandcal.calib.sim.intrinsics`), else None (rig.json's are the truth).
    """

    R: np.ndarray
    t: np.ndarray
    wand: np.ndarray
    cameras: tuple[Camera, ...] | None = None

    @property
    def centers(self) -> np.ndarray:
        return camera_centers(self.R, self.t)

    def to_json(self, rig: Rig) -> dict:
        return {
            "format": "wandcal-truth/1",
            "cameras": [
                {"id": cam.id, "R": self.R[i].tolist(), "t": self.t[i].tolist(), "center": self.centers[i].tolist()}
                | ({} if self.cameras is None else {"K": self.cameras[i].K.tolist(), "dist": self.cameras[i].dist.tolist()})
                for i, cam in enumerate(rig.cameras)
            ],
            "wand_points_m": self.wand.tolist(),
        }


@dataclass(frozen=True, eq=False)
class SimulatedCapture:
    rig: Rig
    wand: WandObservations
    static: StaticObservations | None
    truth: Truth


def look_at(center: np.ndarray, target: np.ndarray, roll: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """World->camera pose of a camera at ``center`` (3,) looking at ``target`` (3,), world z up.

    Returns R (3, 3) with image y pointing down in the world, and t (3,).
    """
    z = target - center
    z = z / np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c, s = np.cos(roll), np.sin(roll)
    R = np.array([c * x + s * y, -s * x + c * y, z])
    return R, -R @ center


def ring_cameras(n: int, rng: np.random.Generator, radius: float = 3.2) -> tuple[list[Camera], np.ndarray, np.ndarray]:
    """n cameras on a ring above the volume, each aimed near its centre."""
    cams, Rs, ts = [], [], []
    w, h = IMAGE_SIZE
    for i in range(n):
        az = 2 * np.pi * i / n + rng.uniform(-0.15, 0.15)
        center = np.array([radius * np.cos(az), radius * np.sin(az), rng.uniform(2.3, 2.9)])
        target = np.array([0.0, 0.0, 0.8]) + rng.uniform(-0.25, 0.25, 3)
        R, t = look_at(center, target, roll=rng.uniform(-0.1, 0.1))
        f = rng.uniform(1000, 1150)
        K = np.array([[f, 0, w / 2 + rng.uniform(-10, 10)], [0, f, h / 2 + rng.uniform(-10, 10)], [0, 0, 1]])
        dist = np.array([rng.uniform(-0.15, -0.05), rng.uniform(0.0, 0.08), 0.0, 0.0, 0.0])
        cams.append(Camera(id=f"cam{i + 1}", width=w, height=h, K=K, dist=dist))
        Rs.append(R)
        ts.append(t)
    return cams, np.array(Rs), np.array(ts)


def wand_path(
    frames: int, length: float, rng: np.random.Generator, times: np.ndarray | None = None, sweep_frames: float = 150.0
) -> np.ndarray:
    """A smooth wand path through a 2 x 2 x 1.6 m volume that starts low.

    Args:
        times: (K, T) or (T,) instants to sample, in frames (fractions and instants outside
            [0, frames) allowed: the path is a smooth function of time); default every frame.
        sweep_frames: about one sweep this many frames long (150: 1-4 m/s at 100 fps, median 2.3).

    Returns (F, 2, 3) marker positions, metres, or (K, T, 2, 3) with ``times`` (K, T).
    """
    grid = np.arange(frames, dtype=float) if times is None else np.asarray(times, dtype=float)
    s = grid.reshape(-1)[:, None] / max(frames - 1, 1)
    k = np.arange(1, 4)[None, :]
    cycles = max(2.0, frames / sweep_frames)

    def smooth(scale: float) -> np.ndarray:
        amp = rng.normal(0, 1, (3, 3)) / k.T
        phase = rng.uniform(0, 2 * np.pi, (3, 3))
        out = np.stack([(amp[d] * np.sin(2 * np.pi * cycles * k * s / 2 + phase[d])).sum(1) for d in range(3)], 1)
        # normalised by the path's own extreme over the recording, whatever instants are sampled
        full = np.linspace(0.0, 1.0, frames)[:, None]
        peak = np.stack([(amp[d] * np.sin(2 * np.pi * cycles * k * full / 2 + phase[d])).sum(1) for d in range(3)], 1)
        return scale * out / np.abs(peak).max(0)

    mid = smooth(1.0) * [0.9, 0.9, 0.55] + [0.0, 0.0, 1.0]
    # start low: the first part of the path sweeps up from about 0.4 m, as in the seed paper
    ramp = np.clip(4 * s, 0, 1)
    mid[:, 2:] = ramp * mid[:, 2:] + (1 - ramp) * 0.45
    direction = smooth(1.0) + rng.normal(0, 0.3, 3)
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    out = np.stack([mid - direction * length / 2, mid + direction * length / 2], axis=1)
    return out.reshape(*grid.shape, 2, 3)


ROLL_STREAM = 23  # the random stream of a planar wand's roll (issue 23), apart from the capture's own
ROLL_PERIODS = (173.0, 61.0)  # frames: a slow turn and a quicker wobble of the wand's plane


def wand_roll(rng: np.random.Generator):
    """A planar wand's roll angle (radians) about its axis as a function of the instant (frames):
    a random start, a full slow turn and a wobble of about a radian, so the plane is seen from
    every side and, now and then, edge on."""
    phase = rng.uniform(0, 2 * np.pi, 3)
    amplitude = rng.uniform(0.6, 1.2)

    def roll(tau: np.ndarray) -> np.ndarray:
        return (phase[0] + 2 * np.pi * tau / ROLL_PERIODS[0] + amplitude * np.sin(2 * np.pi * tau / ROLL_PERIODS[1]
                                                                                   + phase[1]))
    return roll


def camera_times(frames: int, offsets: np.ndarray, drift_ppm: np.ndarray | None = None) -> np.ndarray:
    """(N, F) the instant, in frames of the reference clock, at which each camera exposed its
    frame k: ``k * (1 + drift_ppm 1e-6) + offset`` (docs/sync.md's model).

    Args:
        offsets: (N,) frames, any sign, fractions allowed; drift_ppm: (N,) rate differences, ppm.
    """
    k = np.arange(frames, dtype=float)[None, :]
    drift = np.zeros(len(offsets)) if drift_ppm is None else np.asarray(drift_ppm, dtype=float)
    return k * (1 + 1e-6 * drift[:, None]) + np.asarray(offsets, dtype=float)[:, None]


def observe_wand(cams, R, t, wand, noise_px, outliers, occlusion, rng) -> WandObservations:
    """Blobs of wand markers (F, K, 3), or (N, F, K, 3) each camera's own instants, in every camera
    (K = 2: the ends): noise, gross outliers (one blob of a camera-frame moved 20-60 px),
    occlusion, the image border, and a random blob order."""
    frames, k = wand.shape[-3], wand.shape[-2]
    rows_f, rows_c, rows_uv = [], [], []
    for c, cam in enumerate(cams):
        pts = (wand[c] if wand.ndim == 4 else wand).reshape(-1, 3)  # (N, F, 2, 3): each camera's own instants
        z = depth(R[c], t[c], pts)
        uv = distort_points(cam, project_normalized(R[c], t[c], pts)) + rng.normal(0, noise_px, (len(pts), 2))
        inside = (
            (z > 0.1)
            & (uv[:, 0] > BORDER_PX) & (uv[:, 0] < cam.width - BORDER_PX)
            & (uv[:, 1] > BORDER_PX) & (uv[:, 1] < cam.height - BORDER_PX)
            & (rng.random(len(pts)) > occlusion)
        )
        uv = uv.reshape(frames, k, 2)
        inside = inside.reshape(frames, k)
        gross = (rng.random(frames) < outliers) & inside.all(1)
        if gross.any():
            which = rng.integers(0, k, gross.sum())
            ang = rng.uniform(0, 2 * np.pi, gross.sum())
            mag = rng.uniform(20, 60, gross.sum())
            uv[np.flatnonzero(gross), which] += np.stack([np.cos(ang), np.sin(ang)], 1) * mag[:, None]
        for f in range(frames):
            ends = np.flatnonzero(inside[f])
            rng.shuffle(ends)
            for e in ends:
                rows_f.append(f)
                rows_c.append(c)
                rows_uv.append(uv[f, e])
    return WandObservations(frame=np.array(rows_f, dtype=np.int64), camera=np.array(rows_c, dtype=np.int64), uv=np.array(rows_uv).reshape(-1, 2))


def observe_static(cams, R, t, markers, sigma_px, rng) -> StaticObservations:
    """Unlabeled blobs of the static markers (M, 3) in every camera, in random order."""
    sc, suv = [], []
    for c, cam in enumerate(cams):
        uv = distort_points(cam, project_normalized(R[c], t[c], markers)) + rng.normal(0, sigma_px, (len(markers), 2))
        suv.append(uv[rng.permutation(len(uv))])
        sc += [c] * len(uv)
    return StaticObservations(camera=np.array(sc), uv=np.concatenate(suv))


def place_markers(ends: np.ndarray, offsets_2d: np.ndarray, phi: np.ndarray, length: float) -> np.ndarray:
    """(..., K, 3) every marker of a wand of ``length`` metres whose end markers are ``ends``
    (..., 2, 3), metres, from its layout's (along, across) offsets (K, 2)
    (wandcal.calib.wandlayout.plane_offsets), the plane rolled by ``phi`` (...,) radians about
    the axis (a collinear wand's roll is moot)."""
    d = (ends[..., 1, :] - ends[..., 0, :]) / length
    helper = np.where(np.abs(d[..., :1]) < 0.9, np.array([1.0, 0, 0]), np.array([0, 1.0, 0]))
    u1 = np.cross(d, helper)
    u1 /= np.linalg.norm(u1, axis=-1, keepdims=True)
    phi = np.asarray(phi)[..., None]
    e = np.cos(phi) * u1 + np.sin(phi) * np.cross(d, u1)
    return ends.mean(axis=-2)[..., None, :] + offsets_2d[:, :1] * d[..., None, :] + offsets_2d[:, 1:] * e[..., None, :]


def simulate_capture(
    cameras: int = 8,
    frames: int = 1500,
    noise_px: float = 0.3,
    outliers: float = 0.0,
    static: bool = True,
    seed: int = 0,
    wand_length: float = 0.5,
    occlusion: float = 0.03,
    wand_markers: np.ndarray | None = None,
    offsets: np.ndarray | None = None,
    drift_ppm: np.ndarray | None = None,
    sweep_frames: float = 150.0,
) -> SimulatedCapture:
    """Simulate a wand capture.

    Args:
        cameras: number of cameras on the ring.
        frames: number of synchronised frame sets.
        noise_px: Gaussian blob-centre noise, pixels (std per axis).
        outliers: fraction of camera-frames whose one blob is moved 20-60 px (a gross outlier).
        static: include an L-frame (``Rig.static_markers`` and static blobs).
        seed: random seed.
        wand_length: metres.
        occlusion: probability that a marker is hidden from a camera in a frame.
        wand_markers: (K, 3) a collinear or planar multi-marker wand's layout (metres; its span
            replaces ``wand_length``; a planar wand rolls about its axis, :func:`wand_roll`), or
            None for two markers. ``truth.wand`` is then (F, K, 3), the
            markers in the layout's order.
        offsets: (N,) each camera's time offset, frames: its frame k shows the wand at the
            reference instant k + offset (``truth.wand`` is at the reference instants); None: all
            cameras synchronised.
        drift_ppm: (N,) each camera's rate difference, ppm (:func:`camera_times`); with offsets.
        sweep_frames: the wand's sweep length in frames (:func:`wand_path`; larger is slower).
    """
    rng = np.random.default_rng(seed)
    cams, R, t = ring_cameras(cameras, rng)
    if wand_markers is not None:
        from wandcal.calib.wandlayout import check_layout, plane_offsets, span

        wand_markers = check_layout(wand_markers)
        wand_length = span(wand_markers)
    if offsets is None and drift_ppm is None:
        wand = wand_path(frames, wand_length, rng, sweep_frames=sweep_frames)
        seen = wand
    else:
        times = camera_times(frames, np.zeros(cameras) if offsets is None else offsets, drift_ppm)
        both = wand_path(frames, wand_length, rng, np.concatenate([np.arange(frames)[None], times]), sweep_frames)
        wand, seen = both[0], both[1:]
    if wand_markers is not None:
        offsets_2d = plane_offsets(wand_markers)
        # a planar wand's roll about its axis, a smooth function of the instant (its own stream, so
        # that collinear captures keep theirs)
        roll = wand_roll(np.random.default_rng(None if seed is None else [seed, ROLL_STREAM]))
        instants = np.arange(frames, dtype=float) if offsets is None and drift_ppm is None else np.concatenate(
            [np.arange(frames, dtype=float)[None], times])

        def markers(ends: np.ndarray, tau: np.ndarray) -> np.ndarray:  # (..., 2, 3) ends -> (..., K, 3) every marker
            return place_markers(ends, offsets_2d, roll(tau), wand_length)

        if offsets is None and drift_ppm is None:
            wand = seen = markers(wand, instants)
        else:
            both = markers(np.concatenate([wand[None], seen]), instants)
            wand, seen = both[0], both[1:]
    obs = observe_wand(cams, R, t, seen, noise_px, outliers, occlusion, rng)
    static_obs = observe_static(cams, R, t, L_FRAME_M, noise_px / np.sqrt(STATIC_FRAMES_AVERAGED), rng) if static else None
    rig = Rig(cameras=tuple(cams), wand_length=wand_length, static_markers=L_FRAME_M.copy() if static else None,
              wand_markers=wand_markers)
    return SimulatedCapture(rig=rig, wand=obs, static=static_obs, truth=Truth(R=R, t=t, wand=wand))


# The seed paper's simulation (Masoudas/CameraCalibration, Newton/Main_Program.m and StreoSim.m):
# 4 cameras of 1200 x 900 px with f = 984 px, a 300 mm wand at random positions and orientations
# seen by at least two cameras, and the static object below (mm in the original), whose blobs
# carry the same noise as the wand's (no averaging).
PAPER_IMAGE = (1200, 900)
PAPER_FOCAL_PX = 984.0
PAPER_WAND_M = 0.3
PAPER_STATIC_M = np.array([[0.0, 0.55, 0.0], [0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.75, 0.0, 0.0]])


def simulate_paper_protocol(noise_px: float, seed: int, frames: int = 300, test_frames: int = 100):
    """A capture in the seed paper's simulation protocol, and held-out test frames.

    The authors' camera poses come from .mat files of random poses, one set per quadrant; here
    one camera stands in each quadrant at 3.5-4.5 m, 2-3 m high, aimed at the volume's centre.

    Returns:
        (SimulatedCapture of ``frames`` frames, WandObservations of ``test_frames`` more frames,
        their true wand ends (T, 2, 3)).
    """
    rng = np.random.default_rng(seed)
    w, h = PAPER_IMAGE
    K = np.array([[PAPER_FOCAL_PX, 0, w / 2], [0, PAPER_FOCAL_PX, h / 2], [0, 0, 1.0]])
    cams, Rs, ts = [], [], []
    for k in range(4):
        az = np.pi / 4 + k * np.pi / 2 + rng.uniform(-0.25, 0.25)
        dist = rng.uniform(3.5, 4.5)
        center = np.array([dist * np.cos(az), dist * np.sin(az), rng.uniform(2.0, 3.0)])
        R, t = look_at(center, np.array([0.0, 0.0, 1.2]) + rng.uniform(-0.2, 0.2, 3), roll=rng.uniform(-0.1, 0.1))
        cams.append(Camera(id=f"cam{k + 1}", width=w, height=h, K=K, dist=np.zeros(5)))
        Rs.append(R)
        ts.append(t)
    R, t = np.array(Rs), np.array(ts)
    wand = _random_wand_frames(frames + test_frames, cams, R, t, rng)
    train = observe_wand(cams, R, t, wand[:frames], noise_px, 0.0, 0.0, rng)
    test = observe_wand(cams, R, t, wand[frames:], noise_px, 0.0, 0.0, rng)
    static = observe_static(cams, R, t, PAPER_STATIC_M, noise_px, rng)
    rig = Rig(cameras=tuple(cams), wand_length=PAPER_WAND_M, static_markers=PAPER_STATIC_M.copy())
    sim = SimulatedCapture(rig=rig, wand=train, static=static, truth=Truth(R=R, t=t, wand=wand[:frames]))
    return sim, test, wand[frames:]


def _random_wand_frames(n: int, cams, R, t, rng) -> np.ndarray:
    """Wands at random positions (x, y ~ N(0, 1 m), z ~ U(0.1, 2.5 m)) and uniformly random
    directions, kept when at least two cameras see both ends (StreoSim.m's rule)."""
    out: list[np.ndarray] = []  # (2, 3) wand ends, metres
    while len(out) < n:
        mid = np.array([rng.normal(0, 1.0), rng.normal(0, 1.0), rng.uniform(0.1, 2.5)])
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        ends = np.stack([mid - d * PAPER_WAND_M / 2, mid + d * PAPER_WAND_M / 2])
        seen = 0
        for c, cam in enumerate(cams):
            if np.all(depth(R[c], t[c], ends) > 0.1):
                uv = distort_points(cam, project_normalized(R[c], t[c], ends))
                seen += bool(np.all((uv >= 0) & (uv < [cam.width, cam.height])))
        if seen >= 2:
            out.append(ends)
    return np.array(out)
