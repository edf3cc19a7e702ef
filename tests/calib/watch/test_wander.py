"""The pose's wander between the baseline's blocks (:func:`between_blocks`), on synthetic blocks of
whitened residuals (unit noise) whose pose is displaced by a known wander: the estimate is the injected
wander within its standard error, and blocks of a few residuals, whose pose they do not fix, add none."""

import numpy as np

from wandcal.calib.watch.sequential import PARAMS, between_blocks

SCALE = 1100.0  # pixels a radian: a camera's Jacobian entries


def _blocks(rng, sizes, lam):
    """(Ib, gb, per) of blocks of ``sizes`` residuals each, every block's pose displaced by a draw of
    the wander ``lam per^+`` (lam: the image shift of one residual, in units of the unit noise)."""
    Ib, gb = [], []
    per = 2 * SCALE ** 2 * np.eye(PARAMS)  # E[J^T J] of one residual of J ~ N(0, SCALE)
    for n in sizes:
        J = rng.normal(0.0, SCALE, (n, 2, PARAMS))
        wander = rng.normal(0.0, 1.0, PARAMS) * np.sqrt(lam / per[0, 0])
        r = J @ wander + rng.normal(0.0, 1.0, (n, 2))
        Ib.append(np.einsum("kpi,kpj->ij", J, J))
        gb.append(np.einsum("kpi,kp->i", J, r))
    return np.array(Ib), np.array(gb), per


def _standard_error(lam, sizes):
    """A moment estimate's standard error: each block's wander and noise, lam + 1 / n (the noise of a
    block of n residuals' pose, as one residual's image shift), over its 6 (B - 1) degrees of freedom."""
    return (lam + 1.0 / np.median(sizes)) * np.sqrt(2.0 / (PARAMS * (len(sizes) - 1)))


def test_the_wander_injected_is_measured():
    sizes = [50] * 100
    for lam, seed in ((0.05, 1), (0.5, 2)):
        est = between_blocks(*_blocks(np.random.default_rng(seed), sizes, lam))
        assert abs(est - lam) < 4 * _standard_error(lam, sizes)


def test_no_wander_is_none_and_a_few_residuals_add_none():
    """Blocks of two residuals (four scalars: a pose they do not fix, fitted exactly) beside blocks of 50:
    their least-norm poses are far off in what they do not fix, and must not read as wander."""
    sizes = [50] * 40 + [2] * 20
    Ib, gb, per = _blocks(np.random.default_rng(3), sizes, 0.0)
    assert between_blocks(Ib, gb, per) < 4 * _standard_error(0.0, sizes[:40])


def test_a_changes_own_statistic_is_what_the_test_scores_for_it():
    """A step of a known change after the baseline: the test's S at the step's window scatters about the
    change's own (noise-free) statistic plus its 6 degrees of freedom, within 4 of its standard deviations."""
    from wandcal.calib.watch.health import WINDOW_FRAMES
    from wandcal.calib.watch.sequential import BASELINE_WINDOWS, CameraTest

    rng = np.random.default_rng(4)
    change = np.array([8e-5, 0.0, 0.0, 0.0, 0.0, 0.0])  # 0.09 px at 1100 px: a statistic of ~450 over 10 windows
    test = CameraTest()
    for w in range(BASELINE_WINDOWS + 10):
        J = rng.normal(0.0, SCALE, (400, 2, PARAMS))
        r = J @ (change if w >= BASELINE_WINDOWS else 0 * change) + rng.normal(0.0, 0.3, (400, 2))
        H, g = np.einsum("kpi,kpj->ij", J, J), np.einsum("kpi,kp->i", J, r)
        test.add(g, H, float(((r - J @ np.linalg.solve(H, g)) ** 2).sum()), 400.0, w * WINDOW_FRAMES)
    own = test.statistic_of(change, BASELINE_WINDOWS)
    test.glr()
    base = test.baseline()
    assert base is not None
    scored = test._change(BASELINE_WINDOWS, len(test.g), base)
    assert abs(scored - (own + PARAMS)) < 4 * np.sqrt(2 * (PARAMS + 2 * own))
