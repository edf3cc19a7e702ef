"""calib/watch/refracted.py: the matcher through a flat window, on a simulated cavity shaped like
OpenPTV's (calib/sim/cavity.py: two cameras on each side of a water-filled glass box), against the truth."""

import numpy as np

from wandcal.calib.refraction import project_through_window, trace_into_medium
from wandcal.calib.sim.cavity import FOCAL_PX, one_particle, simulate_cavity
from wandcal.calib.watch.match import MatchCounts, match_frames
from wandcal.calib.watch.refracted import CURVE_SAMPLES, Refracted
from wandcal.calib.watch.take import pad_frames

NOISE_PX = 0.3
MM_PER_PX = 0.1  # 0.57 m out at 5833 px
DEPTH_WEAKNESS = 3  # the cameras face each other across the box: depth is ~3x less sure than the side


def test_matches_through_the_window_are_the_particles():
    """>= 99% of the tracks hold one particle's blobs only (the issue's goal on simulated takes), and
    they find >= 90% of 200 particles; their points are within the noise's reach of the truth."""
    frame = simulate_cavity(200, noise_px=NOISE_PX, seed=3)
    model = Refracted(frame.R, frame.t, frame.windows, frame.depth, np.full(4, FOCAL_PX))
    counts = MatchCounts()
    tracks = match_frames(frame.rig, frame.R, frame.t, pad_frames(frame.rig, frame.blobs), model=model, counts=counts)
    who = one_particle(frame, tracks.views)
    assert (who >= 0).mean() >= 0.99, f"{(who >= 0).mean():.4f} of {len(tracks)} tracks are one particle's"
    assert len(np.unique(who[who >= 0])) >= 0.9 * 200
    assert counts.pairs >= counts.candidates >= len(tracks)
    error_mm = np.linalg.norm(tracks.X[who >= 0] - frame.X[who[who >= 0]], axis=1) * 1e3
    assert np.median(error_mm) < 3 * NOISE_PX * MM_PER_PX * DEPTH_WEAKNESS


def test_epipolar_curve_samples_follow_the_curve():
    """The sampled curve is within a tenth of the blob noise of the curve sampled 20x finer."""
    frame = simulate_cavity(0, noise_px=NOISE_PX, seed=0)
    model = Refracted(frame.R, frame.t, frame.windows, frame.depth, np.full(4, FOCAL_PX))
    xy = np.random.default_rng(4).uniform(-0.05, 0.05, (50, 2))
    for a, b in ((0, 1), (0, 2), (3, 1)):
        coarse = model._curves(a, b, xy) * FOCAL_PX
        fine = _dense_curve(model, a, b, xy, 20 * CURVE_SAMPLES) * FOCAL_PX
        checked = 0
        for k in range(len(xy)):
            ok = np.isfinite(coarse[k, :, 0])
            if ok.sum() < 2:
                continue
            checked += 1
            assert _polyline_distance(fine[k][np.isfinite(fine[k, :, 0])], coarse[k][ok]).max() < NOISE_PX / 10
        assert checked >= 10


def _dense_curve(model, a, b, xy, samples):
    origin, direction = trace_into_medium(model.windows[a], model.R[a], model.t[a], xy)
    down = -(direction @ model.windows[a].normal)
    depths = np.linspace(model.depth[a, 0], model.depth[a, 1], samples)
    X = origin[:, None] + (depths[None, :] / down[:, None])[..., None] * direction[:, None]
    proj = project_through_window(model.windows[b], model.R[b], model.t[b], X.reshape(-1, 3))
    return proj.reshape(len(xy), samples, 2)


def _polyline_distance(points, line):
    d = line[1:] - line[:-1]
    s = np.clip(np.einsum("pmk,mk->pm", points[:, None] - line[None, :-1], d) / (d * d).sum(1), 0, 1)
    foot = line[None, :-1] + s[..., None] * d[None]
    return np.linalg.norm(points[:, None] - foot, axis=2).min(1)
