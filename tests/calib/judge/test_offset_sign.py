"""One sign for a camera's time offset everywhere (docs/result-format.md: positive is late, the
camera's frame k exposed at the others' frame k + offset): the judgement's timing fault and
``--sync auto``'s result and warning give the same number for the same simulated camera."""

from __future__ import annotations

import re

import numpy as np
import pytest

from wandcal.calib.run.calibrate import calibrate
from wandcal.calib.run.options import CalibrationOptions
from wandcal.calib.sim.simulate import simulate_capture

NOISE_PX = 0.3
# the judgement's offset is fitted on a solve the late camera bent: 0.03-0.06 frame off on this rig
# (a first-order velocity fit); --sync auto's within a hundredth (docs/sync.md)
TOLERANCE = 0.1


@pytest.mark.parametrize("offset", [-1.0, 0.6])
def test_the_judgement_and_sync_auto_give_one_offset_with_one_sign(offset):
    offsets = np.zeros(5)
    offsets[3] = offset  # camera 3's frame k shows the wand at the others' k + offset: late when positive
    sim = simulate_capture(5, 600, NOISE_PX, static=True, seed=8, offsets=offsets)
    cam = sim.rig.cameras[3].id
    judged = calibrate(sim.rig, sim.wand, sim.static).to_json()["verdict"]["faults"]
    timing = [f for f in judged if f["kind"] == "timing"]
    assert [f["camera"] for f in timing] == [cam], judged
    found = timing[0]["evidence"]["timing"]["offset_frames"]
    assert abs(found - offset) < TOLERANCE
    assert ("late" if offset > 0 else "early") in timing[0]["message"]

    synced = calibrate(sim.rig, sim.wand, sim.static, options=CalibrationOptions(sync="auto"))
    entry = next(c for c in synced.sync["cameras"] if c["id"] == cam)
    reference = next(c for c in synced.sync["cameras"] if c["id"] == synced.sync["reference"])
    assert abs(entry["offset_frames"] - reference["offset_frames"] - offset) < TOLERANCE
    warned = [w for w in synced.warnings if w.startswith(f"{cam} is out of time")]
    assert warned, synced.warnings
    said = float(re.search(r"frame k ([+-][0-9.]+)", warned[0]).group(1))  # "exposed at cam0's frame k +0.600"
    assert abs(said - offset) < TOLERANCE and np.sign(said) == np.sign(found)
