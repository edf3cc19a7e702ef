"""Simulated captures with one thing wrong, whose truth is known: the cases the judgement is
tested on (tests/calib/judge/, bench/bench_judgement.py).

Each function takes a :class:`~wandcal.calib.sim.simulate.SimulatedCapture` and returns one with
the named fault: a camera's intrinsics in rig.json off, a camera out of time, the wand length
disagreeing with the static object, reflections or extra noise in one camera, a camera knocked
partway through.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from wandcal.calib.geometry import distort_points, project_normalized, rotvec_to_matrix, undistort_points
from wandcal.calib.rig import Camera, Rig, WandObservations
from wandcal.calib.sim.simulate import SimulatedCapture


def _with_camera(rig: Rig, c: int, cam: Camera) -> Rig:
    cams = list(rig.cameras)
    cams[c] = cam
    return replace(rig, cameras=tuple(cams))


def wrong_focal(sim: SimulatedCapture, c: int, factor: float) -> SimulatedCapture:
    """rig.json gives camera c a focal length ``factor`` times its true one (blobs unchanged)."""
    cam = sim.rig.cameras[c]
    K = cam.K.copy()
    K[0, 0] *= factor
    K[1, 1] *= factor
    return replace(sim, rig=_with_camera(sim.rig, c, replace(cam, K=K)))


def wrong_k1(sim: SimulatedCapture, c: int, k1: float) -> SimulatedCapture:
    """rig.json gives camera c the radial distortion ``k1`` where the lens has its true one."""
    cam = sim.rig.cameras[c]
    dist = np.zeros(max(len(cam.dist), 5))
    dist[: len(cam.dist)] = cam.dist
    dist[0] = k1
    return replace(sim, rig=_with_camera(sim.rig, c, replace(cam, dist=dist)))


def wrong_wand_length(sim: SimulatedCapture, factor: float) -> SimulatedCapture:
    """rig.json gives the wand ``factor`` times its true length (the static object stays right)."""
    if sim.rig.wand_length is None:
        raise ValueError("the simulated capture has no wand")
    return replace(sim, rig=replace(sim.rig, wand_length=sim.rig.wand_length * factor))


def late_camera(sim: SimulatedCapture, c: int, frames: float, noise_px: float, seed: int) -> SimulatedCapture:
    """Camera c ``frames`` late (docs/result-format.md's sign: negative is early): its frame k was
    exposed at the others' frame k + ``frames`` and shows the wand of then (fractions interpolated
    along the true path), with ``noise_px`` blob noise; frames it has no wand for are left out."""
    rng = np.random.default_rng(seed)
    wand = sim.truth.wand
    F = len(wand)
    at = np.arange(F) + frames
    ok = (at >= 0) & (at <= F - 1)
    lo = np.clip(np.floor(at).astype(int), 0, F - 1)
    hi = np.clip(lo + 1, 0, F - 1)
    w = (at - lo)[:, None, None]
    shifted = (1 - w) * wand[lo] + w * wand[hi]
    mine = sim.wand.camera == c
    frame, end_uv = sim.wand.frame[mine], sim.wand.uv[mine]
    keep = ok[frame]
    cam = sim.rig.cameras[c]
    # each kept blob becomes the nearer of the two shifted ends (the blob order stays unlabelled)
    ends = shifted[frame[keep]]  # (B, 2, 3)
    uv = np.stack([distort_points(cam, project_normalized(sim.truth.R[c], sim.truth.t[c], ends[:, e])) for e in (0, 1)], 1)
    pick = np.argmin(np.linalg.norm(uv - end_uv[keep][:, None, :], axis=2), axis=1)
    new_uv = uv[np.arange(len(pick)), pick] + rng.normal(0, noise_px, (len(pick), 2))
    return replace(sim, wand=_replace_camera(sim.wand, c, frame[keep], new_uv))


def reflections(sim: SimulatedCapture, c: int, share: float, seed: int) -> SimulatedCapture:
    """In a ``share`` of camera c's frames, one wand blob is replaced by a reflection 20-60 px off."""
    rng = np.random.default_rng(seed)
    mine = np.flatnonzero(sim.wand.camera == c)
    frames = np.unique(sim.wand.frame[mine])
    hit = set(frames[rng.random(len(frames)) < share].tolist())
    uv = sim.wand.uv.copy()
    done: set[int] = set()
    for i in mine:
        f = int(sim.wand.frame[i])
        if f in hit and f not in done:
            ang, mag = rng.uniform(0, 2 * np.pi), rng.uniform(20, 60)
            uv[i] += mag * np.array([np.cos(ang), np.sin(ang)])
            done.add(f)
    return replace(sim, wand=WandObservations(sim.wand.frame, sim.wand.camera, uv))


def noisy_camera(sim: SimulatedCapture, c: int, extra_px: float, seed: int) -> SimulatedCapture:
    """Camera c's blobs get ``extra_px`` more noise per axis (out of focus, a poor exposure)."""
    rng = np.random.default_rng(seed)
    uv = sim.wand.uv.copy()
    mine = sim.wand.camera == c
    uv[mine] += rng.normal(0, extra_px, (int(mine.sum()), 2))
    return replace(sim, wand=WandObservations(sim.wand.frame, sim.wand.camera, uv))


def knocked_camera(sim: SimulatedCapture, c: int, degrees: float, seed: int) -> SimulatedCapture:
    """Camera c turned by ``degrees`` about a random axis through its centre (drawn from ``seed``)
    after the middle of its wand frames: its later blobs are seen through the turned camera (each
    undistorted, its ray rotated, projected and distorted again), every marker of any wand."""
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    Rk = rotvec_to_matrix(np.radians(degrees) * axis / np.linalg.norm(axis))
    cam, obs = sim.rig.cameras[c], sim.wand
    mine = obs.camera == c
    after = mine & (obs.frame > np.median(obs.frame[mine]))
    ray = np.concatenate([undistort_points(cam, obs.uv[after]), np.ones((int(after.sum()), 1))], axis=1) @ Rk.T
    uv = obs.uv.copy()
    uv[after] = distort_points(cam, ray[:, :2] / ray[:, 2:])
    return replace(sim, wand=WandObservations(obs.frame, obs.camera, uv))


def _replace_camera(wand: WandObservations, c: int, frame: np.ndarray, uv: np.ndarray) -> WandObservations:
    other = wand.camera != c
    return WandObservations(np.concatenate([wand.frame[other], frame]),
                            np.concatenate([wand.camera[other], np.full(len(frame), c)]),
                            np.concatenate([wand.uv[other], uv]))


# The cases the judgement is measured on: (name, fault kind expected or None for a good rig,
# whether it names a camera). Magnitudes vary with the seed so no case is tuned to one number.
CASES = ("good", "good_no_static", "focal", "k1", "late", "early", "reflections", "noisy", "wand_length")
EXPECTED = {"good": None, "good_no_static": None, "focal": "intrinsics", "k1": "intrinsics", "late": "timing",
            "early": "timing", "reflections": "outliers", "noisy": "noise", "wand_length": "wand_scale"}


def broken_capture(case: str, seed: int, cameras: int = 6, frames: int = 1000, noise_px: float = 0.3):
    """A simulated capture with the fault ``case`` (one of :data:`CASES`), its magnitude and the
    camera at fault drawn from ``seed``. Returns (capture, the camera index at fault or None,
    the fault's size: the offset in frames for timing, the factor for focal and wand length)."""
    from wandcal.calib.sim.simulate import simulate_capture

    rng = np.random.default_rng(1000 + seed)
    sim = simulate_capture(cameras, frames, noise_px, 0.0, case != "good_no_static", seed)
    c = int(rng.integers(0, cameras))
    sign = rng.choice([-1.0, 1.0])
    if case in ("good", "good_no_static"):
        return sim, None, None
    if case == "focal":
        factor = 1 + sign * rng.uniform(0.04, 0.12)
        return wrong_focal(sim, c, factor), c, factor
    if case == "k1":
        k1 = sign * rng.uniform(0.15, 0.35)
        return wrong_k1(sim, c, k1), c, k1
    if case in ("late", "early"):
        offset = (1 if case == "late" else -1) * rng.uniform(0.4, 3.5)
        return late_camera(sim, c, offset, noise_px, seed), c, offset
    if case == "reflections":
        return reflections(sim, c, rng.uniform(0.08, 0.25), seed), c, None
    if case == "noisy":
        return noisy_camera(sim, c, rng.uniform(2.5, 4.0) * noise_px, seed), c, None
    if case == "wand_length":
        factor = 1 + sign * rng.uniform(0.02, 0.06)
        return wrong_wand_length(sim, factor), None, factor
    raise ValueError(f"unknown case {case!r}; one of {', '.join(CASES)}")
