"""Simulated world references besides the L-frame: points on the floor, and a dropped ball.

The simulator's world has z up and the floor at z = 0 (the L-frame lies on it), so a calibration
set by either reference can be compared with the truth's vertical and floor.
"""

from __future__ import annotations

import numpy as np

from wandcal.calib.geometry import depth, distort_points, project_normalized
from wandcal.calib.rig import Rig, VerticalObservations

GRAVITY_M_S2 = 9.81
DROP_RATE_HZ = 100.0  # the simulated cameras' frame rate (sweep_frames' 150 frames: 1-4 m/s at 100 fps)
FLOOR_HALF_WIDTH_M = 1.0  # floor points are spread over a 2 x 2 m square under the volume
DROP_HEIGHT_M = 1.9  # the ball is let go this high (it falls 0.44 m in 30 frames at 100 fps)


def floor_points(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) points on the floor (z = 0) under the volume."""
    return np.column_stack([rng.uniform(-FLOOR_HALF_WIDTH_M, FLOOR_HALF_WIDTH_M, (n, 2)), np.zeros(n)])


def drop_track(frames: int, rng: np.random.Generator, rate_hz: float = DROP_RATE_HZ) -> np.ndarray:
    """(frames, 3) a ball let go near the volume's centre with a small sideways speed, falling freely."""
    tau = np.arange(frames) / rate_hz
    start = np.array([*rng.uniform(-0.4, 0.4, 2), DROP_HEIGHT_M])
    velocity = np.array([*rng.uniform(-0.3, 0.3, 2), rng.uniform(-0.2, 0.2)])
    return start + tau[:, None] * velocity - 0.5 * GRAVITY_M_S2 * tau[:, None] ** 2 * np.array([0, 0, 1.0])


def observe(rig: Rig, R: np.ndarray, t: np.ndarray, kind: str, X: np.ndarray, noise_px: float,
            rng: np.random.Generator) -> VerticalObservations:
    """Each point of ``X`` (K, 3) in every camera that sees it (in front, inside the image), with
    Gaussian pixel noise: floor points (key: the point's number) or the drop's frames (key: frame)."""
    key, camera, uv = [], [], []
    for c, cam in enumerate(rig.cameras):
        p = distort_points(cam, project_normalized(R[c], t[c], X)) + rng.normal(0, noise_px, (len(X), 2))
        inside = (depth(R[c], t[c], X) > 0.1) & (p[:, 0] > 0) & (p[:, 0] < cam.width) & (p[:, 1] > 0) & (
            p[:, 1] < cam.height)
        key.append(np.flatnonzero(inside))
        camera.append(np.full(inside.sum(), c))
        uv.append(p[inside])
    return VerticalObservations(kind, np.concatenate(key), np.concatenate(camera), np.concatenate(uv))
