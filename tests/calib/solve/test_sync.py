"""Time offsets of cameras without a trigger (docs/sync.md): simulated rigs whose cameras expose
their frames at their own instants (calib/sim/simulate.py's offsets and drift_ppm)."""

import dataclasses

import numpy as np
import pytest
from scipy.stats import chi2

from wandcal.calib.geometry import kabsch, project_normalized
from wandcal.calib.observations import wand_pairs
from wandcal.calib.run.calibrate import calibrate
from wandcal.calib.run.options import CalibrationOptions
from wandcal.calib.sim.scenes import perturbed_model, prepared_scene
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.calib.solve.ba import bundle_adjust_points
from wandcal.calib.solve.reprojection import CAM_PARAMS, TIME_PARAMS, TimeFit
from wandcal.calib.solve.sync import fit_timing
from wandcal.calib.start.labels import label_ends

NOISE_PX = 0.3
OFFSET_TOL_FRAMES = 0.05  # the goal
RIG_RATIO = 1.2  # the goal: the rig's error within 1.2x the same rig synchronised
DRIFT_TOL_PPM = 20.0  # the goal at 100 ppm
CHI2_TAIL = 0.001  # each side: a correct SE fails the spread test once in 500 runs


def _offsets(n: int, rng: np.random.Generator) -> np.ndarray:
    """Whole frames up to +-5 plus fractions, the first camera (the reference) at 0."""
    off = rng.integers(-5, 6, n) + rng.uniform(-0.5, 0.5, n)
    off[0] = 0.0
    return off


def _found(result) -> tuple[np.ndarray, np.ndarray]:
    cams = result.sync["cameras"]
    assert result.sync["reference"] == cams[0]["id"]
    return np.array([c["offset_frames"] for c in cams]), np.array([c["offset_std_frames"] for c in cams])


def _centre_error_mm(result, sim) -> float:
    Ra, ta, s = kabsch(result.centers, sim.truth.centers, scale=True)
    return float(np.sqrt(np.mean(np.sum((s * result.centers @ Ra.T + ta - sim.truth.centers) ** 2, 1))) * 1000)


def test_offsets_found_within_a_twentieth_of_a_frame_and_the_rig_as_good_as_synchronised():
    errors, synced = [], []
    for seed in (11, 12):
        off = _offsets(6, np.random.default_rng(seed))
        sim = simulate_capture(6, 1000, NOISE_PX, static=False, seed=seed, offsets=off)
        result = calibrate(sim.rig, sim.wand, options=CalibrationOptions(sync="auto"))
        found, _ = _found(result)
        assert np.abs(found - off).max() < OFFSET_TOL_FRAMES, (found, off)
        assert any("cam2 is out of time" in w or "out of time" in w for w in result.warnings)
        errors.append(_centre_error_mm(result, sim))
        plain = simulate_capture(6, 1000, NOISE_PX, static=False, seed=seed)
        synced.append(_centre_error_mm(calibrate(plain.rig, plain.wand), plain))
    # RMS over the seeds: one seed's ratio scatters by ~15% with the noise alone
    assert np.sqrt(np.mean(np.square(errors))) <= RIG_RATIO * np.sqrt(np.mean(np.square(synced)))


@pytest.mark.parametrize("frames", [600, pytest.param(1500, marks=pytest.mark.long)])
def test_predicted_standard_error_matches_the_spread_over_seeds(frames):
    """sum of z^2 over independent seeds (one camera each: offsets share the reference's noise)
    lies within the chi^2 bounds of that many degrees of freedom, for a short recording and a
    longer one (docs/sync.md, "How fast the wand must move")."""
    z = []
    for seed in range(20, 32):
        # six cameras: a rig of five or fewer is judged by the few-camera path, 3 of its 3.4 CPU s here
        off = _offsets(6, np.random.default_rng(seed))
        sim = simulate_capture(6, frames, NOISE_PX, static=False, seed=seed, offsets=off)
        found, std = _found(calibrate(sim.rig, sim.wand, options=CalibrationOptions(sync="auto")))
        z.append((found[1] - off[1]) / std[1])
    total = float(np.sum(np.square(z)))
    assert chi2.ppf(CHI2_TAIL, len(z)) < total < chi2.ppf(1 - CHI2_TAIL, len(z)), z


def test_drift_of_100_ppm_found_within_20_ppm():
    rng = np.random.default_rng(5)
    off = _offsets(6, rng)
    drift = rng.choice([-100.0, 100.0], 6)
    drift[0] = 0.0
    sim = simulate_capture(6, 3000, NOISE_PX, static=False, seed=5, offsets=off, drift_ppm=drift)
    result = calibrate(sim.rig, sim.wand, options=CalibrationOptions(sync="auto", sync_drift=True))
    cams = result.sync["cameras"]
    found = np.array([c["drift_ppm"] for c in cams])
    assert np.abs(found - drift).max() < DRIFT_TOL_PPM, (found, drift)
    offsets = np.array([c["offset_frames"] for c in cams])
    assert np.abs(offsets - off).max() < OFFSET_TOL_FRAMES


def test_a_synchronised_capture_under_auto_reports_zero_and_matches_none():
    sim = simulate_capture(6, 1000, NOISE_PX, static=True, seed=7)
    none = calibrate(sim.rig, sim.wand, sim.static)
    auto = calibrate(sim.rig, sim.wand, sim.static, options=CalibrationOptions(sync="auto"))
    found, std = _found(auto)
    z = found[1:] / std[1:]
    assert np.sum(z**2) < chi2.ppf(1 - CHI2_TAIL, len(z)), z
    assert not any("out of time" in w for w in auto.warnings)
    sigma_mm = np.array([c.uncertainty.center_std_mm for c in none.cameras])
    moved_mm = np.linalg.norm(auto.centers - none.centers, axis=1) * 1000
    assert np.all(moved_mm < sigma_mm), (moved_mm, sigma_mm)
    assert "sync" not in none.to_json() and auto.to_json()["sync"]["mode"] == "auto"


@pytest.mark.parametrize("sweep", [150.0, 600.0])
def test_standard_error_follows_the_wands_image_speed(sweep):
    """SE(offset) ~ sigma_px / (|v|_rms sqrt(n)) (docs/sync.md), with the poses known: a wand four
    times slower gives a standard error four times larger."""
    off = np.array([0.0, 0.3, -0.2, 0.4])
    sim = simulate_capture(4, 800, NOISE_PX, static=False, seed=3, offsets=off, sweep_frames=sweep)
    pairs = wand_pairs(sim.rig, sim.wand)
    labelled = label_ends(sim.truth.R, sim.truth.t, pairs, np.ones(4, bool), sim.rig.wand_length)[0]
    focal = np.array([c.focal for c in sim.rig.cameras])
    timing = fit_timing(sim.truth.R, sim.truth.t, labelled, focal, 0)
    value, std = timing.offset_at(np.zeros(4))
    # the formula from each camera's own image speed, the points' share of the information taken
    # out as 1 - 1/views (each wand end is seen by ~4 cameras, which share its triangulation); the
    # offset is relative to the reference camera, whose own timing is as uncertain: their
    # variances add
    def alone(c: int) -> float:
        mine = labelled.camera == c
        f = labelled.frames[labelled.frame[mine]]
        f = f[f + 1 < len(sim.truth.wand)]
        ends = sim.truth.wand[np.concatenate([f, f + 1])].reshape(2, -1, 3)
        uv = [project_normalized(sim.truth.R[c], sim.truth.t[c], e) * focal[c] for e in ends]
        v = np.linalg.norm(uv[1] - uv[0], axis=1)  # each end's image speed, px a frame
        views = np.bincount(labelled.frame, minlength=len(labelled.frames))[labelled.frame[mine]].mean()
        return timing.sigma_px / (np.sqrt(np.mean(v**2)) * np.sqrt(2 * mine.sum() * (1 - 1 / views)))

    c = 1
    assert std[c] == pytest.approx(np.hypot(alone(c), alone(0)), rel=0.2)
    assert abs(value[c] - off[c]) < 5 * std[c]


def _true_velocity(scene) -> np.ndarray:
    """(M, 2) each wand observation's image velocity from the true path, pixels a frame (the
    central difference of the true end's projections; the end nearest the observation's blob)."""
    T, p = scene.sim.truth, scene.setup.problem
    f = scene.setup.frames[p.frame]
    before, after = np.clip(f - 1, 0, len(T.wand) - 1), np.clip(f + 1, 0, len(T.wand) - 1)
    focal = p.focal[p.camera]
    def seen(frames, end):
        return np.array([project_normalized(T.R[c], T.t[c], T.wand[k, e][None])[0]
                         for c, k, e in zip(p.camera, frames, end)])
    near = [np.linalg.norm(seen(f, np.full(len(f), e)) - p.xy, axis=1) for e in (0, 1)]
    end = (near[1] < near[0]).astype(int)
    return (seen(after, end) - seen(before, end)) / (after - before)[:, None] * focal


def test_ba_without_the_time_columns_is_the_plain_path():
    """``--sync none`` (and every method but ``ba`` under auto) adds no column: the offsets' block
    held at zero with no velocity changes nothing, and without it there is no extra column."""
    scene = prepared_scene(cameras=4, frames=200, noise_px=NOISE_PX, seed=2)
    model = perturbed_model(scene, degrees=1.0, metres=0.03, seed=2)
    plain = bundle_adjust_points(model, None, None, loss="linear")
    assert plain.dt is None and plain.camera_std.shape == (4, CAM_PARAMS)
    held = bundle_adjust_points(model, None, None, loss="linear",
                                timing=TimeFit(np.zeros((len(model.p.camera), 2)), np.ones(4, bool)))
    assert held.camera_std.shape == (4, CAM_PARAMS + TIME_PARAMS) and np.all(held.dt == 0)
    # the same steps: only rounding in the reduced system's extra (identity) rows may differ
    assert np.allclose(held.x, plain.x, rtol=0, atol=1e-9)


def test_ba_refines_time_offsets_left_in_the_observations():
    """Each camera's observations resampled with an offset delta too large (a few hundredths of a
    frame, as a fit on fewer frames may leave): each blob is the one at f - delta, xy - delta v (v
    the true image velocity). ``ba`` with the time columns finds the increment -delta within the
    chi^2 bound of its own standard errors, the reference camera held."""
    scene = prepared_scene(cameras=5, frames=400, noise_px=NOISE_PX, seed=4)
    p = scene.setup.problem
    velocity = _true_velocity(scene)
    delta = np.array([0.0, 0.03, -0.02, 0.05, -0.04])
    moved = p.xy - delta[p.camera, None] * velocity / p.focal[p.camera]
    setup = dataclasses.replace(scene.setup, problem=dataclasses.replace(p, xy=moved))
    model = perturbed_model(dataclasses.replace(scene, setup=setup), degrees=1.0, metres=0.03, seed=4)
    held = np.zeros(5, bool)
    held[0] = True
    out = bundle_adjust_points(model, None, None, loss="linear", timing=TimeFit(velocity, held))
    assert out.dt[0] == 0 and out.info["status"] == "converged"
    z = (out.dt[1:] + delta[1:]) / out.camera_std[1:, -1]
    assert np.sum(z**2) < chi2.ppf(1 - CHI2_TAIL, len(z)), z
