"""A take: every bright blob of every camera, frame by frame, with no labels (``take.csv``,
docs/capture-format.md), and the padded per-frame layout the matcher works on."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.geometry import undistort_by_camera
from wandcal.calib.rig import Rig, WandObservations

FRAME_GAP_PX = 1e7  # frames side by side in one k-d tree, this far apart: past any image's size


@dataclass(frozen=True, eq=False)
class TakeBlobs(WandObservations):
    """Unlabelled blobs of a take: any number a camera-frame, of any markers (the fields and their
    checks are :class:`wandcal.calib.rig.WandObservations`': frame (B,), camera (B,) index into
    ``Rig.cameras``, uv (B, 2) raw pixels, origin top-left, y down)."""

    def frames(self, first: int, stop: int) -> TakeBlobs:
        """The blobs of frames ``first <= frame < stop``."""
        keep = (self.frame >= first) & (self.frame < stop)
        return TakeBlobs(self.frame[keep], self.camera[keep], self.uv[keep])


def check_take(rig: Rig, blobs: TakeBlobs, source: str = "take") -> None:
    """Refuse a take that cannot be watched, saying what to record instead: no blobs, or blobs in
    fewer than three cameras (a marker is matched in two and verified in a third)."""
    if not len(blobs):
        raise CalibrationError(f"{source}: holds no blobs; record a take in which the cameras see markers")
    seen = np.unique(blobs.camera)
    if len(seen) < 3:
        names = ", ".join(rig.ids[c] for c in seen)
        raise CalibrationError(f"{source}: blobs in only {len(seen)} camera(s) ({names}); a marker is matched in two "
                               "cameras and verified in a third: record a take that at least three cameras see")


@dataclass(frozen=True, eq=False)
class PaddedFrames:
    """A batch of frames' blobs, padded per camera.

    frames: (F,) frame numbers; xy: (F, C, K, 2) normalised undistorted coordinates, NaN where
    there is no blob; row: (F, C, K) each slot's row in the take's blobs, -1 where empty.
    """

    frames: np.ndarray
    xy: np.ndarray
    row: np.ndarray

    def xy_of(self, rows: np.ndarray) -> np.ndarray:
        """(..., 2) the normalised coordinates of blob ``rows`` (any shape) of this batch."""
        first, table = self._by_row
        return table[np.asarray(rows) - first]

    def blob_tree(self, c: int, focal: float):
        """(frame index (B,), slot (B,), a k-d tree of (x, y) in pixels and the frame index times
        :data:`FRAME_GAP_PX`) of camera c's blobs, built once a camera (focal:
        its focal length, pixels)."""
        key = (c, float(focal))
        if key not in self._trees:
            from scipy.spatial import cKDTree

            fi, k = np.nonzero(np.isfinite(self.xy[:, c, :, 0]))
            tree = cKDTree(np.column_stack([self.xy[fi, c, k] * focal, fi * FRAME_GAP_PX])) if len(fi) else None
            self._trees[key] = (fi, k, tree)
        return self._trees[key]

    @cached_property
    def _trees(self) -> dict:
        return {}

    @cached_property
    def _by_row(self) -> tuple[int, np.ndarray]:
        valid = self.row >= 0
        first = int(self.row[valid].min()) if valid.any() else 0
        table = np.full((int(self.row.max()) + 1 - first if valid.any() else 1, 2), np.nan)
        table[self.row[valid] - first] = self.xy[valid]
        return first, table


def pad_frames(rig: Rig, blobs: TakeBlobs, rows: np.ndarray | None = None) -> PaddedFrames:
    """The blobs (all, or ``rows`` of them) as :class:`PaddedFrames`, undistorted once."""
    rows = np.arange(len(blobs)) if rows is None else rows
    frame, camera = blobs.frame[rows], blobs.camera[rows]
    xy = undistort_by_camera(rig.cameras, camera, blobs.uv[rows])
    frames, f_idx = np.unique(frame, return_inverse=True)
    n_cam = len(rig.cameras)
    key = f_idx * n_cam + camera
    order = np.argsort(key, kind="stable")
    key_sorted = key[order]
    starts = np.searchsorted(key_sorted, key_sorted, side="left")
    slot = np.empty(len(rows), dtype=np.int64)
    slot[order] = np.arange(len(rows)) - starts
    width = int(slot.max()) + 1 if len(rows) else 1
    out_xy = np.full((len(frames), n_cam, width, 2), np.nan)
    out_row = np.full((len(frames), n_cam, width), -1, dtype=np.int64)
    out_xy[f_idx, camera, slot] = xy
    out_row[f_idx, camera, slot] = rows
    return PaddedFrames(frames, out_xy, out_row)
