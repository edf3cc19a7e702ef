"""The report's figures read cleanly: no two texts (labels, titles, ticks, legends) on one another,
and each caption names the marks its figure draws, on a simulated report and on real sessions."""

from __future__ import annotations

import re

import pytest
from matplotlib.collections import PathCollection
from matplotlib.colors import to_hex

from tests.capture.importers.test_import_easywand import USHICHKA_HEIGHT
from tests.conftest import SHARED_DATA, long_except
from tests.service.conftest import wandcal
from wandcal.capture.folder import read_capture
from wandcal.capture.result_file import read_result
from wandcal.service.report.analysis import analyse
from wandcal.service.report.figures import (
    AXIS_POINTS,
    OUTLIER_CROSSES,
    POINT_DOTS,
    WAND_DOTS,
    draw_camera,
    draw_rig,
    draw_wand,
)
from wandcal.service.report.labels import text_overlaps
from wandcal.service.report.page import camera_caption, rig_caption

# -- no text on text: every figure's labels, titles, ticks and legends apart ------------------
# easyWand sessions in ../shared/data: sparse, with axis points and background points; (file, import options)
REAL_SESSIONS = {
    "brown-1": (SHARED_DATA / "easywand_brown_windtunnel_4cam" / "calibration1" / "extrinsicCalib_20230228_easyWandData.mat",
                ()),
    "brown-2": (SHARED_DATA / "easywand_brown_windtunnel_4cam" / "calibration2" / "extrinsicCalib_20230228_easyWandData.mat",
                ()),
    # its cameras' height is not in the file (tests/capture/importers/test_import_easywand.py)
    "ushichka": (SHARED_DATA / "easywand_ushichka_thermal_3cam" / "round3_2018-07-28_easyWandData.mat",
                 ("--height", str(USHICHKA_HEIGHT))),
}


def assert_no_text_overlaps(data) -> None:
    """Every figure of a report, drawn: no two texts' boxes (from matplotlib's renderer) meet."""
    figures = {"rig": draw_rig(data)}
    if len(data.wand_frames):
        figures["wand"] = draw_wand(data)
    if data.has_capture:
        figures |= {cam.id: draw_camera(cam) for cam in data.cameras}
    for name, fig in figures.items():
        assert not text_overlaps(fig), f"{name}: {text_overlaps(fig)}"


def scatter_colours(fig) -> set[str]:
    """The colours of a figure's scattered marks (dots, crosses, diamonds)."""
    return {to_hex(c) for ax in fig.axes for col in ax.collections if isinstance(col, PathCollection)
            for c in col.get_facecolors()}


def assert_captions_match(data) -> None:
    """Each caption names the marks its figure draws, by the colours they are drawn in, and no other."""
    colours = scatter_colours(draw_rig(data))
    caption = rig_caption(data)
    for (colour, word), what in ((WAND_DOTS, "dots"), (POINT_DOTS, "dots"), (AXIS_POINTS, "diamonds")):
        assert (f"{word} {what}" in caption.lower()) == (colour in colours), (word, colour, caption)
    assert not re.search(r"(?<!blue-)grey dots", caption.lower()), caption
    for cam in data.cameras if data.has_capture else []:
        said = camera_caption(cam)
        drawn = scatter_colours(draw_camera(cam))
        assert ("crosses are outliers" in said) == (to_hex(OUTLIER_CROSSES[0]) in drawn), said
        assert (f"{POINT_DOTS[1]} dots" in said) == bool(len(cam.point_uv)), said


def test_no_text_overlaps_in_the_figures_of_a_simulated_report(sim_report):
    tmp, _, _ = sim_report
    data = analyse(read_result(tmp / "result.json"), read_capture(tmp / "capture"))
    assert_no_text_overlaps(data)
    assert_captions_match(data)


@pytest.mark.shared_data
@pytest.mark.parametrize("session", long_except(sorted(REAL_SESSIONS), {"brown-1"}))
def test_no_text_overlaps_in_the_figures_of_real_sessions(session, tmp_path):
    """The Brown wind tunnel's top view put camera ids and "origin" on one another."""
    mat, options = REAL_SESSIONS[session]
    if not mat.is_file():
        pytest.skip(f"third-party data not found at {mat.parent}")
    capture = tmp_path / "capture"
    run = wandcal("import", "easywand", str(mat), *options, "--out", str(capture))
    assert run.returncode == 0, run.stderr
    run = wandcal("calibrate", str(capture), "--out", str(tmp_path / "result.json"), "--quiet")
    assert run.returncode == 0, run.stderr
    data = analyse(read_result(tmp_path / "result.json"), read_capture(capture))
    assert data.axis or len(data.points)  # the crowded elements this test is about
    assert_no_text_overlaps(data)
    assert_captions_match(data)
