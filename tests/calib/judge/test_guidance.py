"""Wanding guidance on seeded simulated captures: enough when well covered, the starved camera
named alone, the predicted sigma falling as frames arrive and matching the real error spread."""

import numpy as np
import pytest
from scipy.stats import chi2

from wandcal.calib.errors import CalibrationError
from wandcal.calib.geometry import camera_centers
from wandcal.calib.observations import wand_pairs
from wandcal.calib.rig import Rig, WandObservations
from wandcal.calib.run.calibrate import calibrate
from wandcal.calib.run.guidance import (
    DEFAULT_MIN_COVERAGE,
    DEFAULT_TARGET_STD_MM,
    NO_WAND_YET,
    SILENT_CAMERA_FRAMES,
    GuidanceSettings,
    subsample,
    wanding_guidance,
)
from wandcal.calib.sim.simulate import L_FRAME_M, observe_static, observe_wand, ring_cameras
from wandcal.calib.solve.gauge_free import AXIS_POINT_M

NOISE_PX = 0.3
WAND_M = 0.5
# The ring's cameras stand 3.2 m out and aim near (0, 0, 0.8 m): a volume of 3.6 x 3.6 x 1.8 m
# reaches the edges of their views, as a lab waves through the whole captured volume.
VOLUME_LOW, VOLUME_HIGH = (-1.8, -1.8, 0.2), (1.8, 1.8, 2.0)
STARVED, STARVED_FRAMES = "cam5", 40
SEEDS = 10
FALSE_ALARM = 1e-3  # two-sided chance that a right prediction fails the spread test


def covering_capture(cameras: int = 8, frames: int = 1500, seed: int = 0, noise_px: float = NOISE_PX):
    """A rig on a ring and a wand waved at random through the whole volume (it covers each view)."""
    rng = np.random.default_rng(seed)
    cams, R, t = ring_cameras(cameras, rng)
    middle = rng.uniform(VOLUME_LOW, VOLUME_HIGH, (frames, 3))
    direction = rng.normal(size=(frames, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    wand = np.stack([middle - WAND_M / 2 * direction, middle + WAND_M / 2 * direction], axis=1)
    observed = observe_wand(cams, R, t, wand, noise_px, 0.0, 0.0, rng)
    static = observe_static(cams, R, t, L_FRAME_M, noise_px / 10, rng)
    return Rig(tuple(cams), WAND_M, L_FRAME_M.copy()), observed, static, (R, t)


def starve(rig: Rig, wand: WandObservations, camera_id: str, frames: int) -> WandObservations:
    """Keep only ``frames`` of the camera's frames, all with both ends in the top-left ninth of its image."""
    c = rig.index(camera_id)
    cam = rig.cameras[c]
    mine = wand.camera == c
    corner = mine & (wand.uv[:, 0] < cam.width / 3) & (wand.uv[:, 1] < cam.height / 3)
    f, n = np.unique(wand.frame[corner], return_counts=True)
    keep = ~mine | np.isin(wand.frame, f[n == 2][:frames])
    return WandObservations(wand.frame[keep], wand.camera[keep], wand.uv[keep])


def first_frames(wand: WandObservations, frames: int) -> WandObservations:
    keep = wand.frame < frames
    return WandObservations(wand.frame[keep], wand.camera[keep], wand.uv[keep])


@pytest.fixture(scope="module")
def covered():
    return covering_capture()


def test_a_well_covered_rig_is_enough(covered):
    rig, wand, static, _ = covered
    doc = wanding_guidance(rig, wand, static).document
    assert doc["enough"] and doc["advice"] == []
    assert doc["target"] == {"center_std_mm": DEFAULT_TARGET_STD_MM, "coverage": DEFAULT_MIN_COVERAGE}
    assert doc["solve"]["ok"] and doc["solve"]["cameras"] == 8
    for cam in doc["cameras"]:
        assert cam["advice"] is None
        assert cam["center_std_mm"] < DEFAULT_TARGET_STD_MM and cam["coverage"] >= DEFAULT_MIN_COVERAGE
        assert np.array(cam["grid"]).shape == (8, 8)
        # every frame with both ends in two cameras is a link of both
        assert sum(cam["linked"].values()) >= cam["shared_frames"] > 0
    counted = np.bincount(wand_pairs(rig, wand).camera, minlength=8)
    assert [cam["frames"] for cam in doc["cameras"]] == counted.tolist()


def test_a_starved_camera_is_named_and_no_other(covered):
    rig, wand, static, _ = covered
    doc = wanding_guidance(rig, starve(rig, wand, STARVED, STARVED_FRAMES), static).document
    assert not doc["enough"]
    assert len(doc["advice"]) == 1 and doc["advice"][0].startswith(STARVED)
    others = [cam for cam in doc["cameras"] if cam["id"] != STARVED]
    assert all(cam["advice"] is None for cam in others), [cam["advice"] for cam in others]
    (cam,) = [cam for cam in doc["cameras"] if cam["id"] == STARVED]
    assert cam["frames"] == STARVED_FRAMES
    assert cam["coverage"] < DEFAULT_MIN_COVERAGE and cam["center_std_mm"] > DEFAULT_TARGET_STD_MM
    # its samples are all in the top-left: the advice says so and sends the wand everywhere else
    assert "samples only in the top-left of its image" in cam["advice"] and "the rest of its view" in cam["advice"]


def test_a_camera_that_saw_nothing_is_named_first():
    rig, wand, static, _ = covering_capture(cameras=5, frames=500, seed=4)
    keep = wand.camera != 2
    doc = wanding_guidance(rig, WandObservations(wand.frame[keep], wand.camera[keep], wand.uv[keep]), static).document
    assert not doc["enough"] and doc["advice"][0].startswith("cam3 has not seen both wand ends")
    assert doc["cameras"][2]["center_std_mm"] is None and doc["cameras"][2]["frames"] == 0
    assert doc["solve"]["ok"] and doc["solve"]["cameras"] == 4


def test_nothing_yet_is_not_enough_and_says_why():
    rig, _, static, _ = covering_capture(cameras=3, frames=10, seed=1)
    doc = wanding_guidance(rig, WandObservations([], [], np.zeros((0, 2))), static).document
    assert not doc["enough"] and not doc["solve"]["ok"] and doc["frames"] == 0
    assert doc["advice"][0] == doc["solve"]["message"] == NO_WAND_YET
    # no wand yet says nothing about a camera: no camera is suspected of being off
    assert len(doc["advice"]) == 4 and all(a.endswith("waiting for the wand") for a in doc["advice"][1:])


def test_a_silent_camera_is_suspected_only_once_the_others_saw_the_wand():
    """Before the rest of the rig has seen the wand in SILENT_CAMERA_FRAMES frames, a camera that
    saw none is asked for the wand, not suspected of being off."""
    rig, wand, static, _ = covering_capture(cameras=4, frames=500, seed=4)
    for frames, suspected in ((20, False), (SILENT_CAMERA_FRAMES + 50, True)):
        keep = (wand.camera != 2) & (wand.frame < frames)
        doc = wanding_guidance(rig, WandObservations(wand.frame[keep], wand.camera[keep], wand.uv[keep]), static).document
        said = doc["cameras"][2]["advice"]
        assert not doc["enough"] and said.startswith("cam3 has not seen both wand ends"), said
        assert ("check that it is on" in said) == suspected, (frames, said)


def test_a_camera_that_saw_a_still_wand_is_named_and_spoils_no_other():
    """cam3 sees only a wand held still (1 mm of jitter) in 12 frames, with cam1: it is placed,
    but hardly determined. The reference frame's reweighting keeps its metres of sigma out of
    the others'."""
    rig, wand, static, (R, t) = covering_capture(cameras=5, frames=400, seed=7)
    rng = np.random.default_rng(1)
    still = np.array([[0.0, 0.0, 1.0], [WAND_M, 0.0, 1.0]]) + rng.normal(0, 0.001, (12, 2, 3))
    seen = observe_wand(rig.cameras, R, t, still, NOISE_PX, 0.0, 0.0, rng)
    extra = np.isin(seen.camera, [0, 2])
    others = wand.camera != 2
    thin = WandObservations(np.concatenate([wand.frame[others], seen.frame[extra] + wand.frame.max() + 1]),
                            np.concatenate([wand.camera[others], seen.camera[extra]]),
                            np.concatenate([wand.uv[others], seen.uv[extra]]))
    doc = wanding_guidance(rig, thin, static).document
    assert len(doc["advice"]) == 1 and doc["advice"][0].startswith("cam3")
    sigma = np.array([cam["center_std_mm"] for cam in doc["cameras"]])
    assert sigma[2] > 100 * np.delete(sigma, 2).max()
    assert np.delete(sigma, 2).max() < DEFAULT_TARGET_STD_MM


def _anchors(R, t):
    """(2N, 3): every camera's centre, then a point along its optical axis (gauge_free's anchors)."""
    C = camera_centers(R, t)
    return np.concatenate([C, C + AXIS_POINT_M * R[:, 2, :]])


def _weighted_fit(source, target, weight):
    """The rigid map ``target ~ Rw source + tw`` of least weighted squares (Umeyama with weights)."""
    w = weight / weight.sum()
    mu_s, mu_t = w @ source, w @ target
    U, _, Vt = np.linalg.svd((target - mu_t).T @ ((source - mu_s) * w[:, None]))
    Rw = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    return Rw, mu_t - Rw @ mu_s


def _relative_errors(R, t, R_true, t_true, sigma):
    """Centre errors (N,) after the reference frame of the prediction: the weighted fit of the
    estimate's anchors onto the truth's."""
    Rw, tw = _weighted_fit(_anchors(R, t), _anchors(R_true, t_true), np.tile(1 / sigma**2, 2))
    return np.linalg.norm(camera_centers(R, t) @ Rw.T + tw - camera_centers(R_true, t_true), axis=1)


def test_the_predicted_sigma_falls_as_frames_arrive_and_matches_the_real_error_spread():
    """The bounds: each camera's squared error over its predicted variance has mean 1; the cameras
    of one rig share the frame's error, so in the worst case they count as one sample per seed
    (a chi^2 with SEEDS degrees of freedom, as tests/calib/solve/test_uncertainty.py). The subsample
    adds its own error: sigma^2 scaled from n of N frames per camera has a relative spread of
    sqrt((1 - n/N) / n) (sampling without replacement, per-frame information of unit spread),
    half of that on sigma, allowed to 3 of its sigmas."""
    cameras, frames, kept = 6, 1200, 200
    settings = GuidanceSettings(frames_per_camera=kept)
    ratios, drops = [], []
    for seed in range(SEEDS):
        rig, wand, static, (R_true, t_true) = covering_capture(cameras, frames, 100 + seed)
        sigmas = []
        start = None
        for prefix in (150, 300, 600, frames):
            g = wanding_guidance(rig, first_frames(wand, prefix), static, settings, start)
            start = g.solution
            sigmas.append([cam["center_std_mm"] for cam in g.document["cameras"]])
        sigmas = np.array(sigmas)
        assert np.all(np.diff(sigmas, axis=0) < 0), sigmas  # every camera, every time frames arrive
        drops.append(sigmas[0] / sigmas[-1])
        res = calibrate(rig, wand, static)
        errors = _relative_errors(res.R, res.t, R_true, t_true, sigmas[-1] / 1000)
        ratios.append(errors / (sigmas[-1] / 1000))
    subsample_tol = 3 * 0.5 * np.sqrt((1 - kept / (frames * 0.8)) / kept)  # ~80% of frames reach each camera
    lo = np.sqrt(chi2.ppf(FALSE_ALARM / 2, SEEDS) / SEEDS) / (1 + subsample_tol)
    hi = np.sqrt(chi2.ppf(1 - FALSE_ALARM / 2, SEEDS) / SEEDS) * (1 + subsample_tol)
    rms = float(np.sqrt(np.mean(np.square(np.concatenate(ratios)))))
    print(f"RMS(error/predicted) {rms:.2f} in [{lo:.2f}, {hi:.2f}]; sigma drop over 8x the frames {np.median(drops):.2f}")
    assert lo < rms < hi, f"RMS of error / predicted {rms:.2f} outside [{lo:.2f}, {hi:.2f}]"
    # information grows with the frames: 8x the frames, about sqrt(8) = 2.8x less sigma
    assert 2.0 < float(np.median(drops)) < 4.0, np.median(drops)


def test_the_subsample_is_nested_as_the_capture_grows(covered):
    rig, wand, _, _ = covered
    early, late = wand_pairs(rig, first_frames(wand, 700)), wand_pairs(rig, wand)
    kept_early = set(early.frames[subsample(early, 100)])
    kept_late = set(late.frames[subsample(late, 100)])
    assert kept_late & set(early.frames) <= kept_early  # a lower rate keeps a subset of the same draw
    per_camera = np.bincount(late.camera[subsample(late, 100)[late.frame]], minlength=8)
    assert np.all(per_camera >= 100 * 0.7), per_camera  # about the cap for each camera


def test_the_links_count_as_the_start_counts_them():
    # the guidance counts each frame's camera pairs (sparse); the start's table is frames x cameras:
    # the same integers on a sparse capture with repeated camera-frames and a camera that saw nothing
    from wandcal.calib.observations import WandPairs
    from wandcal.calib.run.guidance.update import _shared_frames
    from wandcal.calib.start.initial import shared_frames

    rng = np.random.default_rng(3)
    frame = rng.integers(0, 40, 300)
    camera = rng.integers(0, 6, 300)  # camera 6 of 7 never seen; some (frame, camera) rows twice
    pairs = WandPairs(frame, camera, np.zeros((300, 2, 2)), np.zeros((300, 2, 2)), np.arange(40))
    np.testing.assert_array_equal(_shared_frames(pairs, 7), shared_frames(pairs, 7))
    assert _shared_frames(WandPairs.empty(), 3).shape == (3, 3)


def test_a_warm_start_gives_the_cold_answer(covered, monkeypatch):
    import wandcal.calib.start.static as static_module

    rig, wand, static, _ = covered
    cold = wanding_guidance(rig, first_frames(wand, 800), static)
    warm = wanding_guidance(rig, wand, static, start=cold.solution)
    again = wanding_guidance(rig, wand, static)
    assert warm.document["solve"]["warm_start"] and not again.document["solve"]["warm_start"]
    # a camera that joins since the last solve: the start places it from the seven solved, with
    # no static object's PnP, and the solve gives the cold answer as well
    early = first_frames(wand, 800)
    others = early.camera != rig.index("cam8")
    seven = WandObservations(early.frame[others], early.camera[others], early.uv[others])
    last = wanding_guidance(rig, seven, static).solution
    assert last is not None and "cam8" not in last.ids and len(last.ids) == 7
    pnp = []
    real = static_module.solve_static
    monkeypatch.setattr(static_module, "solve_static", lambda *args: pnp.append(1) or real(*args))
    joined = wanding_guidance(rig, wand, static, start=last)
    assert not pnp and not joined.document["solve"]["warm_start"]
    for a, b, c in zip(warm.document["cameras"], again.document["cameras"], joined.document["cameras"]):
        # the solves stop within wandcal.calib.solve.ba.STOP_SE (0.05) standard errors of the optimum, where the
        # noise scale, a median of the residuals, differs by a fraction of a percent
        assert a["center_std_mm"] == pytest.approx(b["center_std_mm"], rel=1e-2)
        assert c["center_std_mm"] == pytest.approx(b["center_std_mm"], rel=1e-2)


def test_bad_settings_and_a_rig_without_wand_are_refused(covered):
    rig, wand, _, _ = covered
    with pytest.raises(CalibrationError, match="target_std_mm"):
        GuidanceSettings(target_std_mm=0)
    with pytest.raises(CalibrationError, match="min_coverage"):
        GuidanceSettings(min_coverage=1.5)
    with pytest.raises(CalibrationError, match="wand.length_m"):
        wanding_guidance(Rig(rig.cameras, None), wand)


def test_a_points_only_rig_is_advised_in_its_points_not_the_wand():
    """Guidance on a rig without a wand judges each camera by its points and says so: a camera whose
    points are all in the left half of its image is told to show points elsewhere, never to wave a wand."""
    import dataclasses

    from wandcal.calib.rig import PointObservations
    from wandcal.calib.sim.scenes import pairwise_points
    from wandcal.calib.sim.simulate import simulate_capture

    sim = simulate_capture(4, 50, NOISE_PX, 0.0, False, 1)
    points = pairwise_points(sim, 400, np.random.default_rng(5), third=0.8)
    width = sim.rig.cameras[2].width
    keep = (points.camera != 2) | (points.uv[:, 0] < width / 2)  # cam2's points only in its left half
    points = PointObservations(points.frame[keep], points.camera[keep], points.uv[keep])
    rig = dataclasses.replace(sim.rig, wand_length=None)
    doc = wanding_guidance(rig, None, points=points).document
    advice = " ".join(doc["advice"])
    assert "wand" not in advice, doc["advice"]
    said = {c["id"]: c["advice"] for c in doc["cameras"]}
    assert said[rig.ids[2]] is not None and "show points" in said[rig.ids[2]] and "right" in said[rig.ids[2]], said
    silent = PointObservations(points.frame[points.camera != 3], points.camera[points.camera != 3],
                               points.uv[points.camera != 3])  # cam3 saw none of the points the others saw
    words = next(c["advice"] for c in wanding_guidance(rig, None, points=silent).document["cameras"] if c["id"] == rig.ids[3])
    assert "points" in words and "wand" not in words, words


def _triples(extra_of_last: int = 0):
    """Wand pairs of a sparse 12-camera rig: cameras 0-4 see the wand together, and each later camera
    c sees it in MIN_SOLVE_FRAMES frames (``extra_of_last`` more or fewer for the last), each with its
    own pair of cameras placed before it, so no two cameras share MIN_SOLVE_FRAMES frames but c's."""
    from wandcal.calib.observations import WandPairs
    from wandcal.calib.run.guidance import MIN_SOLVE_FRAMES

    rng = np.random.default_rng(7)
    rows = [(f, c) for f in range(2) for c in range(5)]  # 2 frames of the five first cameras
    frame = 2
    for c in range(5, 12):
        earlier = [(a, b) for a in range(c) for b in range(a + 1, c)]
        for i in rng.permutation(len(earlier))[:MIN_SOLVE_FRAMES + (extra_of_last if c == 11 else 0)]:
            rows += [(frame, c), (frame, earlier[i][0]), (frame, earlier[i][1])]
            frame += 1
    f, c = np.array(rows).T
    return WandPairs(f, c, np.zeros((len(f), 2, 2)), np.zeros((len(f), 2, 2)), np.arange(frame))


def test_a_sparse_rig_is_solved_by_its_group_links_not_its_pairs():
    # no pair of cameras shares MIN_SOLVE_FRAMES frames, yet each camera has that many frames two
    # cameras placed before it also see: the start's resection places it, so the solve takes it
    from wandcal.calib.run.guidance import MIN_SOLVE_FRAMES
    from wandcal.calib.run.guidance.update import _seen, _solve_set

    seed = np.arange(12) < 5  # the cameras that see the whole static object
    seen = _seen(12, _triples())
    off_diagonal = seen.linked[~np.eye(12, dtype=bool)]
    assert off_diagonal.max() < MIN_SOLVE_FRAMES  # the pairwise rule alone solves nothing
    assert _solve_set(seen).sum() < 2 and _solve_set(seen, seed, grow=False).sum() == 5
    assert _solve_set(seen, seed).all()
    # one frame short, the last camera stays out; a camera-frame recorded twice counts once
    short = _triples(extra_of_last=-1)
    twice = short.subset(np.concatenate([np.arange(len(short)), np.flatnonzero(short.camera == 11)]))
    for pairs in (short, twice):
        assert _solve_set(_seen(12, pairs), seed).tolist() == [True] * 11 + [False]
