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
