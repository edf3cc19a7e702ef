"""calib.watch.attribute: which of several raised cameras moved, by Vuong's test on batch means, and a
"one of" move as the report, the CLI's JSON and its message say it (decision 0089)."""

import numpy as np
from scipy.stats import t as student

from wandcal.calib.watch.attribute import BATCH_WINDOWS, LEVEL, LOOKS, critical_t, moved_pose, vuong
from wandcal.calib.watch.report import ONE_OF_ADVICE, CameraHealth, WatchReport
from wandcal.calib.watch.sequential import Alarm
from wandcal.capture.watch_report import report_json


def test_vuong_is_the_batch_means_mean_over_its_standard_error():
    """Windows' differences summed in batches of BATCH_WINDOWS: t = mean / (sd / sqrt(batches))."""
    rng = np.random.default_rng(3)
    diff = rng.normal(1.0, 2.0, size=8 * BATCH_WINDOWS)
    sums = diff.reshape(8, BATCH_WINDOWS).sum(1)
    t, batches = vuong(diff)
    assert batches == 8
    np.testing.assert_allclose(t, sums.mean() / (sums.std(ddof=1) / np.sqrt(8)), rtol=1e-12)
    assert vuong(diff[:BATCH_WINDOWS])[1] == 1  # one batch: no standard error, no test


def test_vuong_holds_its_level_when_the_hypotheses_fit_alike():
    """Equal fits (differences of mean 0, time-correlated within a batch's span): the leader's t passes
    the critical value for two candidates about LEVEL / LOOKS of the time (2000 draws: 3 sigma of binomial)."""
    rng = np.random.default_rng(5)
    batches, draws = 6, 2000
    crit = critical_t(batches, 1)
    hits = 0
    for _ in range(draws):
        per_batch = rng.normal(0.0, 1.0, size=batches)  # what a batch shares (the wander), and the frames' own noise
        diff = np.repeat(per_batch, BATCH_WINDOWS) + rng.normal(0.0, 0.3, size=batches * BATCH_WINDOWS)
        hits += vuong(diff)[0] > crit
    rate = LEVEL / LOOKS
    assert abs(hits / draws - rate) < 3 * np.sqrt(rate * (1 - rate) / draws) + 1e-3
    assert crit == student.ppf(1 - LEVEL / LOOKS, batches - 1)


def test_a_moved_pose_turns_the_camera_about_its_centre():
    R = np.stack([np.eye(3)] * 2)
    t = np.array([[0.0, 0.0, 2.0], [1.0, 0.0, 0.0]])
    R2, t2 = moved_pose(R, t, 1, np.r_[0.0, 0.0, 0.01, 0.0, 0.0, 0.0])
    np.testing.assert_array_equal(R2[0], R[0])
    np.testing.assert_allclose(-R2[1].T @ t2[1], -R[1].T @ t[1], atol=1e-15)  # the same centre
    assert np.isclose(np.degrees(np.arccos((np.trace(R2[1]) - 1) / 2)), np.degrees(0.01))


def test_a_one_of_move_is_reported_as_such():
    """Both candidates carry the alarm, status one_of, each naming the other; the JSON says what to do."""
    alarm = Alarm(0, 300, 340, 80.0, np.zeros(6), one_of=(1,))
    cams = [CameraHealth("camA", 0.3, 0.95, alarm, "knock", 300, one_of=["camB"]),
            CameraHealth("camB", 0.3, 0.95, Alarm(1, 300, 340, 30.0, np.zeros(6), one_of=(0,)), "knock", 300,
                         one_of=["camA"]),
            CameraHealth("camC", 0.3, 0.95)]
    doc = report_json(WatchReport(cams, frames=600))
    a, b, c = doc["cameras"]
    assert (a["status"], b["status"], c["status"]) == ("one_of", "one_of", "ok")
    assert a["one_of"] == ["camB"] and b["one_of"] == ["camA"] and "one_of" not in c
    assert a["message"].startswith("one of camA or camB moved at frame 300: ") and a["message"].endswith(ONE_OF_ADVICE)
    assert doc["moved"] == ["camA", "camB"]


def test_the_downdated_markers_are_the_refined_ones_within_a_hundredth_of_the_blob_noise():
    """The attribution's markers triangulated without each camera by one down-dated step (decision 0102)
    against the watch's refined ones: the same residuals kept, each marker within 1% of the injected 0.3 px
    blob noise once projected into the camera left out, and the windows' normal equations alike."""
    from wandcal.calib.sim.takes import simulate_take
    from wandcal.calib.watch.health import camera_windows
    from wandcal.calib.watch.match import match_frames
    from wandcal.calib.watch.take import pad_frames

    noise = 0.3
    sim = simulate_take(6, 60, markers=20, noise_px=noise, seed=4)
    R, t = sim.truth.R, sim.truth.t
    padded = pad_frames(sim.rig, sim.blobs)
    tracks = match_frames(sim.rig, R, t, padded)
    refined, downdated = (camera_windows(sim.rig, R, t, padded, tracks, keep_obs=True, method=m)
                          for m in ("refined", "downdated"))
    np.testing.assert_array_equal(refined.n, downdated.n)
    assert refined.obs is not None and downdated.obs is not None
    for c, ((_, X1, _), (_, X2, _)) in enumerate(zip(refined.obs, downdated.obs)):
        x1, x2 = X1 @ R[c].T + t[c], X2 @ R[c].T + t[c]
        moved = sim.rig.cameras[c].focal.mean() * np.hypot(*(x1[:, :2] / x1[:, 2:] - x2[:, :2] / x2[:, 2:]).T)
        assert len(moved) > 100 and moved.max() < 0.01 * noise
    np.testing.assert_allclose(downdated.sse.sum(0), refined.sse.sum(0), rtol=1e-3)
