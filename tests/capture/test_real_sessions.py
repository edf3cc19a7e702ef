"""Real sessions of other tools, imported and calibrated end to end, against their published
figures (../shared/data, read in place: some carry no licence). Our figures are printed beside
theirs (run with -s); the same table is in docs/benchmarks.md (bench/bench_real.py)."""

import numpy as np
import pytest

from bench import real_sessions as rs
from wandcal.calib.geometry import kabsch
from wandcal.calib.run.options import CalibrationOptions

pytestmark = pytest.mark.shared_data


@pytest.fixture(autouse=True)
def _data():
    if not (rs.SHARED_DATA / rs.BROWN).is_dir():
        pytest.skip(f"third-party data not found at {rs.SHARED_DATA}")


def _std_of_std(n: int) -> float:
    """Relative standard error of a standard deviation estimated from n Gaussian samples."""
    return 1 / np.sqrt(2 * (n - 1))


# Brown cal2: ours 0.298% (ba) / 0.285% (lp) against easyWand's 0.245%; why, and what was tried,
# in docs/decisions/0020-brown-wand-score.md and 0023-brown-noise-floor.md (a noise variance per
# point track, time offsets; the ends' own noise alone would give ~0.35% with exact cameras).
# Strict: the mark must go when the goal is met.
_SHORT_OF_EASYWAND = pytest.mark.xfail(strict=True, reason="cal2's background points hold the cameras where the "
                                       "wand lengths spread more than easyWand's (decisions 0020, 0023)")


@pytest.mark.parametrize("session", [1, 2])
@pytest.mark.parametrize("method", ["ba", "lp"])
def test_brown_wind_tunnel_calibrates_as_easywand_did(session, method):
    """The sparse Brown sessions (wand frames mostly in 2-3 of 4 cameras, background points)."""
    got = rs.brown(session, method)
    score, n = got["wand_score_on_easywand_frames"]
    print(f"\nBrown cal{session} {method}: wand score {score:.3f}% on easyWand's {n} frames "
          f"({got['wand_score_percent']:.3f}% on our {got['wand_frames']}), easyWand {got['easywand_wand_score_percent']:.3f}% "
          f"on {got['easywand_frames']}; centres vs easyWand {np.round(got['centre_diff_mm'], 1)} mm")
    assert n == got["easywand_frames"]
    # a score measured on ~25 frames has a sampling error of 1/sqrt(2(n-1)) ~ 15% of itself:
    # ours must not be worse than easyWand's by more than two of those
    assert score <= got["easywand_wand_score_percent"] * (1 + 2 * _std_of_std(n))
    assert np.sqrt(np.mean(got["centre_diff_mm"] ** 2)) <= 10.0  # the goal: within 10 mm RMS


@pytest.mark.parametrize("session, method", [(1, "ba"), (1, "lp"), pytest.param(2, "ba", marks=_SHORT_OF_EASYWAND),
                                             pytest.param(2, "lp", marks=_SHORT_OF_EASYWAND)])
def test_brown_wand_score_at_most_easywands(session, method):
    """Issue 23's goal, the published figure itself the tolerance: easyWand's ``wandScore`` (the
    sample std of its triangulated wand lengths over their mean, on its frames)."""
    got = rs.brown(session, method)
    score, n = got["wand_score_on_easywand_frames"]
    print(f"\nBrown cal{session} {method}: ours {score:.3f}%, easyWand {got['easywand_wand_score_percent']:.3f}% (n={n})")
    assert score <= got["easywand_wand_score_percent"]


@pytest.mark.parametrize("session", [1, 2])
def test_our_wand_score_is_easywands(session):
    """easyWand's own cameras scored our way reproduce its published wandScore: the score the
    goal above holds ours to is the one easyWand computes (sample std over mean, its frames).
    The cameras are its DLT's decomposition (K with fx != fy, printed to 1e-6) under our lens
    model: measured 0.532% against 0.558% (cal1) and 0.2452% against 0.2445% (cal2). The two
    differ only by that decomposition and its printed precision, so a tenth of the published
    figure is the tolerance, well under the 14-15% sampling error of a std from 24-28 frames
    that separates two calibrations."""
    own, n = rs.easywand_cameras_score(session)
    published = rs.brown(session)["easywand_wand_score_percent"]
    print(f"\nBrown cal{session}: easyWand's own cameras scored our way {own:.4f}% (n={n}), published {published:.4f}%")
    assert abs(own - published) <= 0.1 * published


MONTE_CARLO_DRAWS = 100  # x 24 frames: the std of the simulated lengths to ~1.5% of itself


def test_score_per_pixel_is_the_spread_simulated_noise_gives():
    """Decision 0023's noise floor, checked by simulation: independent 1 px per axis on every
    end's views of easyWand's cal2 frames, cameras held at ba's, spreads the re-triangulated
    lengths as ``score_per_pixel`` predicts to first order. The tolerance is three standard
    errors of a std from the draws x frames samples (the first-order error at 1 px over a
    ~1700 px focal length is far smaller)."""
    result = rs.brown(2)["result"]
    predicted = rs.score_per_pixel(2, result)
    R, t, cameras = result.R, result.t, result.rig.cameras
    rng = np.random.default_rng(23)
    deviations, lengths = [], []
    for ends in rs.scored_ends(cameras, rs.SHARED_DATA / rs.BROWN / "calibration2"):
        length = rs.wand_length(R, t, ends)
        lengths.append(length)
        for _ in range(MONTE_CARLO_DRAWS):
            X = []
            for cams, xy in ends:
                focal = np.array([cameras[c].focal for c in cams])
                X.append(rs.triangulated_end(R, t, cams, xy + rng.normal(0.0, 1.0, xy.shape) / focal))
            deviations.append(np.linalg.norm(X[1] - X[0]) - length)
    simulated = 100 * np.sqrt(np.mean(np.square(deviations))) / np.mean(lengths)
    print(f"\nBrown cal2: score per px of end noise {predicted:.4f}% (first order), {simulated:.4f}% (simulated)")
    assert abs(simulated - predicted) <= 3 * _std_of_std(len(deviations)) * predicted


def test_brown_session_1_refines_rough_focal_lengths():
    """Start from the profile's focal lengths (up to 2.7% off easyWand's optimised ones)."""
    got = rs.brown(1, "ba", intrinsics="profile", options=CalibrationOptions(refine_intrinsics=("focal",)))
    score, n = got["wand_score_on_easywand_frames"]
    rel = np.array(got["focal_px"]) / got["easywand_focal_px"] - 1
    print(f"\nBrown cal1 from profile focals: refined {np.round(got['focal_px'], 1)} vs easyWand "
          f"{got['easywand_focal_px']} ({np.round(100 * rel, 2)}%); wand score {score:.3f}% vs {got['easywand_wand_score_percent']:.3f}%")
    assert np.all(np.abs(rel) <= 0.01)  # the goal
    assert score <= got["easywand_wand_score_percent"]
    for cam in got["result"].cameras:
        assert cam.intrinsics.focal_std_px < 0.005 * cam.intrinsics.focal_px


def test_brown_sessions_show_the_rig_moved_between_the_two_dates():
    """Each session's centres mapped onto easyWand's frame of that session; then how far each
    camera moved between the dates, ours beside easyWand's."""
    moved, theirs = [], []
    for got in (rs.brown(1, "ba"), rs.brown(2, "ba")):
        C, ref = got["result"].centers, got["reference_centres"]
        Ra, ta, s = kabsch(C, ref, scale=True)
        moved.append(s * C @ Ra.T + ta)
        theirs.append(ref)
    ours_mm = np.linalg.norm(moved[1] - moved[0], axis=1) * 1000
    theirs_mm = np.linalg.norm(theirs[1] - theirs[0], axis=1) * 1000
    print(f"\nBrown cal1 -> cal2 camera centres moved {np.round(ours_mm)} mm; easyWand {np.round(theirs_mm)} mm")
    # each session's centres are held to 10 mm RMS of easyWand's, so the moves to sqrt(2) x that
    assert np.all(np.abs(ours_mm - theirs_mm) <= np.sqrt(2) * 10.0)
    assert theirs_mm.max() > 30.0  # SOURCE.md: the rig really changed (3-10 cm)


def test_ushichka_through_its_mat_file():
    """The existing acceptance figures (tests/capture/importers/test_easywand_real.py) hold through the import."""
    got = rs.ushichka()
    print(f"\nushichka: wand {got['wand_mean_m'] * 1000:.1f} +- {got['wand_std_m'] * 1000:.2f} mm "
          f"({got['wand_score_percent']:.2f}%, easyWand {got['easywand_wand_score_percent']:.2f}%); per-axis rms "
          f"{np.round(got['rms_per_axis_px'], 3)} px, easyWand DLT {np.round(got['easywand_dlt_rmse_px'], 3)}")
    assert got["wand_score_percent"] < 1.6 * got["easywand_wand_score_percent"]
    assert abs(got["wand_mean_m"] - 0.66) < 0.005 * 0.66
    for rms, published in zip(got["rms_per_axis_px"], got["easywand_dlt_rmse_px"]):
        assert rms < 2 * published


def test_multicamselfcal_tracks_calibrate_up_to_scale():
    got = rs.svoboda()
    result = got["result"]
    print(f"\nMultiCamSelfCal caldata20130726: mean 2D error {got['mean_error_px']:.3f} px over {got['inliers']} of "
          f"{got['observations']} observations (toolbox: 0.62 px on its sister set); centres vs "
          f"original_cam_centers.dat {np.round(got['centre_diff_mm'], 1)} mm after similarity alignment")
    assert result.world.scale == "arbitrary" and result.wand_report is None
    assert got["mean_error_px"] <= got["published_mean_error_px"]  # the goal
    # the earlier calibration of the same rig (Align-Existing); a gross error would be a
    # sizeable fraction of the 0.8 m rig
    assert got["centre_diff_mm"].max() < 0.1 * got["rig_extent_mm"]
