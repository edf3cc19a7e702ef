import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("WANDCAL_SHARED_DATA", REPO.parent / "shared" / "data"))


@pytest.fixture
def shared_data():
    """The third-party data beside the repository (../shared/data); skips the test when absent.

    Some of it carries no licence: it is read in place and never copied into the repository.
    """
    if not SHARED_DATA.is_dir():
        pytest.skip(f"third-party data not found at {SHARED_DATA}")
    return SHARED_DATA


# The suite's longest tests, about longest first (CI's --durations, 2 workers): collected first, so
# xdist deals them out while both workers are fresh and the suite ends on short tests, not on one
# long test dealt last while the other worker sits idle (longest-first scheduling). A test missing
# here only runs in its place; one named here that no longer exists changes nothing.
LONGEST_FIRST = (
    "tests/calib/watch/test_watch.py::test_a_knock_is_named_with_its_frame",
    "tests/calib/solve/test_sync.py::test_predicted_standard_error_matches_the_spread_over_seeds",
    "tests/service/test_cli_watch.py",  # a module fixture: the whole file, made once
    "tests/calib/watch/test_sparse_takes.py::test_a_camera_knocked_too_far_to_follow_is_named_at_its_frame",
    "tests/calib/watch/test_watch.py::test_a_camera_moved_before_the_take_is_named",
    "tests/capture/test_capture_pty.py::test_pty_capture_detect_and_calibrate_recover_the_rig",
    "tests/service/test_page_watch.py::test_the_live_panel_shows_each_cameras_health_and_offers_the_resolve",
    "tests/capture/test_centroid_recording.py::test_the_points_level_written_as_it_goes_is_what_detection",
    "tests/calib/watch/test_watch.py::test_a_drift_is_told_from_a_knock",
    "tests/calib/watch/test_watch.py::test_a_clean_take_raises_no_alarm",
    "tests/calib/solve/test_uncertainty.py::test_predicted_uncertainty_matches_the_real_error_spread",
    "tests/service/test_live_take.py",  # likewise
    "tests/service/test_cli.py::test_calibrate_an_image_level_capture_detects_first",
    "tests/reliability/test_chaos.py::test_every_accepted_job_ends_exactly_once_under_chaos",
    "tests/service/test_watch_api.py",  # likewise
    "tests/calib/watch/test_sparse_takes.py::test_frame_numbers_with_gaps_are_windows_of_the_frames_held",
    "tests/service/test_api.py::test_a_finished_job_is_deleted_with_or_without_its_result",
    "tests/calib/solve/test_refinement.py::test_paper_stops_within_a_fraction_of_sigma_of_the_plain_rounds_fixed_point",
    "tests/test_readme_tour.py",  # the last file collected, and its two tests are long
    "tests/calib/solve/test_planar_wand.py::test_t_wand_labels_and_accuracy_against_the_bound_and_the_ends_alone",
    "tests/service/test_cli_check.py",  # module fixtures, as above
    "tests/service/test_cli_progress.py",
    "tests/calib/test_sparse_offsets.py",
    "tests/reliability/test_extreme_numbers.py",
    "tests/service/test_blobsets.py::test_a_rig_streamed_as_blob_sets_over_http_calibrates",
    "tests/service/test_folder_lock.py::test_a_second_serve_refuses_changes_nothing_and_a_killed_owner_is_recovered",
    "tests/reliability/test_faults.py",
)


def pytest_collection_modifyitems(config, items):
    """The :data:`LONGEST_FIRST` tests first, in its order; the rest after them in collection order
    (a stable sort: every xdist worker collects the same order, as it must)."""
    def rank(item) -> int:
        return next((i for i, name in enumerate(LONGEST_FIRST) if item.nodeid.startswith(name)), len(LONGEST_FIRST))

    items.sort(key=rank)


_WORKER_SECONDS: dict[str, float] = {}


def pytest_runtest_logreport(report):
    """Each xdist worker's seconds in tests (setup, call and teardown), for the balance line below."""
    node = getattr(report, "node", None)
    if node is not None:
        worker = node.gateway.id
        _WORKER_SECONDS[worker] = _WORKER_SECONDS.get(worker, 0.0) + report.duration


def pytest_terminal_summary(terminalreporter):
    if _WORKER_SECONDS:
        terminalreporter.write_line("seconds in tests by xdist worker: " + ", ".join(
            f"{w} {s:.0f}" for w, s in sorted(_WORKER_SECONDS.items())))
