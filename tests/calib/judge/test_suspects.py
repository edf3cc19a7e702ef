"""The suspect screen's share of gross outliers (wandcal.calib.run.rig_faults.suspects): a camera is
looked into for its outliers only beyond the binomial scatter of the median camera's share, its
camera-frames the trials (decision 0080)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from wandcal.calib.run.rig_faults import SUSPECT_OUTLIER_LEVEL, binomial_tail, camera_frames, suspects


def _exact_tail(k: int, n: int, p: float) -> float:
    return sum(math.comb(n, i) * p**i * (1 - p) ** (n - i) for i in range(k, n + 1))


@pytest.mark.parametrize(("k", "n", "p"), [(0, 10, 0.1), (1, 10, 0.1), (5, 43, 0.03), (8, 77, 0.028), (10, 10, 0.1),
                                           (30, 200, 0.05), (3, 3, 0.5)])
def test_the_binomial_tail_is_the_sum_of_its_terms(k, n, p):
    assert binomial_tail(k, n, p) == pytest.approx(_exact_tail(k, n, p), rel=1e-9, abs=1e-300)


def test_the_binomial_tail_of_an_impossible_or_certain_count():
    assert binomial_tail(11, 10, 0.3) == 0.0
    assert binomial_tail(2, 10, 0.0) == 0.0
    assert binomial_tail(0, 10, 0.0) == 1.0


def test_a_wand_frames_two_ends_are_one_camera_frame_and_a_track_observation_one():
    # camera 0: three wand frames (six ends), one an outlier by both ends; camera 1: two wand
    # frames and three track observations, one track observation an outlier
    res = SimpleNamespace(camera=np.array([0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 1, 1, 1]),
                          point=np.array([0, 1, 2, 3, 4, 5, 0, 1, 3, 4, -1, -2, -3]),
                          outlier=np.array([1, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0, 1, 0], bool))
    bad, total = camera_frames(res, 3)
    assert bad.tolist() == [1, 1, 0]
    assert total.tolist() == [3, 5, 0]


def _figures(shares: list[float], observations: list[int]) -> list[dict]:
    return [{"noise_px": 0.3, "outlier_share": s, "observations": n} for s, n in zip(shares, observations)]


def _rig(outlying: int, frames: int = 43, cameras: int = 128, rate: float = 0.03) -> tuple[list[dict], tuple]:
    """A rig whose cameras each hold ``frames`` camera-frames (two ends each), the median camera
    ``rate`` of them outliers, camera 0 ``outlying`` of them."""
    bad = np.full(cameras, round(rate * frames))
    bad[0] = outlying
    total = np.full(cameras, frames)
    return _figures(list(bad / total), list(2 * total)), (bad, total)


def test_a_share_within_the_binomial_scatter_of_the_median_cameras_makes_no_suspect():
    # 5 of 43 against 1 of 43 (2.3%) in the median camera: 11.6%, five times the median share, the
    # ratio's suspect; its binomial tail 0.02 is what one camera of 128 shows on noise alone
    figures, frames = _rig(5)
    tail = binomial_tail(5, 43, 1 / 43)
    assert tail > SUSPECT_OUTLIER_LEVEL / 128
    assert suspects(figures) == [0]  # the ratio alone
    assert suspects(figures, None, frames) == []


def test_a_share_beyond_the_scatter_is_a_suspect():
    # 12 of 43 (28%): a reflection in a quarter of its frames, its tail under 1e-9
    figures, frames = _rig(12)
    assert binomial_tail(12, 43, 1 / 43) < 1e-9
    assert suspects(figures, None, frames) == [0]


def test_a_noisy_camera_stays_a_suspect_whatever_its_outliers():
    figures, frames = _rig(1)
    figures[3] = figures[3] | {"noise_px": 0.3 * 2.0}
    assert suspects(figures, None, frames) == [3]


def test_the_lens_screens_fit_is_the_lens_fit_of_the_same_columns():
    """The screen's one-array fit (screen._screen_fit) against _lens_fit on _pose_columns and
    lens_columns: the same pattern, within the normal matrix's rounding, and a focal length 2% long
    found to within the noise's standard error (0.3 px at 1000 px over 1500 views: ~1e-4)."""
    from wandcal.calib.judge.faults.screen import _lens_fit, _pose_columns, _screen_fit
    from wandcal.calib.sim.simulate import look_at

    rng = np.random.default_rng(5)
    R, t = look_at(np.array([3.0, 0.5, 1.5]), np.zeros(3))
    X = rng.uniform(-0.8, 0.8, (1500, 3))
    Xc = X @ R.T + t
    xy = Xc[:, :2] / Xc[:, 2:]
    seen = xy * 1.02 + rng.normal(0, 3e-4, xy.shape)  # rig.json's focal length 2% short of the data's
    y = (xy - seen).ravel()
    fast, full = _screen_fit(y, R, t, X, seen), _lens_fit(y, _pose_columns(R, t, X), seen)
    for name in ("focal_error", "k1_error", "explained", "f_stat"):
        assert getattr(fast, name) == pytest.approx(getattr(full, name), rel=1e-9), name
    assert fast.focal_error == pytest.approx(-0.02 / 1.02, abs=1e-3)


def test_lens_patterned_suspects_beyond_the_cap_are_said_in_one_rig_wide_line():
    """The suspects left after MAX_SUSPECTS whose residuals hold a lens pattern join the first
    intrinsics fault's message and evidence (decision 0100); no fault is added or dropped."""
    from wandcal.calib.run.rig_faults import also_patterned

    faults = [{"kind": "noise", "camera": "cam0", "message": "m0", "evidence": {}},
              {"kind": "intrinsics", "camera": "cam3", "message": "m3", "evidence": {"focal_error": 0.02}}]
    out = also_patterned(faults, ["cam1", "cam5"])
    assert [f["camera"] for f in out] == ["cam0", "cam3"] and out[0] == faults[0]
    assert out[1]["evidence"] == {"focal_error": 0.02, "also_patterned": ["cam1", "cam5"]}
    assert "cam1 and cam5 show the same lens pattern" in out[1]["message"]
    assert "--refine-intrinsics focal,k1" in out[1]["message"]
    assert also_patterned(faults[:1], ["cam1"]) == faults[:1]  # no intrinsics fault: nothing to join
    assert also_patterned(faults, []) == faults
