"""The fresh faults' own scoring (bench/fresh_faults.py): a pair of faults on two cameras is right
when each target is right by its own family's rule and no third camera is named; the draws are
the seed's alone. The table itself is ``python bench/bench_real_faults.py --fresh 101,102``."""

from __future__ import annotations

import numpy as np
import pytest

from bench import fresh_faults as ff
from bench import real_faults as rf

IDS = ["a", "b", "c", "d"]
CENTRES = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
CLEAN = rf.Clean(CENTRES, [1.0] * 4, "good")


def _pair() -> ff.FreshCase:
    noise = ff.FreshCase("s", "noise", "noise 2x b", 1, 2.0, "noise", row="two faults", draw=(1,))
    return ff.FreshCase("s", "focal", "focal +2% a + noise 2x b", 0, 1.02, "intrinsics", row="two faults",
                        draw=(1,), second=noise)


def _doc(faults: list[tuple[str, str]], limits: list[tuple[str, str]] = ()) -> dict:
    cameras = [{"geometry_std_mm": 0.5, "geometry_std_honest_mm": 5.0} for _ in IDS]
    return {"cameras": cameras, "verdict": {"level": "poor", "faults": [{"kind": k, "camera": c, "message": ""} for k, c in faults],
                                            "limits": [{"camera": c, "parameter": p} for c, p in limits], "at_limit": []}}


@pytest.mark.parametrize("faults, limits, outcome", [
    ([("intrinsics", "a"), ("noise", "b")], [], "right"),
    ([("noise", "b")], [("a", "focal length")], "limited"),  # a's focal length named as its limit, a within 3 honest sigma
    ([("noise", "b")], [("a", "k1")], "missed"),  # a limit, but not the fault's own intrinsic
    ([("intrinsics", "a"), ("noise", "b"), ("noise", "c")], [], "wrong camera"),
    ([("intrinsics", "a"), ("timing", "b")], [], "wrong kind"),
])
def test_pair_scored_by_each_targets_rule(faults, limits, outcome):
    out = ff.score_pair(_pair(), _doc(faults, limits), CENTRES, CLEAN, IDS)
    assert out.outcome == outcome
    assert out.right == (outcome in ("right", "limited"))


def test_draws_are_the_seeds_and_within_their_ranges():
    if not rf.available():
        pytest.skip(f"third-party data not found at {rf.SHARED_DATA}")
    session = rf.LOADERS["cpp"]()
    first, again, other = (ff.fresh_cases(session, seed) for seed in (101, 101, 102))
    assert [c.label for c in first] == [c.label for c in again] != [c.label for c in other]
    assert {c.row for c in first} == set(ff.FRESH_FAMILIES)  # the C++ sample's cameras can all be shifted in time
    for case in first:
        if case.family == "focal":
            assert 0.01 <= abs(case.size - 1) <= 0.04
        if case.second is not None:
            assert case.second.camera != case.camera
