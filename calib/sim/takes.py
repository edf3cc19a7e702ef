"""Simulated takes (issue 36): markers on moving rigid bodies seen as unlabelled blobs by every
camera, blobs dropped and spurious ones added, and a camera knocked or drifting from a given frame.

The rig is :func:`wandcal.calib.sim.simulate.simulate_capture`'s ring for the same seed and camera
count, so a take of seed s is of the rig a wand capture of seed s calibrates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.geometry import distort_points, rotvec_to_matrix
from wandcal.calib.rig import Rig
from wandcal.calib.sim.simulate import BORDER_PX, L_FRAME_M, ring_cameras
from wandcal.calib.watch.take import TakeBlobs

BODY_RADIUS_M = 0.15  # a rigid body's markers lie within this of its centre (a marker-suit limb, a prop)
MIN_MARKER_GAP_M = 0.03  # markers of one body at least this far apart (15 mm balls do not touch)
BODY_PERIOD_FRAMES = 400.0  # a body crosses the volume in about this many frames (4 s at 100 fps)
TAKE_STREAM = 36  # the take's own random stream beside the rig's (issue 36)
MERGE_PX = 4.0  # two markers' images nearer than this are one blob: a 14 mm ball at 3.5 m and f = 1100 px is 4.4 px wide


@dataclass(frozen=True)
class CameraMove:
    """A camera that moves during the take.

    camera: index into the rig; frame: the first frame it is moved at; rotation_deg: the angle it
    turns about its own centre; translation_mm: how far its centre moves; drift_frames: 0 for a
    knock (the whole move at ``frame``), else the move grows linearly over this many frames (a
    warming mount); seed: the axes' directions.
    """

    camera: int
    frame: int
    rotation_deg: float = 0.0
    translation_mm: float = 0.0
    drift_frames: int = 0
    seed: int = 0

    def share(self, frames: np.ndarray) -> np.ndarray:
        """(F,) the share of the full move applied at each frame, 0 to 1."""
        f = np.asarray(frames, dtype=float) - self.frame
        if self.drift_frames <= 0:
            return (f >= 0).astype(float)
        return np.clip((f + 1) / self.drift_frames, 0.0, 1.0)

    def axes(self) -> tuple[np.ndarray, np.ndarray]:
        """(3,) unit rotation axis and (3,) unit direction of the centre's move, world frame."""
        rng = np.random.default_rng([self.seed, self.camera, TAKE_STREAM])
        a, b = rng.normal(size=3), rng.normal(size=3)
        return a / np.linalg.norm(a), b / np.linalg.norm(b)

    def poses(self, R: np.ndarray, t: np.ndarray, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(F, 3, 3), (F, 3) the camera's world->camera pose at each frame from its standing pose
        ``R`` (3, 3), ``t`` (3,): turned about its centre and the centre moved."""
        s = self.share(frames)
        axis, direction = self.axes()
        center = -R.T @ t
        turn = np.array([rotvec_to_matrix(axis * np.radians(self.rotation_deg) * k) for k in s])
        Rf = turn @ R
        Cf = center + s[:, None] * direction * self.translation_mm / 1000.0
        return Rf, -np.einsum("fij,fj->fi", Rf, Cf)


@dataclass(frozen=True, eq=False)
class TakeTruth:
    """What a simulated take shows. R: (N, 3, 3), t: (N, 3) the standing poses; markers:
    (F, M, 3) metres; marker: (B,) each blob's marker, -1 for a spurious blob; merged: (B,) the
    second marker of a blob two markers' images merged into (:data:`MERGE_PX`), else -1; moves:
    the moved cameras."""

    R: np.ndarray
    t: np.ndarray
    markers: np.ndarray
    marker: np.ndarray
    merged: np.ndarray
    moves: tuple[CameraMove, ...]

    def is_of(self, rows: np.ndarray, marker: np.ndarray) -> np.ndarray:
        """Whether each blob row (any shape) shows the marker of the same shape (merged blobs show two)."""
        return (self.marker[rows] == marker) | (self.merged[rows] == marker)

    def to_json(self, rig: Rig) -> dict:
        return {
            "format": "wandcal-take-truth/1",
            "cameras": [{"id": cam.id, "R": self.R[i].tolist(), "t": self.t[i].tolist()} for i, cam in enumerate(rig.cameras)],
            "moves": [{"camera": rig.ids[m.camera], "frame": m.frame, "rotation_deg": m.rotation_deg,
                       "translation_mm": m.translation_mm, "drift_frames": m.drift_frames} for m in self.moves],
        }


@dataclass(frozen=True, eq=False)
class SimulatedTake:
    rig: Rig
    blobs: TakeBlobs
    truth: TakeTruth


def body_markers(frames: int, markers: int, bodies: int, rng: np.random.Generator, first: int = 0) -> np.ndarray:
    """(F, M, 3) markers on ``bodies`` rigid bodies that walk and turn through a 1.8 x 1.8 x 1.6 m
    volume, ``markers`` spread over them (metres), frames ``first`` .. ``first + frames - 1``."""
    tau = (first + np.arange(frames, dtype=float))[:, None] / BODY_PERIOD_FRAMES
    per_body = np.array_split(np.arange(markers), min(bodies, markers))
    out = np.empty((frames, markers, 3))
    for idx in per_body:
        local = _body_layout(len(idx), rng)
        freq = rng.uniform(0.5, 1.5, (3, 2))
        phase = rng.uniform(0, 2 * np.pi, (3, 2))
        centre = np.stack([np.sin(2 * np.pi * freq[d, 0] * tau[:, 0] + phase[d, 0]) * 0.5
                           + np.sin(2 * np.pi * freq[d, 1] * tau[:, 0] + phase[d, 1]) * 0.3 for d in range(3)], 1)
        centre = centre * [0.9, 0.9, 0.5] + [0.0, 0.0, 1.0]
        spin = rng.normal(size=3) * 2.0
        rot = np.array([rotvec_to_matrix(spin * s) for s in tau[:, 0]])  # (F, 3, 3)
        out[:, idx] = centre[:, None, :] + np.einsum("fij,mj->fmi", rot, local)
    return out


def _body_layout(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) marker positions within :data:`BODY_RADIUS_M` of the body's centre, at least
    :data:`MIN_MARKER_GAP_M` apart."""
    pts: list[np.ndarray] = []
    while len(pts) < n:
        p = rng.uniform(-BODY_RADIUS_M, BODY_RADIUS_M, 3)
        if np.linalg.norm(p) <= BODY_RADIUS_M and all(np.linalg.norm(p - q) >= MIN_MARKER_GAP_M for q in pts):
            pts.append(p)
    return np.array(pts)


def observe_take(rig: Rig, R: np.ndarray, t: np.ndarray, markers: np.ndarray, *, first: int = 0, noise_px: float,
                 dropped: float, spurious: float, moves: tuple[CameraMove, ...] = (),
                 rng: np.random.Generator) -> tuple[TakeBlobs, np.ndarray, np.ndarray]:
    """Blobs of markers (F, M, 3) in every camera: noise (pixels, std per axis), each blob dropped
    with probability ``dropped``, ``spurious`` extra blobs a camera-frame on average (Poisson, anywhere
    in the image), the image border; a moved camera seen from its pose at each frame.

    Returns the blobs in raster order within each camera-frame (as a detector gives them), (B,)
    each blob's marker index, -1 for a spurious one, and (B,) the second marker of a merged blob.
    """
    frames, n_markers = markers.shape[:2]
    frame_no = first + np.arange(frames)
    parts = []
    for c, cam in enumerate(rig.cameras):
        Rf = np.broadcast_to(R[c], (frames, 3, 3))
        tf = np.broadcast_to(t[c], (frames, 3))
        for move in moves:
            if move.camera == c:
                Rf, tf = move.poses(R[c], t[c], frame_no)
        Xc = np.einsum("fij,fmj->fmi", Rf, markers) + tf[:, None, :]
        z = Xc[..., 2].reshape(-1)
        xy = Xc[..., :2].reshape(-1, 2) / np.where(z > 0.1, z, 1.0)[:, None]
        uv = distort_points(cam, xy) + rng.normal(0, noise_px, (len(xy), 2))
        keep = ((z > 0.1) & (uv[:, 0] > BORDER_PX) & (uv[:, 0] < cam.width - BORDER_PX)
                & (uv[:, 1] > BORDER_PX) & (uv[:, 1] < cam.height - BORDER_PX) & (rng.random(len(xy)) >= dropped))
        uv, keep, other = _merge_close(uv.reshape(frames, n_markers, 2), keep.reshape(frames, n_markers))
        f_idx, m_idx = np.divmod(np.flatnonzero(keep), n_markers)
        n_spur = rng.poisson(spurious, frames)
        s_f = np.repeat(np.arange(frames), n_spur)
        s_uv = rng.uniform([BORDER_PX, BORDER_PX], [cam.width - BORDER_PX, cam.height - BORDER_PX], (len(s_f), 2))
        parts.append((np.concatenate([f_idx, s_f]), np.full(len(f_idx) + len(s_f), c),
                      np.concatenate([uv[keep], s_uv]), np.concatenate([m_idx, np.full(len(s_f), -1)]),
                      np.concatenate([other[keep], np.full(len(s_f), -1)])))
    f = np.concatenate([p[0] for p in parts])
    cams = np.concatenate([p[1] for p in parts])
    uv = np.concatenate([p[2] for p in parts])
    marker = np.concatenate([p[3] for p in parts])
    merged = np.concatenate([p[4] for p in parts])
    order = np.lexsort((uv[:, 0], np.floor(uv[:, 1]), cams, f))  # raster order: no trace of the marker's index
    return TakeBlobs(frame_no[f[order]], cams[order], uv[order]), marker[order], merged[order]


def _merge_close(uv: np.ndarray, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Markers' images (F, M, 2) nearer than :data:`MERGE_PX` seen as one blob at their mean, as a
    detector sees them: returns (F*M, 2) blobs, (F*M,) which are kept, and (F*M,) the marker each
    kept blob merged with (-1 none). Pairs only: a third marker in the same spot is rarer still."""
    d = np.linalg.norm(uv[:, :, None] - uv[:, None], axis=-1)
    both = keep[:, :, None] & keep[:, None, :]
    d = np.where(both, d, np.inf)
    idx = np.arange(uv.shape[1])
    d[:, idx, idx] = np.inf
    f, i, j = np.nonzero(np.triu(d < MERGE_PX))
    uv, keep = uv.copy(), keep.copy()
    other = np.full(keep.shape, -1)
    first = np.unique(f * uv.shape[1] + j, return_index=True)[1]  # a marker merges once
    f, i, j = f[first], i[first], j[first]
    free = keep[f, i] & keep[f, j]
    f, i, j = f[free], i[free], j[free]
    uv[f, i] = (uv[f, i] + uv[f, j]) / 2
    keep[f, j] = False
    other[f, i] = j
    return uv.reshape(-1, 2), keep.reshape(-1), other.reshape(-1)


def take_rig(cameras: int, seed: int) -> tuple[Rig, np.ndarray, np.ndarray]:
    """The rig of ``simulate_capture(cameras, seed=seed)`` and its poses R (N, 3, 3), t (N, 3)."""
    cams, R, t = ring_cameras(cameras, np.random.default_rng(seed))
    return Rig(cameras=tuple(cams), wand_length=0.5, static_markers=L_FRAME_M.copy()), R, t


def simulate_take(cameras: int = 12, frames: int = 1000, *, markers: int = 40, bodies: int = 5, noise_px: float = 0.3,
                  dropped: float = 0.03, spurious: float = 0.5, moves: tuple[CameraMove, ...] = (), seed: int = 1,
                  first: int = 0) -> SimulatedTake:
    """A take of ``simulate_capture(cameras, seed=seed)``'s rig: ``markers`` markers on ``bodies``
    rigid bodies, frames ``first`` .. ``first + frames - 1`` (a long take can be made in pieces that
    continue one another: the bodies' paths are a function of the frame number)."""
    rig, R, t = take_rig(cameras, seed)
    scene = np.random.default_rng([seed, TAKE_STREAM])
    pts = body_markers(frames, markers, bodies, scene, first)
    noise_rng = np.random.default_rng([seed, TAKE_STREAM, first])
    blobs, marker, merged = observe_take(rig, R, t, pts, first=first, noise_px=noise_px, dropped=dropped, spurious=spurious,
                                 moves=moves, rng=noise_rng)
    return SimulatedTake(rig, blobs, TakeTruth(R, t, pts, marker, merged, tuple(moves)))

