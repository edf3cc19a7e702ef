"""From per-frame blob lists to a camera's wand observations and static-object markers.

A wand frame shows exactly the two wand markers; a static recording shows the static object's
markers still, averaged over time. Blobs that stay put while the wand moves (an L-frame left on the
floor, a lamp) are still markers and are removed before the wand's two blobs are taken.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from wandcal.calib.detect.measure import Blobs
from wandcal.calib.errors import CalibrationError

# Blobs of one marker in different frames of a still object scatter by the centroid noise
# (~0.01-0.1 px); 2 px is far above that and below the spacing of two distinct markers, which
# would merge into one blob before they came within a marker diameter (> 2 px) of each other.
STILL_RADIUS_PX = 2.0

# A still marker must be seen in this fraction of a static recording; the person placing the
# L-frame or a passing occlusion may hide a marker in a few frames.
STATIC_MIN_PRESENCE = 0.8

# During wanding, a blob position occupied in this fraction of the frames is a still marker (the
# L-frame left on the floor, a lamp). The moving wand never stays this long at one spot unless it
# is held still for half the recording; the waver's body hiding the L-frame costs some presence.
WAND_STILL_PRESENCE = 0.5

# Too few frames give no basis for telling still blobs from a wand that rests for a moment.
WAND_STILL_MIN_FRAMES = 20

WAND_MARKERS = 2


def _frame_uv(item, index: int) -> np.ndarray:
    uv = item.uv if isinstance(item, Blobs) else np.asarray(item, dtype=np.float64)
    if uv.size == 0:
        return np.zeros((0, 2))
    if uv.ndim != 2 or uv.shape[1] != 2:
        raise CalibrationError(
            f"frame {index}: expected Blobs or a (K, 2) array of blob centroids, got shape {uv.shape}"
        )
    return uv


def _cluster_positions(frames: list[np.ndarray], radius_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Cluster blob positions across frames.

    Each blob joins the nearest cluster whose running mean is within ``radius_px``; a blob
    farther from every cluster opens a new one. A frame adds at most one blob per cluster.

    Returns:
        centres (C, 2) mean positions, and frames (C,) int how many frames each cluster was seen in.
    """
    sums = np.zeros((0, 2))
    counts = np.zeros(0, dtype=np.int64)
    for uv in frames:
        if len(uv) == 0:
            continue
        taken = np.zeros(len(counts), dtype=bool)
        new = []
        centres = sums / np.maximum(counts, 1)[:, None]
        for p in uv:
            if len(centres):
                d = np.hypot(*(centres - p).T)
                d[taken] = np.inf
                j = int(np.argmin(d))
                if d[j] <= radius_px:
                    sums[j] += p
                    counts[j] += 1
                    taken[j] = True
                    continue
            new.append(p)
        if new:
            sums = np.vstack((sums, new))
            counts = np.concatenate((counts, np.ones(len(new), dtype=np.int64)))
    return sums / np.maximum(counts, 1)[:, None], counts


def static_markers_from_frames(
    blobs_by_frame: Sequence[Blobs | np.ndarray],
    radius_px: float = STILL_RADIUS_PX,
    min_presence: float = STATIC_MIN_PRESENCE,
) -> np.ndarray:
    """The still markers of a short recording of the static object alone, averaged over time.

    Blobs are clustered across frames (within ``radius_px`` of a cluster's mean); clusters seen
    in at least ``min_presence`` of the frames are markers and their mean position is returned.
    Averaging N frames shrinks the centroid noise by sqrt(N).

    Args:
        blobs_by_frame: one camera's frames, each a :class:`Blobs` or a (K, 2) array of uv.
        radius_px: largest distance of one marker's blob from its mean, pixels.
        min_presence: fraction of frames a marker must appear in, (0, 1].

    Returns:
        (M, 2) float64 marker positions in pixels, sorted by row then column.
    """
    if not 0.0 < min_presence <= 1.0:
        raise CalibrationError(f"min_presence must lie in (0, 1], got {min_presence!r}")
    if radius_px <= 0:
        raise CalibrationError(f"radius_px must be positive, got {radius_px!r}")
    frames = [_frame_uv(item, i) for i, item in enumerate(blobs_by_frame)]
    if not frames:
        return np.zeros((0, 2))
    centres, counts = _cluster_positions(frames, radius_px)
    markers = centres[counts >= min_presence * len(frames)]
    return markers[np.lexsort((markers[:, 0], markers[:, 1]))] if len(markers) else np.zeros((0, 2))


@dataclass(frozen=True, eq=False)
class WandFrames:
    """The frames of one camera that show the wand's two markers, and why the others were dropped.

    Args:
        frame: (N,) int64 indices (into the input sequence) of the kept frames.
        uv: (N, 2, 2) float64 the two wand blobs of each kept frame, pixels (order within a frame
            is the detector's: by row, then column).
        too_few: frames dropped with 0 or 1 wand blob (wand out of view or occluded).
        too_many: frames dropped with more than 2 blobs left (reflections, another marker).
        still_uv: (M, 2) still-marker positions whose blobs were removed first.
        still_removed: total blobs removed as still markers, over all frames.
        total: number of input frames.
    """

    frame: np.ndarray
    uv: np.ndarray
    too_few: int
    too_many: int
    still_uv: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    still_removed: int = 0
    total: int = 0

    def __len__(self) -> int:
        return len(self.frame)

    def summary(self) -> str:
        """One sentence for a report."""
        text = (
            f"kept {len(self)} of {self.total} frames with exactly {WAND_MARKERS} wand blobs; "
            f"dropped {self.too_few} with 0 or 1 blob and {self.too_many} with more than {WAND_MARKERS}"
        )
        if len(self.still_uv):
            text += f"; ignored {len(self.still_uv)} still marker(s) ({self.still_removed} blobs)"
        return text


def wand_frames(
    blobs_by_frame: Sequence[Blobs | np.ndarray],
    static_uv: np.ndarray | None = None,
    *,
    radius_px: float = STILL_RADIUS_PX,
    auto_still: bool = True,
) -> WandFrames:
    """Keep the frames of one camera that show exactly the two wand markers.

    Blobs within ``radius_px`` of a still marker are removed first, so an L-frame left in view
    while wanding is not taken for the wand. The still markers are ``static_uv`` when given;
    otherwise (``auto_still``) they are found in the recording itself as blob positions occupied
    in at least half the frames, which the moving wand never is.

    Args:
        blobs_by_frame: one camera's frames in time order, each a :class:`Blobs` or (K, 2) uv.
        static_uv: (M, 2) still-marker positions in pixels (e.g. from
            :func:`static_markers_from_frames`), or None.
        radius_px: a blob this close to a still marker is that marker, pixels.
        auto_still: with ``static_uv=None``, look for still markers in the recording (needs at
            least 20 frames); pass an empty (0, 2) array to remove nothing.

    Returns:
        :class:`WandFrames` with the kept frames' (2, 2) uv and counts of dropped frames by reason.
    """
    frames = [_frame_uv(item, i) for i, item in enumerate(blobs_by_frame)]
    if static_uv is None:
        if auto_still and len(frames) >= WAND_STILL_MIN_FRAMES:
            static_uv = static_markers_from_frames(frames, radius_px, WAND_STILL_PRESENCE)
        else:
            static_uv = np.zeros((0, 2))
    still = np.asarray(static_uv, dtype=np.float64).reshape(-1, 2)
    kept, kept_uv = [], []
    too_few = too_many = removed = 0
    for i, frame_uv in enumerate(frames):
        uv = frame_uv
        if len(still) and len(uv):
            near = (np.hypot(*(uv[:, None, :] - still[None, :, :]).transpose(2, 0, 1)) <= radius_px).any(axis=1)
            removed += int(near.sum())
            uv = uv[~near]
        if len(uv) < WAND_MARKERS:
            too_few += 1
        elif len(uv) > WAND_MARKERS:
            too_many += 1
        else:
            kept.append(i)
            kept_uv.append(uv)
    return WandFrames(
        frame=np.asarray(kept, dtype=np.int64),
        uv=np.asarray(kept_uv, dtype=np.float64).reshape(-1, WAND_MARKERS, 2),
        too_few=too_few,
        too_many=too_many,
        still_uv=still,
        still_removed=removed,
        total=len(frames),
    )
