"""The result's warnings: per-camera warnings that several cameras share fold into one line naming
them compactly, and each camera's entry keeps its own in full."""

from wandcal.calib.rig import LISTED_CAMERAS
from wandcal.calib.run.camera_figures import CameraFigures
from wandcal.calib.run.camera_reports import camera_warnings, fold_camera_warnings, summary_warnings, with_warnings

AMBIGUOUS = ": static-object pose is ambiguous (planar flip); placed from the wand"
CAPTURE_WIDE = "3674 camera-frames (2.0%) were gross outliers and were dropped"


def ring(n: int) -> list[str]:
    return [f"cam{k}" for k in range(1, n + 1)]


def test_a_warning_every_camera_of_64_gives_is_one_line():
    ids = ring(64)
    warnings = [CAPTURE_WIDE, *(i + AMBIGUOUS for i in ids)]
    assert fold_camera_warnings(warnings, ids) == [CAPTURE_WIDE, "all 64 cameras" + AMBIGUOUS]
    assert camera_warnings(warnings, ids) == [(i + AMBIGUOUS,) for i in ids]


def test_some_cameras_are_named_compactly_at_the_first_ones_place():
    ids = ring(64)
    some = ids[::4]  # 16 cameras, not in a run
    warnings = [some[0] + AMBIGUOUS, CAPTURE_WIDE, *(i + AMBIGUOUS for i in some[1:])]
    out = fold_camera_warnings(warnings, ids)
    assert out == [", ".join(some[:LISTED_CAMERAS]) + f" and {len(some) - LISTED_CAMERAS} more" + AMBIGUOUS, CAPTURE_WIDE]
    assert [i for i, w in zip(ids, camera_warnings(warnings, ids)) if w] == some  # the full list, machine-readable


def test_a_small_rig_and_warnings_that_differ_are_kept_as_they_are():
    ids = ring(4)
    warnings = ["cam2: placed from only 12 correspondences shared with cam1; check its residuals after refinement",
                "cam3 saw both wand ends in only 14 frames; wave the wand nearer cam3",
                "cam4 saw both wand ends in only 15 frames; wave the wand nearer cam4",
                "cam1: its frames are late against 'cam2'", "cam3: its frames are late against 'cam2'"]
    assert fold_camera_warnings(warnings, ids) == warnings  # each figure, or another camera named
    assert camera_warnings(warnings, ids)[1] == (warnings[0], *warnings[3:])  # cam2's own, and those quoting it
    assert fold_camera_warnings(["cam2" + AMBIGUOUS, "cam4" + AMBIGUOUS], ids) == ["cam2 and cam4" + AMBIGUOUS]


def test_the_summary_warnings_follow_what_came_before_them_and_all_fold_together():
    ids = ring(8)
    cameras = [CameraFigures(None, 0, 0, (), "wand") for _ in ids]
    summary = summary_warnings({"outliers": 0, "point_outliers": 3}, {"status": "converged"}, "ba", 1000)
    assert summary == ["3 point-track observations were gross outliers and were dropped"]
    figures, warnings = with_warnings(cameras, [i + AMBIGUOUS for i in ids] + summary, ids)
    assert warnings == ["all 8 cameras" + AMBIGUOUS, *summary]
    assert [f.warnings for f in figures] == [(i + AMBIGUOUS,) for i in ids]
