"""One camera's whole-frame offset against cameras already timed: the shifts it tries, each scored by
the wand midpoints' fit (:func:`~wandcal.calib.start.offsets.pair_fit.midpoint_scores`) or, where the
frames are few, by each shift's own RANSAC pose, and the refusals (a camera that moved with no other,
or whose frames are too few to tell). The order the cameras are timed in, and the search over the
rig: :mod:`wandcal.calib.start.offsets.whole_frames`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.observations import WandPairs
from wandcal.calib.rig import Rig
from wandcal.calib.start.offsets.pair_fit import (
    MIN_TIMING_FRAMES,
    TIMING_FRAMES,
    fit_share,
    lag_share,
    midpoint_scores,
    pose_share,
    shared_counts,
)

# a shift is accepted when both ends of at least this share of its frames fit one relative pose
# within the RANSAC threshold: 0.27-1.0 on simulated rigs (a half-frame offset moves fast frames
# off by more than the threshold), 0 for a camera that saw another motion; what rejects the latter
# first is MAX_CONTRAST
MIN_FIT_SHARE = 0.15
# the best shift's midpoint score against the median shift's: 0.02-0.3 on simulated rigs, whose
# fractional offsets blur the best; a camera that saw another motion has no shift that stands out
MAX_CONTRAST = 0.5
# below this the best shift is taken without an essential matrix: simulated rigs at 1-4 m/s score
# 0.02-0.3, a camera that saw another motion 0.74-0.86, and a neighbour taken in error is corrected
# by the sub-frame fit (within a frame)
CLEAR_CONTRAST = 0.2
# below this many shared frames (a digitised session: easyWand's have 10-40 a pair) a linear fit through
# the midpoints fits any shift, and each shift is judged by its own essential matrix instead
FEW_FRAMES = 60
# in a sparse session the best shift's share must beat every shift two or more frames away by this:
# 0.57-0.90 against at most 0.25 on the Brown wind-tunnel sessions
SPARSE_MARGIN = 0.25
POSE_PASSES = 2  # a pose from a shift one frame off picks the right neighbour; its own RANSAC confirms it
CONTRAST_SPAN = 6  # frames either side the midpoint scores are judged over, however narrow the search


class TooFewShared(CalibrationError):
    """A camera could not be timed and shares fewer than :data:`FEW_FRAMES` frames with its best
    partner at every shift: a sparse rig, whose cameras :mod:`wandcal.calib.run.sparse_offsets`
    times against all the others together instead."""



@dataclass(frozen=True)
class ShiftSearch:
    """What every camera's search shares: the rig, the pairs and their (span, N) ``table``, the
    start (N,) int, the reference camera and the frames searched either side."""

    rig: Rig
    pairs: WandPairs
    table: np.ndarray
    start: np.ndarray
    reference: int
    max_offset: int

    def time(self, b: int, partners: list[int], offsets: np.ndarray) -> tuple[int, float]:
        """Camera b's offset and share against ``partners`` (timed, best linked first; their
        ``offsets`` (N,) found), or raise CalibrationError (:class:`TooFewShared` where the
        frames are too few to tell)."""
        rig, table, max_offset = self.rig, self.table, self.max_offset
        guess = int(self.start[b] - self.start[self.reference])
        shifts = np.arange(guess - max_offset, guess + max_offset + 1)
        best, score = best_shift(self.pairs, table, [(c, int(offsets[c])) for c in partners], b, shifts, rig)
        a = partners[0]
        if best is None or score < MIN_FIT_SHARE:
            what = (f"at best {score:.0%} of the frames they share fit one relative pose" if best is not None
                    else f"they share fewer than {MIN_TIMING_FRAMES} frames at every shift")
            thin = best is None or shared_counts(table, a, b, int(offsets[a]) - shifts).max() < FEW_FRAMES
            raise (TooFewShared if thin else CalibrationError)(
                f"camera {rig.cameras[b].id!r} does not move with the others: at no offset within +-{max_offset} frames "
                f"of {guess} does its wand agree with {rig.cameras[a].id}'s ({what}); check that it recorded the same "
                "session and the same wand, or search wider (sync_max_offset)"
            )
        if abs(best - guess) >= max_offset:
            raise CalibrationError(
                f"camera {rig.cameras[b].id!r}: its best time offset, {best} frames, is at the edge of the search "
                f"(+-{max_offset} frames around {guess}); the offset may lie beyond it: search wider (sync_max_offset)"
            )
        return best, score

    def partner_offsets(self, a: int) -> range:
        """Every offset camera a can have when a camera timed against it is searched: 0 for the
        reference, else strictly inside a's own window (at its edge a's search raises)."""
        if a == self.reference:
            return range(0, 1)
        near = int(self.start[a] - self.start[self.reference])
        return range(near - self.max_offset + 1, near + self.max_offset)

    def shifts(self, b: int) -> np.ndarray:
        """(2 max_offset + 1,) the shifts camera b's search tries."""
        guess = int(self.start[b] - self.start[self.reference])
        return np.arange(guess - self.max_offset, guess + self.max_offset + 1)

    def sparse_everywhere(self, b: int, a: int) -> bool:
        """Whether camera b, timed against ``a`` first, shares fewer than ``FEW_FRAMES`` frames
        with it at every lag any offset of a gives: then its search is judged by one RANSAC a
        shift (or finds too few frames) and refuses only with TooFewShared or at the edge of its
        search."""
        return bool(shared_counts(self.table, a, b, self._partner_lags(b, a)).max() < FEW_FRAMES)

    def proof_cost(self, b: int, a: int) -> int:
        """The RANSACs :meth:`cannot_time` (b, a) runs at most where b is :meth:`sparse_everywhere`
        (elsewhere it runs fewer and refutes the proof): the lags any offset of a gives where the
        pair shares ``MIN_TIMING_FRAMES`` frames."""
        return int(np.count_nonzero(shared_counts(self.table, a, b, self._partner_lags(b, a)) >= MIN_TIMING_FRAMES))

    def _partner_lags(self, b: int, a: int) -> np.ndarray:
        """(L,) every lag between b and ``a`` that an offset of a's (:meth:`partner_offsets`) and a
        shift of b's give, ascending: both are runs of whole numbers, so their differences are one run."""
        offsets, shifts = self.partner_offsets(a), self.shifts(b)
        return np.arange(offsets[0] - shifts[-1], offsets[-1] - shifts[0] + 1)

    def cannot_time(self, b: int, a: int) -> bool:
        """Whether camera b's search against ``a`` as its first partner raises TooFewShared
        whatever offset a's own search finds (:meth:`partner_offsets`): at each such offset b's
        frames are too few to judge, or few enough that one RANSAC a shift judges them
        (:func:`sparse_best_shift`) and no shift reaches ``MIN_FIT_SHARE`` (a shift that does
        is accepted, or refused at the edge of the search: not TooFewShared). False as soon as
        one offset of a might let b pass or be refused otherwise, or would judge b by the
        midpoint scores (which the other partners' offsets enter)."""
        shifts = self.shifts(b)
        shares: dict[int, float] = {}  # by lag: a's offsets share most of their lags
        for offset_a in self.partner_offsets(a):
            lags = offset_a - shifts
            counts = np.minimum(shared_counts(self.table, a, b, lags), TIMING_FRAMES)  # as best_shift's
            if counts.max() < MIN_TIMING_FRAMES:
                continue
            if counts.max() >= FEW_FRAMES:
                return False
            for lag in lags:
                if int(lag) not in shares:
                    shares[int(lag)] = lag_share(self.pairs, self.table, a, b, int(lag), self.rig)
            if sparse_pick(shifts, np.array([shares[int(lag)] for lag in lags]))[1] >= MIN_FIT_SHARE:
                return False
        return True



def best_shift(
    pairs: WandPairs, table: np.ndarray, partners: list[tuple[int, int]], b: int, shifts: np.ndarray, rig: Rig
) -> tuple[int | None, float]:
    """Camera b's offset among ``shifts`` against timed cameras ``partners`` ((camera, offset),
    best linked first) and the share of its frames shared with the first whose ends fit one
    relative pose there (1 when the shift stands out beyond doubt).

    Every shift is scored by a linear fundamental matrix through the frames' wand midpoints (no
    end labels needed; the midpoint of two projections is off the projected midpoint by a few
    pixels, less than a frame of motion), trimmed of its worst fifth: a few hundred microseconds
    a shift, each partner's scores relative to its median shift's, their geometric mean over the partners.
    A best shift that stands out beyond doubt (``CLEAR_CONTRAST``) is taken; otherwise it pays for
    an essential matrix by RANSAC against the first partner, whose inlier share judges it, and
    whose pose picks between the best shift and its neighbours by both ends.
    """
    a, offset_a = partners[0]
    counts = np.minimum(shared_counts(table, a, b, offset_a - shifts), TIMING_FRAMES)  # what shared_rows would give
    if counts.max() < MIN_TIMING_FRAMES:
        return None, 0.0
    if counts.max() < FEW_FRAMES:  # a sparse session: every shift can afford its own RANSAC
        return sparse_best_shift(pairs, table, (a, offset_a), b, shifts, rig)
    # a narrow search is judged against shifts beyond it too: its own median is the best's neighbours'
    pad = max(CONTRAST_SPAN - len(shifts) // 2, 0)
    wide = np.arange(shifts[0] - pad, shifts[-1] + pad + 1)
    each = [midpoint_scores(pairs, table, c, b, offset_c - wide) for c, offset_c in partners]
    # each partner's scores relative to its own median shift's, their geometric mean: a partner
    # whose scores barely tell the shifts apart does not outvote one that does (the arithmetic
    # mean put 12 of 99 cameras on 12 simulated rigs off the nearest whole frame, both synchronised
    # rigs' among them; this, 11, none of the synchronised ones; a camera that saw another motion
    # scores alike either way, 0.40-0.86)
    usable = [e for e in each if np.isfinite(e).sum() > 2]
    if not usable:  # no partner scored three shifts: wand frames far apart in time (Ushichka's, every ~100th)
        return sparse_best_shift(pairs, table, (a, offset_a), b, shifts, rig)
    with np.errstate(all="ignore"):
        everywhere = np.exp(np.nanmean([np.log(e / np.nanmedian(e)) for e in usable], axis=0))
    scores = everywhere[pad : len(wide) - pad]
    if not np.isfinite(scores).any():
        return None, 0.0
    best = int(np.nanargmin(scores))
    typical = np.nanmedian(everywhere)
    if np.nanmin(scores) > MAX_CONTRAST * typical:
        return int(shifts[best]), 0.0  # no shift stands out: the camera saw another motion
    if np.nanmin(scores) < CLEAR_CONTRAST * typical:
        return int(shifts[best]), 1.0  # stands out beyond doubt: the sub-frame fit settles the neighbour
    share = 0.0
    for _ in range(POSE_PASSES):
        found = pose_share(pairs, table, a, b, offset_a - shifts[best], rig)
        if found is None:
            return int(shifts[best]), 0.0
        near = [k for k in (best - 1, best, best + 1) if 0 <= k < len(shifts)]
        fits = [fit_share(pairs, table, a, b, offset_a - shifts[k], rig, *found) for k in near]
        pick = int(np.argmin([err for _, err in fits]))  # the closest fit: shares saturate near the right shift
        share = fits[pick][0]
        if near[pick] == best:
            break
        best = near[pick]
    return int(shifts[best]), float(share)


def sparse_best_shift(pairs: WandPairs, table: np.ndarray, partner: tuple[int, int], b: int, shifts: np.ndarray,
                       rig: Rig) -> tuple[int, float]:
    """(shift, share) of camera b against one timed camera ``partner`` (camera, offset) where its
    frames are too few, or too far apart in time, for the midpoint scores: each shift's own RANSAC
    pose, the best share kept when it beats every shift two or more away by ``SPARSE_MARGIN``."""
    a, offset_a = partner
    return sparse_pick(shifts, np.array([lag_share(pairs, table, a, b, offset_a - s, rig) for s in shifts]))


def sparse_pick(shifts: np.ndarray, shares: np.ndarray) -> tuple[int, float]:
    """(shift, share) of the best of ``shifts`` (S,) by their ``shares`` (S,), the share 0 unless it
    beats every shift two or more away by ``SPARSE_MARGIN``."""
    best = int(np.argmax(shares))
    rival = np.max(np.where(np.abs(shifts - shifts[best]) >= 2, shares, 0.0))
    return int(shifts[best]), float(shares[best]) if shares[best] - rival >= SPARSE_MARGIN else 0.0
