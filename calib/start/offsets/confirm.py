"""The whole-frame offsets a live warning may state: each confirmed by both wand ends against a
camera in time (docs/sync.md)."""

from __future__ import annotations

import numpy as np

from wandcal.calib.observations import WandPairs
from wandcal.calib.rig import Rig
from wandcal.calib.start.offsets.pair_fit import TIMING_FRAMES, fit_share, frame_table, pose_share, shared_counts
from wandcal.calib.start.offsets.whole_frames import FrameOffsets

# an offset is confirmed when the shared frames' ends fit their own relative pose at none this many
# times worse (median squared Sampson distance) than at the offset: a camera a whole frame out of
# time fits 100-10,000 times worse at none (motion against noise), one in time fits best at none,
# and a fractional offset f is confirmed from f = 2/3 of a frame ((f / (1 - f))^2 >= 4)
CONFIRM_RATIO = 4.0


def confirmed_offsets(rig: Rig, pairs: WandPairs, found: FrameOffsets) -> dict[int, int]:
    """{camera: whole frames} of the cameras of ``found`` with an offset that both wand ends
    confirm against none at all: what a live warning may say (docs/sync.md).

    The midpoint scores that :func:`frame_offsets` takes without an essential matrix can leave a
    neighbouring shift ahead when the wand moves little between frames (in a few hundred frames of
    a synchronised recording, 16 of 144 short captures had a camera one frame "off"). Here each
    camera with an offset is matched, by both ends, against the reference camera (or, when they
    share under half of ``TIMING_FRAMES``, the camera in time it shares most frames with), at none and at the offset and its neighbours, each lag with its own
    RANSAC pose: the best of the neighbours is the offset, and it stands when none fits
    ``CONFIRM_RATIO`` times worse. Cameras with no camera in time to compare with are left out.
    """
    table = frame_table(pairs, len(rig.cameras))
    # the reference first (the offsets are its clock's), else the camera in time sharing most frames
    in_time = [found.reference, *(int(c) for c in np.flatnonzero(found.offsets == 0) if c != found.reference)]
    out: dict[int, int] = {}
    for b in np.flatnonzero(found.offsets != 0):
        counts = np.array([shared_counts(table, a, int(b), np.zeros(1, np.int64))[0] for a in in_time])
        enough = np.flatnonzero(counts >= TIMING_FRAMES // 2)
        if not len(enough):
            continue
        a = in_time[0] if enough[0] == 0 else in_time[int(np.argmax(counts))]
        s = int(found.offsets[b])
        errors = {}
        for shift in (0, s - 1, s, s + 1):
            pose = pose_share(pairs, table, a, int(b), -shift, rig)
            errors[shift] = fit_share(pairs, table, a, int(b), -shift, rig, *pose)[1] if pose else np.inf
        best = min((s - 1, s, s + 1), key=lambda k: errors[k])
        if best != 0 and errors[0] >= CONFIRM_RATIO * errors[best]:
            out[int(b)] = best
    return out
