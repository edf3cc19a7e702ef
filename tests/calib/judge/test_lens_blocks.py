"""The few-camera lens pattern judged against its own scatter over blocks of the capture
(calib/judge/faults/leave_one_out.py ``blocks_p_value``, decision 0069): its level on residuals
that run on along a track, and on a real session (MultiCamSelfCal) a clean subsample that named
``intrinsics Basler_21275577`` before, and a focal length 3% off still named on its camera."""

from __future__ import annotations

import numpy as np
import pytest

from bench import real_faults as rf
from wandcal.calib.judge.faults.leave_one_out import blocks_p_value, capture_blocks
from wandcal.calib.judge.faults.screen import _share, lens_columns

K = 400  # observations: 20 blocks of 20


def _design(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Six stand-in pose columns, the lens columns at K image points along a smooth track, and the blocks."""
    s = np.linspace(0, 1, K)
    xy = 0.4 * np.stack([np.sin(7 * s + rng.uniform(0, 6)), np.cos(5 * s + rng.uniform(0, 6))], axis=1)
    pose = rng.normal(size=(2 * K, 6))
    return pose, lens_columns(xy), capture_blocks(np.arange(K), np.ones(K, bool))


def test_its_level_holds_where_residuals_run_on_along_the_track():
    """Residuals that run on along the track (each observation's error the sum of the 5 white
    draws around it, a quarter of a block): the independent-rows F passes its own 5% point (F(4, 790):
    2.38) in most of 60 draws, the blocks' test at 0.05 keeps its level: 3 expected, 10 or
    more has probability 0.002 (binomial). The level holds while a block is at least twice the
    residuals' run (at 10 of 20 it rejected 12% of 200 draws at 0.05)."""
    rng = np.random.default_rng(5)
    rejected, f_rejected = 0, 0
    for _ in range(60):
        pose, lens, blocks = _design(rng)
        white = rng.normal(size=(K + 5, 2))
        y = np.stack([np.convolve(white[:, j], np.ones(5) / np.sqrt(5), "valid")[:K] for j in (0, 1)], axis=1).ravel()
        rejected += blocks_p_value(y, pose, lens, blocks) < 0.05
        f_rejected += _share(y, pose, lens)[2] > 2.38
    assert rejected < 10
    assert f_rejected >= 30  # the independent-rows F is not honest here, which is why the blocks judge


def test_a_lens_error_stands_out_of_independent_noise():
    """A focal-length error of 1% of the normalised coordinates against 0.1% noise: p far below 1e-4."""
    rng = np.random.default_rng(6)
    pose, lens, blocks = _design(rng)
    y = 0.01 * lens[:, 0] + 0.001 * rng.normal(size=2 * K)
    assert blocks_p_value(y, pose, lens, blocks) < 1e-8


@pytest.fixture(scope="module")
def svoboda():
    if not rf.available():
        pytest.skip(f"third-party data not found at {rf.SHARED_DATA}")
    return rf.LOADERS["svoboda"]()


def _named(session: rf.Session) -> tuple[str, list[tuple[str, str | None]]]:
    verdict = rf.calibrated(session).to_json()["verdict"]
    return verdict["level"], [(f["kind"], f["camera"]) for f in verdict["faults"]]


def test_a_clean_real_subsample_names_no_lens(svoboda):
    """MultiCamSelfCal's 40% subsample seed 111: Basler_21275577's real +1.3% focal pattern at
    F 59 (independent rows) was named "intrinsics"; against its blocks it is at p 0.01."""
    level, named = _named(rf.subsample(svoboda, 111, 0.4))
    assert named == []
    assert level != "poor"


def test_a_focal_length_3_percent_off_is_still_named_on_its_camera(svoboda):
    case = next(c for c in rf.cases(svoboda) if c.label == "focal -3% Basler_21275577")
    level, named = _named(rf.inject(svoboda, case, [0.0] * len(svoboda.rig.cameras)))
    assert named == [("intrinsics", "Basler_21275577")]
    assert level == "poor"
