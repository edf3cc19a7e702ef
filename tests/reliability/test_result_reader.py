"""One validated reader for ``wandcal-result/1`` (issue 20, class 1): a result edited by hand,
written by another version or damaged is either read, and then every consumer (each export
format, the report's reading of it, ``check``/``calibrate --from``'s camera entries) works on it,
or refused with a CalibrationError naming the field. Never a TypeError, ValueError,
AttributeError or KeyError from deep inside a consumer."""

from __future__ import annotations

import copy
import json

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.reliability.fuzzing import TRIED
from wandcal.calib.errors import CalibrationError
from wandcal.calib.run.calibrate import calibrate
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.capture.formats.export import FORMAT_NAMES, export
from wandcal.capture.result_file import read_result, result_from_json

# The fields the lead engineer adds in this round (issue 20): a reader must accept them present.
NEW_CAMERA_FIELDS = {"geometry_std_mm": 0.2, "geometry_rotation_std_deg": 0.01, "residual_mm": 0.3,
                     "outlier_share": 0.02, "verdict": {"level": "good", "reasons": ["a reason"], "advice": ["wave"]},
                     "warnings": ["cam1: static-object pose is ambiguous (planar flip); placed from the wand"]}
NEW_RESULT_FIELDS = {
    "world": {"frame": "static_object", "placement": {"origin_std_mm": 0.4, "axes_std_deg": 0.05}, "scale": "wand"},
    "verdict": {"level": "good", "reasons": [], "advice": "wave more", "placement": {"level": "good", "reasons": []},
                "faults": [{"kind": "bumped", "camera": "cam2", "message": "cam2 moved", "evidence": {"px": [1.5]}}]},
}

# JSON values of every type and of sizes a damaged file holds
VALUES = st.one_of(
    st.none(), st.booleans(), st.integers(min_value=-(10**30), max_value=10**30),
    st.floats(allow_nan=False, allow_infinity=False), st.sampled_from([1e308, -1e308, 5e-324, 0, -1, 10**400]),
    st.text(max_size=20), st.lists(st.floats(allow_nan=False, allow_infinity=False, width=32), max_size=4),
    st.dictionaries(st.text(max_size=5), st.integers(), max_size=3),
    st.lists(st.lists(st.integers(-5, 5), max_size=3), max_size=3),
)


def _paths(doc, prefix=()):
    """Every path to a value in ``doc`` (dict keys and list indices)."""
    yield prefix
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(doc, list) and len(doc) < 10:  # into cameras and short vectors, not every matrix cell
        for i, v in enumerate(doc):
            yield from _paths(v, (*prefix, i))


@pytest.fixture(scope="module")
def result_doc():
    sim = simulate_capture(3, 150, 0.3, 0.0, True, 5)
    doc = calibrate(sim.rig, sim.wand, sim.static).to_json()
    for cam in doc["cameras"]:
        cam.update(copy.deepcopy(NEW_CAMERA_FIELDS))
    doc.update(copy.deepcopy(NEW_RESULT_FIELDS))
    return doc


def consume(doc: dict, path) -> None:
    """Everything that reads a result: the file reader, every export format, and what the report,
    ``check`` and ``calibrate --from`` take from the read document."""
    result = read_result(path)
    for fmt in FORMAT_NAMES:
        export(result.doc, fmt, result.rig)
    for entry in result.doc["cameras"]:  # check: expected RMS; report: its per-camera table
        float(entry.get("reprojection_rms_px") or 0.0)
        for reason in (entry.get("verdict") or {}).get("reasons") or []:
            reason.upper()
    world = result.doc.get("world") or {}
    _ = world.get("scale") == "arbitrary", (world.get("placement") or {}).get("origin_std_mm")
    for fault in (result.doc.get("verdict") or {}).get("faults") or []:
        fault["kind"].upper()


def test_the_new_optional_fields_are_read(result_doc, tmp_path):
    path = tmp_path / "result.json"
    path.write_text(json.dumps(result_doc))
    consume(result_doc, path)
    assert result_from_json(result_doc).doc["verdict"]["faults"][0]["camera"] == "cam2"


def test_unknown_extra_fields_are_tolerated(result_doc, tmp_path):
    doc = copy.deepcopy(result_doc)
    doc["from_the_future"] = {"x": [1, 2]}
    doc["cameras"][0]["also_new"] = "yes"
    path = tmp_path / "result.json"
    path.write_text(json.dumps(doc))
    consume(doc, path)
    plain = tmp_path / "plain.json"
    plain.write_text(json.dumps(result_doc))
    # the known fields read as they do without the unknown ones
    assert read_result(path).result.to_json() == read_result(plain).result.to_json() == result_from_json(result_doc).result.to_json()


def test_any_field_of_any_type_is_read_or_refused_naming_it(result_doc, tmp_path_factory):
    paths = [p for p in _paths(result_doc) if p]
    file = tmp_path_factory.mktemp("result") / "result.json"

    @settings(max_examples=300, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
    @given(edits=st.lists(st.tuples(st.sampled_from(paths), VALUES | st.just("<delete>")), min_size=1, max_size=3))
    def fuzz(edits):
        doc = copy.deepcopy(result_doc)
        for path, value in edits:
            parent = doc
            try:
                for key in path[:-1]:
                    parent = parent[key]
                if value == "<delete>":
                    del parent[path[-1]]
                else:
                    parent[path[-1]] = value
            except (KeyError, IndexError, TypeError):
                continue  # an earlier edit replaced the path's parent
        try:
            text = json.dumps(doc)
        except (ValueError, OverflowError):
            return
        file.write_text(text)
        TRIED["result files: a field of another type or size"] += 1
        try:
            consume(doc, file)
        except CalibrationError as exc:  # the reader names the file; an exporter the camera it cannot write
            assert str(file) in str(exc) or "the result" in str(exc) or "camera '" in str(exc), str(exc)

    fuzz()
