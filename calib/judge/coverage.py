"""Where in each camera's image the wand was seen: a grid of counts, the share covered, and words.

A camera calibrated from wand samples in one corner of its image has a poorly determined pose
(and intrinsics, if refined); the report, the guidance and the verdict all look at this grid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

GRID = (8, 8)  # rows, columns: cells of 160 x 128 px on a 1280 x 1024 image, near Motive's painting
MIN_SAMPLES_PER_CELL = 1  # a cell with at least one wand end seen in it counts as covered
# the image split into thirds for the advice: (rows, columns) of the 3 x 3 regions, named as an operator sees them
_THIRDS = ("top", "middle", "bottom"), ("left", "centre", "right")
# with samples in this many of the 9 regions or fewer, the advice says where they are, not the
# (longer) list of where they are not
MAX_REGIONS_NAMED_AS_SEEN = 2


def coverage_grid(xy: np.ndarray, width: int, height: int, grid: tuple[int, int] = GRID) -> np.ndarray:
    """Counts of image points per grid cell.

    Args:
        xy: (M, 2) pixel positions (origin top-left, y down) of one camera's wand samples.
        width, height: the image size, pixels.
        grid: (rows, columns) of the grid.

    Returns:
        (rows, columns) int counts; row 0 is the top of the image. Points outside the image are
        left out.
    """
    rows, cols = grid
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    inside = (xy[:, 0] >= 0) & (xy[:, 0] < width) & (xy[:, 1] >= 0) & (xy[:, 1] < height)
    col = (xy[inside, 0] * cols / width).astype(int)
    row = (xy[inside, 1] * rows / height).astype(int)
    return np.bincount(row * cols + col, minlength=rows * cols).reshape(rows, cols)


def coverage_grids(camera: np.ndarray, xy: np.ndarray, sizes: list[tuple[int, int]],
                   grid: tuple[int, int] = GRID) -> np.ndarray:
    """(N, rows, columns) every camera's :func:`coverage_grid` in one pass (the same counts).

    Args:
        camera: (M,) camera index of each point; xy: (M, 2) pixel positions;
        sizes: (N,) each camera's (width, height), pixels.
    """
    rows, cols = grid
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    width, height = (np.array([s[k] for s in sizes], dtype=float)[camera] for k in (0, 1))
    inside = (xy[:, 0] >= 0) & (xy[:, 0] < width) & (xy[:, 1] >= 0) & (xy[:, 1] < height)
    col = (xy[inside, 0] * cols / width[inside]).astype(int)
    row = (xy[inside, 1] * rows / height[inside]).astype(int)
    return np.bincount((camera[inside] * rows + row) * cols + col, minlength=len(sizes) * rows * cols).reshape(
        len(sizes), rows, cols)


def covered_fraction(counts: np.ndarray) -> float:
    """Share of the grid's cells that hold at least :data:`MIN_SAMPLES_PER_CELL` samples."""
    return float(np.mean(counts >= MIN_SAMPLES_PER_CELL))


def _regions(counts: np.ndarray) -> np.ndarray:
    """(3, 3) bools: which regions of the image's 3 x 3 split (of whole grid cells) hold a sample."""
    covered = counts >= MIN_SAMPLES_PER_CELL
    rows, cols = covered.shape
    r_edges = np.linspace(0, rows, 4).round().astype(int)
    c_edges = np.linspace(0, cols, 4).round().astype(int)
    return np.array([[covered[r_edges[i]:r_edges[i + 1], c_edges[j]:c_edges[j + 1]].any() for j in range(3)]
                     for i in range(3)])


def _region_name(i: int, j: int) -> str:
    """"the top-left", "the top-centre", "the middle-left", "the centre", ..."""
    return "the centre" if (i, j) == (1, 1) else f"the {_THIRDS[0][i]}-{_THIRDS[1][j]}"


def empty_regions(counts: np.ndarray) -> list[str]:
    """The parts of the image without a sample, in words an operator can act on: whole thirds
    ("the left third") first, then single regions of the 3 x 3 split ("the top-left")."""
    region = _regions(counts)
    words, named = [], np.zeros((3, 3), bool)
    for j, side in ((0, "left"), (2, "right")):
        if not region[:, j].any():
            words.append(f"the {side} third")
            named[:, j] = True
    for i, side in ((0, "top"), (2, "bottom")):
        if not region[i, :].any():
            words.append(f"the {side} third")
            named[i, :] = True
    words += [_region_name(i, j) for i in range(3) for j in range(3) if not region[i, j] and not named[i, j]]
    return words


def _seen(region: np.ndarray) -> str | None:
    """Where the samples are, when that is shorter to say than where they are not: one third
    ("the top third") or up to MAX_REGIONS_NAMED_AS_SEEN regions; else None."""
    rows, cols = np.flatnonzero(region.any(1)), np.flatnonzero(region.any(0))
    if region.sum() > MAX_REGIONS_NAMED_AS_SEEN:
        if len(rows) == 1 and rows[0] != 1:
            return f"the {_THIRDS[0][rows[0]]} third"
        if len(cols) == 1 and cols[0] != 1:
            return f"the {_THIRDS[1][cols[0]]} third"
        return None
    return _listed([_region_name(i, j) for i in range(3) for j in range(3) if region[i, j]]) if region.any() else None


def _listed(words: list[str]) -> str:
    return ", ".join(words[:-1]) + (" and " if len(words) > 1 else "") + words[-1]


@dataclass(frozen=True)
class Sampling:
    """How the advice names what a camera samples its image with and what the operator does to
    sample more: a wand's camera-frames, or a points-only rig's points (docs/inputs.md)."""

    samples: str  # what the coverage counts, plural: "wand samples"
    act: str  # what gives more of them: "wave the wand"
    unit: str  # what a camera's count counts, plural: "frames"
    seen: str  # what a camera has not seen when its count is 0: "both wand ends"
    thing: str  # what is waited for: "the wand"
    it: str  # the pronoun of ``thing`` after "see": "it"


WAND = Sampling("wand samples", "wave the wand", "frames", "both wand ends", "the wand", "it")
# a points-only rig (no wand): its samples are the points two cameras or more saw, and more come from
# markers or features placed (or digitised) where those cameras see them
POINTS = Sampling("points", "show points", "points", "a point with another camera", "points", "them")


def coverage_advice(counts: np.ndarray, camera_id: str, min_fraction: float, words: Sampling = WAND) -> str | None:
    """Words for the operator when a camera's coverage is short of ``min_fraction``, else None,
    e.g. "cam2: no wand samples in the left third of its image; wave the wand there", or, when the
    samples sit in a few regions only, where they are: "cam5: wand samples only in the top-left of
    its image; wave the wand across the rest of its view". ``words``: what the samples are
    (:data:`WAND`, or :data:`POINTS` for a points-only rig)."""
    fraction = covered_fraction(counts)
    if fraction >= min_fraction:
        return None
    tally = f"({fraction:.0%} covered, goal {min_fraction:.0%})"
    seen = _seen(_regions(counts))
    if seen:
        return (f"{camera_id}: {words.samples} only in {seen} of its image {tally}; "
                f"{words.act} across the rest of its view")
    empty = empty_regions(counts)
    if not empty:
        return (f"{camera_id}: {words.samples} cover only {fraction:.0%} of its image (goal {min_fraction:.0%}); "
                f"{words.act} through the gaps of its view")
    return f"{camera_id}: no {words.samples} in {_listed(empty)} of its image {tally}; {words.act} there"
