"""Turn raw, unlabeled wand blobs into per-camera-frame pairs in normalised coordinates.

A camera-frame is usable when it shows exactly the wand's two blobs; anything else (one blob,
a third blob) is dropped here and counted, so the report can say so.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calib.errors import CalibrationError
from calib.geometry import undistort_points
from calib.rig import Rig, WandObservations


@dataclass(frozen=True, eq=False)
class WandPairs:
    """Camera-frames that show both wand ends, in an arbitrary end order.

    frame: (P,) index into ``frames``; camera: (P,) camera index; xy: (P, 2, 2) normalised
    coordinates of the two blobs; uv: (P, 2, 2) the raw pixels they came from; frames: (F,)
    the capture's frame numbers.
    """

    frame: np.ndarray
    camera: np.ndarray
    xy: np.ndarray
    uv: np.ndarray
    frames: np.ndarray
    dropped: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.frame)

    def subset(self, keep: np.ndarray) -> WandPairs:
        return WandPairs(self.frame[keep], self.camera[keep], self.xy[keep], self.uv[keep], self.frames, self.dropped)

    def swapped(self, swap: np.ndarray) -> WandPairs:
        """The same pairs with the end order of rows where ``swap`` (P,) bool is true reversed."""
        xy, uv = self.xy.copy(), self.uv.copy()
        xy[swap] = xy[swap, ::-1]
        uv[swap] = uv[swap, ::-1]
        return WandPairs(self.frame, self.camera, xy, uv, self.frames, self.dropped)


def wand_pairs(rig: Rig, wand: WandObservations) -> WandPairs:
    """Group blobs by camera-frame, keep the two-blob ones and undistort them.

    Args:
        rig: the rig (for intrinsics).
        wand: raw blobs.

    Returns:
        :class:`WandPairs`; ``dropped`` counts camera-frames with one blob (``"one_blob"``) or more
        than two (``"extra_blobs"``).
    """
    n_cams = len(rig.cameras)
    if len(wand) == 0:
        raise CalibrationError("wand.csv has no rows; record the wand being waved through the volume")
    bad = (wand.camera < 0) | (wand.camera >= n_cams)
    if bad.any():
        raise CalibrationError(f"wand observations refer to camera index {wand.camera[bad][0]}, outside the rig")
    if not np.all(np.isfinite(wand.uv)):
        k = int(np.flatnonzero(~np.isfinite(wand.uv).all(1))[0])
        raise CalibrationError(
            f"wand blob of camera {rig.cameras[wand.camera[k]].id!r} in frame {wand.frame[k]} is not finite; "
            "drop rows of undetected blobs instead of writing NaN"
        )
    key = wand.frame * n_cams + wand.camera
    order = np.argsort(key, kind="stable")
    key_sorted = key[order]
    uniq, start, count = np.unique(key_sorted, return_index=True, return_counts=True)
    two = count == 2
    dropped = {"one_blob": int((count == 1).sum()), "extra_blobs": int((count > 2).sum())}
    first = order[start[two]]
    second = order[start[two] + 1]
    cam = uniq[two] % n_cams
    frame_no = uniq[two] // n_cams
    uv = np.stack([wand.uv[first], wand.uv[second]], axis=1)
    xy = np.empty_like(uv)
    for c, camera in enumerate(rig.cameras):
        sel = cam == c
        xy[sel] = undistort_points(camera, uv[sel].reshape(-1, 2)).reshape(-1, 2, 2)
    frames, frame_idx = np.unique(frame_no, return_inverse=True)
    return WandPairs(frame=frame_idx, camera=cam, xy=xy, uv=uv, frames=frames, dropped=dropped)
