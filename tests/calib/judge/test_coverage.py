import numpy as np

from wandcal.calib.judge.coverage import (
    GRID,
    coverage_advice,
    coverage_grid,
    coverage_grids,
    covered_fraction,
    empty_regions,
)

W, H = 1280, 1024


def test_uniform_samples_cover_the_whole_grid_and_need_no_advice():
    xy = np.random.default_rng(0).uniform([0, 0], [W, H], (2000, 2))
    counts = coverage_grid(xy, W, H)
    assert counts.shape == GRID and counts.sum() == 2000
    assert covered_fraction(counts) == 1.0
    assert coverage_advice(counts, "cam1", 0.5) is None


def test_points_outside_the_image_are_left_out_and_rows_run_top_down():
    counts = coverage_grid(np.array([[-1, 5], [W, 5], [10, 10], [10, H - 1]]), W, H)
    assert counts.sum() == 2 and counts[0, 0] == 1 and counts[-1, 0] == 1


def test_a_camera_that_saw_only_the_right_part_is_told_to_wave_on_the_left():
    xy = np.random.default_rng(1).uniform([0.5 * W, 0], [W, H], (800, 2))
    counts = coverage_grid(xy, W, H)
    assert covered_fraction(counts) == 0.5
    assert empty_regions(counts) == ["the left third"]
    advice = coverage_advice(counts, "cam2", 0.6)
    assert advice.startswith("cam2: no wand samples in the left third of its image")


def test_a_single_empty_corner_is_named():
    xy = np.random.default_rng(2).uniform([0, 0], [W, H], (4000, 2))
    # the 3 x 3 regions follow the grid's cells: on an 8 x 8 grid the top-left one is 3 x 3 cells
    xy = xy[~((xy[:, 0] < 3 * W / 8) & (xy[:, 1] < 3 * H / 8))]
    assert empty_regions(coverage_grid(xy, W, H)) == ["the top-left"]


def test_samples_confined_to_a_corner_or_a_third_are_named_where_they_are():
    rng = np.random.default_rng(3)
    corner = coverage_grid(rng.uniform([0, 0], [W / 3, H / 3], (500, 2)), W, H)
    assert coverage_advice(corner, "cam5", 0.5).startswith("cam5: wand samples only in the top-left of its image")
    strip = coverage_grid(rng.uniform([0, 0], [W, 0.3 * H], (500, 2)), W, H)
    assert "only in the top third" in coverage_advice(strip, "cam5", 0.5)
    two = coverage_grid(np.array([[10.0, 10.0], [W - 10.0, H - 10.0]]), W, H)
    assert "only in the top-left and the bottom-right of its image" in coverage_advice(two, "cam5", 0.5)


def test_every_cameras_grid_at_once_is_each_cameras_own():
    """coverage_grids (the verdict's one pass over every camera) counts what coverage_grid counts
    camera by camera: points on the image's edges, outside it, NaN, and a camera with no points."""
    rng = np.random.default_rng(31)
    sizes = [(1280, 1024), (640, 480), (2560, 1600), (800, 600)]
    camera = rng.integers(0, 3, 4000)  # the fourth camera has no points
    xy = rng.uniform(-50, 2700, (4000, 2))
    xy[:10] = [0, 0]
    xy[10:20] = np.nan
    xy[20:30, 0] = np.take([w for w, _ in sizes], camera[20:30])  # on the right edge: outside
    grids = coverage_grids(camera, xy, sizes)
    for c, (w, h) in enumerate(sizes):
        assert np.array_equal(grids[c], coverage_grid(xy[camera == c], w, h))
    assert grids[3].sum() == 0 and grids[:3].sum() > 1000
