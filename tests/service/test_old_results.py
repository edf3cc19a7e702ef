"""Results written before the typed result (tests/fixtures/results/) still read, report (with and
without their capture) and export in every format."""

import pytest

from tests.conftest import long_except
from tests.fixtures.results.cases import CAPTURES, CASES, Case, capture
from wandcal.calib.rig import WandObservations
from wandcal.capture.folder import read_capture, write_capture
from wandcal.capture.formats.export import export, formats
from wandcal.capture.result_file import read_result
from wandcal.service.report import INDEX, write_report


@pytest.mark.parametrize("case", long_except(CASES, {"solve_only", "points_only"}, ids=lambda c: c.name))
def test_an_old_result_reports_and_exports(case: Case, tmp_path):
    got = read_result(case.path)
    sim, rig, inputs = capture(CAPTURES.get(case.name, case.name))
    wand = inputs["wand"] if inputs["wand"] is not None else WandObservations([], [], [])
    write_capture(tmp_path / "capture", rig, wand, inputs["static"], inputs.get("points"))
    written = write_report(got, read_capture(tmp_path / "capture"), tmp_path / "report")
    page = (tmp_path / "report" / INDEX).read_text()
    assert written[0].name == INDEX and all(cam.id in page for cam in got.rig.cameras)
    assert len([p for p in written if p.name.startswith("camera-")]) == len(got.rig.cameras)  # residuals drawn
    write_report(got, None, tmp_path / "alone")
    assert "need the capture" in (tmp_path / "alone" / INDEX).read_text()
    for fmt in formats():
        assert export(got.doc, fmt, got.rig).strip(), fmt
