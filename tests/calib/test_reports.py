"""The result's warnings: per-camera warnings that several cameras share fold into one line naming
them compactly, and each camera's entry keeps its own in full."""

from wandcal.calib.rig import LISTED_CAMERAS
from wandcal.calib.run.camera_reports import fold_camera_warnings, summary_warnings

AMBIGUOUS = ": static-object pose is ambiguous (planar flip); placed from the wand"
CAPTURE_WIDE = "3674 camera-frames (2.0%) were gross outliers and were dropped"


def ring(n: int) -> list[str]:
    return [f"cam{k}" for k in range(1, n + 1)]


def test_a_warning_every_camera_of_64_gives_is_one_line():
    ids = ring(64)
    cameras: list[dict] = [{} for _ in ids]
    out = fold_camera_warnings([CAPTURE_WIDE, *(i + AMBIGUOUS for i in ids)], ids, cameras)
    assert out == [CAPTURE_WIDE, "all 64 cameras" + AMBIGUOUS]
    assert [c["warnings"] for c in cameras] == [[i + AMBIGUOUS] for i in ids]


def test_some_cameras_are_named_compactly_at_the_first_ones_place():
    ids = ring(64)
    cameras: list[dict] = [{} for _ in ids]
    some = ids[::4]  # 16 cameras, not in a run
    warnings = [some[0] + AMBIGUOUS, CAPTURE_WIDE, *(i + AMBIGUOUS for i in some[1:])]
    out = fold_camera_warnings(warnings, ids, cameras)
    assert out == [", ".join(some[:LISTED_CAMERAS]) + f" and {len(some) - LISTED_CAMERAS} more" + AMBIGUOUS, CAPTURE_WIDE]
    assert [i for i, c in zip(ids, cameras) if c["warnings"]] == some  # the full list, machine-readable


def test_a_small_rig_and_warnings_that_differ_are_kept_as_they_are():
    ids = ring(4)
    cameras: list[dict] = [{} for _ in ids]
    warnings = ["cam2: placed from only 12 correspondences shared with cam1; check its residuals after refinement",
                "cam3 saw both wand ends in only 14 frames; wave the wand nearer cam3",
                "cam4 saw both wand ends in only 15 frames; wave the wand nearer cam4",
                "cam1: its frames are late against 'cam2'", "cam3: its frames are late against 'cam2'"]
    assert fold_camera_warnings(warnings, ids, cameras) == warnings  # each figure, or another camera named
    assert cameras[1]["warnings"] == [warnings[0], *warnings[3:]]  # cam2's own, and those quoting it
    assert fold_camera_warnings(["cam2" + AMBIGUOUS, "cam4" + AMBIGUOUS], ids, cameras) == ["cam2, cam4" + AMBIGUOUS]


def test_summary_warnings_fold_what_came_before_them():
    ids = ring(8)
    cameras: list[dict] = [{} for _ in ids]
    warnings = [i + AMBIGUOUS for i in ids]
    summary_warnings(warnings, {"outliers": 0}, {"status": "converged"}, "ba", 1000, (ids, cameras))
    assert warnings == ["all 8 cameras" + AMBIGUOUS]
    summary_warnings(more := [i + AMBIGUOUS for i in ids], {}, {"status": "converged"}, "ba", 1000)
    assert len(more) == len(ids)  # without the cameras nothing is folded
