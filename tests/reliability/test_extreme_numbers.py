"""Extreme numbers where a rig enters (issue 20, class 6): intrinsics at 1e308, distortion past
any lens, a static object whose markers coincide or lie on a line, a wand of a kilometre. Each is
refused naming the field, or accepted and then calibrated or refused with a CalibrationError:
never a LinAlgError, an overflow or a traceback from deep in the linear algebra."""

from __future__ import annotations

import contextlib
import copy

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.reliability.fuzzing import TRIED
from wandcal.calib.errors import CalibrationError
from wandcal.calib.run.calibrate import calibrate
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.capture.folder import CaptureFormatError, rig_to_json
from wandcal.capture.rig_file import rig_from_json

EXTREME = st.one_of(st.sampled_from([1e308, -1e308, 1e-308, -1e-308, 0.0, 1e6 + 1, 1e12, -1e12, 5e-324, 1e-12]),
                    st.floats(-1e15, 1e15, allow_nan=False))


@pytest.fixture(scope="module")
def scene():
    sim = simulate_capture(cameras=3, frames=80, noise_px=0.3, seed=4)
    return sim, rig_to_json(sim.rig)


def _edits(doc: dict):
    """(field name as the message gives it, path) of every number a rig enters with."""
    for c, cam in enumerate(doc["cameras"]):
        for i in range(3):
            for j in range(3):
                yield "K", ("cameras", c, "K", i, j)
        for k in range(len(cam["dist"])):
            yield "dist", ("cameras", c, "dist", k)
    yield "wand.length_m", ("wand", "length_m")
    for m in range(len(doc.get("static_object", {}).get("markers_m", []))):
        for a in range(3):
            yield "markers_m", ("static_object", "markers_m", m, a)


def _set(doc, path, value):
    for key in path[:-1]:
        doc = doc[key]
    doc[path[-1]] = value


def _run(sim, doc, field):
    TRIED["rigs with extreme numbers"] += 1
    try:
        rig = rig_from_json(doc)
    except CaptureFormatError as exc:
        assert field in str(exc) or "camera 'cam" in str(exc), str(exc)
        return
    with contextlib.suppress(CalibrationError):
        calibrate(rig, sim.wand, sim.static)


def test_any_number_of_a_rig_at_an_extreme_is_refused_or_calibrated(scene):
    sim, base = scene
    edits = list(_edits(base))

    @settings(max_examples=60, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
    @given(edit=st.sampled_from(edits), value=EXTREME)
    def fuzz(edit, value):
        field, path = edit
        doc = copy.deepcopy(base)
        _set(doc, path, value)
        _run(sim, doc, field)

    fuzz()


@pytest.mark.parametrize("markers, words", [
    (lambda m: [m[0]] * len(m), "are 0 mm apart"),
    (lambda m: [m[0], [m[0][0] + 1e-4, m[0][1], m[0][2]], *m[2:]], "one marker"),
    (lambda m: [[0.1 * k, 0.0, 0.0] for k in range(len(m))], "on one line"),
    (lambda m: [[x * 1e6 for x in p] for p in m], "past"),
])
def test_static_objects_that_fix_nothing_are_refused_naming_the_markers(scene, markers, words):
    sim, base = scene
    doc = copy.deepcopy(base)
    doc["static_object"]["markers_m"] = markers(doc["static_object"]["markers_m"])
    with pytest.raises(CaptureFormatError, match="static_object.markers_m") as err:
        rig_from_json(doc)
    assert words in str(err.value)
