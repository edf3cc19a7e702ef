"""A simulated particle frame seen through water: a glass box like OpenPTV's test cavity, two
cameras on each side 0.57 m out, each behind a 6 mm window 0.125 m from the centre
(calib/refraction.py), particles in criteria.par's volume, blobs with Gaussian noise."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.refraction import FlatWindow, project_through_window
from wandcal.calib.rig import Camera, Rig
from wandcal.calib.watch.take import TakeBlobs

FOCAL_PX = 5833.0  # OpenPTV's cavity: 70 mm behind 12 um pixels
SIZE = (1280, 1024)
VOLUME_M = (np.array([-0.04, -0.03, -0.02]), np.array([0.04, 0.03, 0.02]))  # the cavity's criteria.par volume
CENTRES_M = np.array([[0.1, 0.02, -0.57], [-0.1, 0.02, -0.57], [-0.1, 0.07, 0.58], [0.12, 0.07, 0.58]])
WINDOW_M, GLASS_M = 0.125, 0.006
INDICES = (1.0, 1.49, 1.33)  # air, glass, water


@dataclass(frozen=True, eq=False)
class CavityFrame:
    """One simulated frame. rig, R (4, 3, 3), t (4, 3) the cameras; windows, one a camera; depth
    (4, 2) metres below each window that the volume spans; blobs; particle (B,) each blob's
    particle; X (N, 3) the particles, metres."""

    rig: Rig
    R: np.ndarray
    t: np.ndarray
    windows: tuple[FlatWindow, ...]
    depth: np.ndarray
    blobs: TakeBlobs
    particle: np.ndarray
    X: np.ndarray


def _look_at(C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    z = -C / np.linalg.norm(C)
    x = np.cross([0.0, -1.0, 0.0], z)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    return R, -R @ C


def simulate_cavity(particles: int, *, noise_px: float, seed: int) -> CavityFrame:
    """``particles`` uniform in the volume, projected through each camera's window, noise_px of
    Gaussian noise a coordinate; a camera's blobs are in a random order, those off its image dropped."""
    rng = np.random.default_rng(seed)
    poses = [_look_at(C) for C in CENTRES_M]
    windows = tuple(FlatWindow(np.array([0.0, 0.0, np.sign(C[2])]), WINDOW_M, GLASS_M, *INDICES) for C in CENTRES_M)
    K = np.array([[FOCAL_PX, 0, SIZE[0] / 2 - 0.5], [0, FOCAL_PX, SIZE[1] / 2 - 0.5], [0, 0, 1]])
    rig = Rig(tuple(Camera(f"cam{i + 1}", *SIZE, K, np.zeros(5)) for i in range(len(CENTRES_M))), None)
    R, t = np.stack([p[0] for p in poses]), np.stack([p[1] for p in poses])
    depth = np.array([[w.distance - VOLUME_M[1][2], w.distance - VOLUME_M[0][2]] for w in windows])
    X = rng.uniform(*VOLUME_M, (particles, 3))
    cam, uv, who = [], [], []
    for c, window in enumerate(windows):
        p = project_through_window(window, R[c], t[c], X) * FOCAL_PX + K[:2, 2]
        p += rng.normal(0, noise_px, p.shape)
        inside = rng.permutation(np.flatnonzero((p >= 0).all(1) & (p[:, 0] < SIZE[0]) & (p[:, 1] < SIZE[1])))
        cam.append(np.full(len(inside), c))
        uv.append(p[inside])
        who.append(inside)
    camera = np.concatenate(cam)
    blobs = TakeBlobs(np.zeros(len(camera), np.int64), camera, np.concatenate(uv))
    return CavityFrame(rig, R, t, windows, depth, blobs, np.concatenate(who), X)


def one_particle(frame: CavityFrame, views: np.ndarray) -> np.ndarray:
    """(T,) the particle whose blobs every view of track t is, -1 where its views are of several."""
    owner = np.where(views >= 0, frame.particle[np.maximum(views, 0)], -1)
    first = owner.max(1)
    return np.where(((owner == first[:, None]) | (owner < 0)).all(1), first, -1)
