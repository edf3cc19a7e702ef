"""Whole-frame time offsets of cameras without a trigger, found from the wand itself.

A camera whose frame k was exposed at the reference camera's frame k + n (n a whole number of
frames) sees the wand where the others saw it n frames later. Its wand ends agree with another
camera's epipolar geometry only when its frames are shifted by n: at any other shift the wand has
moved between the two views (1-3 cm a frame at 1-3 m/s and 100 fps, several pixels), and no
relative pose fits both ends of most frames. So each camera's offset is the shift at which an
essential matrix (five-point RANSAC, both matchings of each frame's unlabelled ends, as
:func:`wandcal.calib.start.chain.pair_pose`) fits the largest share of the frames it shares with
a camera already timed. Cameras are timed one at a time, best linked first, from a reference
camera, so a rig whose cameras overlap only pairwise is timed too.

The sub-frame part of the offset, and a rate difference, are refined afterwards with the poses
known (:mod:`wandcal.calib.solve.sync`). The model and its limits: docs/sync.md. One camera's search
over the shifts: :mod:`wandcal.calib.start.offsets.shift_search`; each pair's scores at a shift:
:mod:`wandcal.calib.start.offsets.pair_fit`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.observations import WandPairs
from wandcal.calib.rig import Rig, WandObservations
from wandcal.calib.start.offsets.pair_fit import MIN_TIMING_FRAMES, frame_table, shared_counts
from wandcal.calib.start.offsets.shift_search import ShiftSearch, TooFewShared

REFERENCE_LINKS = 0.5  # the first camera is the reference when it has half the best-linked camera's links
DEFAULT_MAX_OFFSET = 8  # frames searched either side: the issue's +-5 and fractions, with room to see the best stand out
PARTNERS = 3  # timed cameras a camera is tried against, best linked first, before it is judged out of step


@dataclass(frozen=True, eq=False)
class FrameOffsets:
    """Whole-frame offsets: camera c's frame k was exposed at the reference camera's frame
    k + offsets[c].

    offsets: (N,) int frames; reference: the camera of offset 0; timed_against: (N,) the camera
    each was timed against (-1 for the reference); share: (N,) the share of shared frames whose
    ends fit at the chosen shift; notes: what the user should know.
    """

    offsets: np.ndarray
    reference: int
    timed_against: np.ndarray
    share: np.ndarray
    notes: list[str] = field(default_factory=list)


def shift_frames(wand: WandObservations, offsets: np.ndarray) -> WandObservations:
    """The blobs with each camera's frames renumbered onto the reference camera's clock: camera
    c's frame k becomes frame k + offsets[c] (offsets (N,) int frames)."""
    return WandObservations(wand.frame + np.asarray(offsets, dtype=np.int64)[wand.camera], wand.camera, wand.uv)


def shift_pairs(pairs: WandPairs, offsets: np.ndarray) -> WandPairs:
    """The pairs with each camera's frames renumbered as :func:`shift_frames` renumbers the blobs
    (the same pairs as grouping the shifted blobs again, in the same order, without undistorting
    them again)."""
    number = pairs.frames[pairs.frame] + np.asarray(offsets, dtype=np.int64)[pairs.camera]
    order = np.lexsort((pairs.camera, number))
    frames, frame = np.unique(number[order], return_inverse=True)
    return WandPairs(frame, pairs.camera[order], pairs.xy[order], pairs.uv[order], frames, pairs.dropped)


def frame_offsets(
    rig: Rig, pairs: WandPairs, max_offset: int = DEFAULT_MAX_OFFSET, start: np.ndarray | None = None,
    reference: int | None = None, *, fail_fast: bool = False, prove_sparse: bool = False,
) -> FrameOffsets:
    """Each camera's whole-frame offset (see module docstring).

    Args:
        rig: the rig (camera ids and focal lengths).
        pairs: two-blob camera-frames on each camera's own frame numbers (normalised coordinates).
        max_offset: frames searched either side of the start.
        start: (N,) int, a first guess of each camera's offset (timestamps), searched around;
            default zeros.
        reference: the camera of offset 0; default the rig's first camera, or the best-linked
            one when the first has less than half its links.
        fail_fast: for a caller that needs only whether the search succeeds, not which camera
            stops it: the cameras most likely to fail (fewest frames shared with their partner at
            the start's offsets) are timed first, each after the cameras it is timed against. The
            offsets found are the same (each camera's search sees only its partners' offsets); a
            search that fails may raise for another camera, or another kind of failure, than
            the default order would. Implies ``prove_sparse``.
        prove_sparse: for a caller that falls back on :class:`TooFewShared` (calibrate's sync):
            before timing anyone, try to prove that the planned search would raise TooFewShared
            (:func:`_refuse_untimeable`), and raise it at once; otherwise the planned search, as by
            default. The answer is the default's on every input but one kind (decision 0081): a
            camera planned before the one proved, in the sparse regime (fewer than ``FEW_FRAMES``
            frames shared with its first partner at any lag), whose best shift is at the edge of
            its search: the default refuses it ("at the edge of the search"), this raises
            TooFewShared.

    Raises:
        CalibrationError: a camera's wand agrees with no timed camera's at any shift searched
            (it never moved with the others), or the search reaches past the recording; the
            message names the camera and what to do.
    """
    n = len(rig.cameras)
    start = np.zeros(n, np.int64) if start is None else np.asarray(start, dtype=np.int64)
    table = frame_table(pairs, n)
    seen = table >= 0
    _check_range(rig, seen, max_offset, start)
    links = _links(seen, max_offset)
    if reference is None:  # the rig's first camera, as users number them, unless it is poorly linked
        total = links.sum(1)
        reference = 0 if total[0] >= REFERENCE_LINKS * total.max() else int(np.argmax(total))
    steps, unlinked = _plan(links, reference)
    if unlinked is not None and fail_fast:  # the search cannot time this camera whatever the others give
        raise _unlinked_error(rig, unlinked, steps, reference, max_offset)
    offsets = np.zeros(n, np.int64)
    against = np.full(n, -1, np.int64)
    share = np.ones(n)
    search = ShiftSearch(rig, pairs, table, start, reference, max_offset)
    if fail_fast or prove_sparse:
        _refuse_untimeable(search, steps, table)
    for b, partners in (_risk_first(steps, table, start) if fail_fast else steps):
        offsets[b], share[b] = search.time(b, partners, offsets)
        against[b] = partners[0]
    if unlinked is not None:
        raise _unlinked_error(rig, unlinked, steps, reference, max_offset)
    return FrameOffsets(offsets=offsets, reference=reference, timed_against=against, share=share, notes=[])


def _plan(links: np.ndarray, reference: int) -> tuple[list[tuple[int, list[int]]], int | None]:
    """The order the cameras are timed in and the timed cameras each is timed against (at most
    ``PARTNERS``, best linked first): from ``reference``, always the untimed camera best linked to
    a timed one (``links`` (N, N), :func:`_links`). It depends on the links alone, not on the
    offsets found. Also the first camera linked to none timed before it (None: every camera is
    reached); the cameras after it are not planned."""
    n = len(links)
    timed = np.zeros(n, bool)
    timed[reference] = True
    steps: list[tuple[int, list[int]]] = []
    while not timed.all():
        strength = np.where(timed[:, None] & ~timed[None, :], links, -1)
        ia, ib = np.unravel_index(np.argmax(strength), strength.shape)
        b = int(ib)
        if strength[int(ia), b] <= 0:
            return steps, int(np.flatnonzero(~timed)[0])
        # against the best-linked timed cameras together: one pair's geometry may barely tell the
        # shifts apart (the wand moving along their epipolar lines), several rarely do
        partners = [int(c) for c in np.argsort(-strength[:, b], kind="stable")[:PARTNERS] if strength[c, b] > 0]
        steps.append((b, partners))
        timed[b] = True
    return steps, None


def _risk_first(steps: list[tuple[int, list[int]]], table: np.ndarray, start: np.ndarray) -> list[tuple[int, list[int]]]:
    """``steps`` reordered for a search that should fail early: the camera sharing the fewest frames
    with its first partner at the start's offsets first, each after the cameras it is timed against
    (and theirs); ties in the planned order. Only the order changes, so each camera's search sees
    the same partners' offsets as in the planned order."""
    index = {b: i for i, (b, _) in enumerate(steps)}
    shared = [int(shared_counts(table, p[0], b, np.array([int(start[b] - start[p[0]])]))[0]) for b, p in steps]
    done: set[int] = set()
    out: list[tuple[int, list[int]]] = []
    for i in np.argsort(shared, kind="stable"):
        needed, stack = set(), [int(i)]
        while stack:  # the step and every step it depends on, not yet taken
            j = stack.pop()
            if j in done or j in needed:
                continue
            needed.add(j)
            stack += [index[p] for p in steps[j][1] if p in index]
        out += [steps[j] for j in sorted(needed)]  # the planned order: partners before the cameras timed against them
        done |= needed
    return out


def _refuse_untimeable(search: ShiftSearch, steps: list[tuple[int, list[int]]], table: np.ndarray) -> None:
    """Raise TooFewShared if :meth:`ShiftSearch.cannot_time` proves that the search would refuse
    some camera b of ``steps`` with TooFewShared, b sharing fewer than ``MIN_TIMING_FRAMES`` frames
    with its first partner at the start's offsets, provided every camera planned before b can refuse
    with nothing else but the edge of its search (:meth:`ShiftSearch.sparse_everywhere`: the
    midpoint scores' other refusals need ``FEW_FRAMES`` frames). Whether it raises does not depend
    on the order the cameras are tried in, only what it costs and which camera the message names:
    the cheapest proofs first (:meth:`ShiftSearch.proof_cost`, one RANSAC a lag; ties in the planned
    order), and none that the frame counts already refute (a camera not sparse everywhere). Which
    cameras are tried only bounds the cost; the proofs are exact."""
    tried = []  # (RANSACs, planned index, b, a)
    for i, (b, partners) in enumerate(steps):
        a = partners[0]
        lag = int(search.start[b] - search.start[a])
        if not search.sparse_everywhere(b, a):
            break  # b might be refused otherwise than TooFewShared, and cannot_time refutes it on the counts alone
        if shared_counts(table, a, b, np.array([lag]))[0] < MIN_TIMING_FRAMES:
            tried.append((search.proof_cost(b, a), i, b, a))
    for _, _, b, a in sorted(tried):
        if search.cannot_time(b, a):
            rig = search.rig
            raise TooFewShared(
                f"camera {rig.cameras[b].id!r} cannot be timed against {rig.cameras[a].id}: at no offset of "
                f"{rig.cameras[a].id}'s within +-{search.max_offset} frames does its wand agree with "
                f"{rig.cameras[a].id}'s at a shift within +-{search.max_offset} frames; check that it recorded the same "
                "session and the same wand, or search wider (sync_max_offset)")


def _unlinked_error(rig: Rig, b: int, steps: list[tuple[int, list[int]]], reference: int, max_offset: int,
                    ) -> CalibrationError:
    """The error for camera b, which shares no wand frame with the cameras timed before it (the
    reference and the cameras of ``steps``)."""
    timed = sorted([reference, *(c for c, _ in steps)])
    return CalibrationError(
        f"camera {rig.cameras[b].id!r} shares no wand frames with the cameras timed so far "
        f"({', '.join(rig.cameras[c].id for c in timed)}) at any offset within +-{max_offset} "
        f"frames; wave the wand where {rig.cameras[b].id} and the others see it at the same time"
    )



def _check_range(rig: Rig, seen: np.ndarray, max_offset: int, start: np.ndarray) -> None:
    """A search that reaches past every frame a camera recorded cannot find its offset."""
    for c, cam in enumerate(rig.cameras):
        frames = np.flatnonzero(seen[:, c])
        if not len(frames):
            continue
        length = int(frames[-1] - frames[0] + 1)
        if abs(int(start[c])) + max_offset >= len(seen) or abs(int(start[c])) >= length:
            raise CalibrationError(
                f"camera {cam.id!r}: an offset of up to {abs(int(start[c])) + max_offset} frames is as long as the recording "
                f"({len(seen)} frames, {length} with the wand in {cam.id}); the cameras' recordings must overlap: "
                "check the timestamps, or lower sync_max_offset"
            )


def _links(seen: np.ndarray, max_offset: int) -> np.ndarray:
    """(N, N) frames each pair of cameras sees the wand in within ``max_offset`` frames of each
    other: a link count that the unknown offsets do not hide."""
    c = np.concatenate([np.zeros((1, seen.shape[1]), np.int64), np.cumsum(seen, 0)])
    lo = np.clip(np.arange(len(seen)) - max_offset, 0, len(seen))
    hi = np.clip(np.arange(len(seen)) + max_offset + 1, 0, len(seen))
    near = (c[hi] - c[lo]) > 0
    # einsum: NumPy's integer matmul is a plain loop 5x slower (as calib/start/initial.shared_frames)
    links = np.einsum("fa,fb->ab", seen.astype(np.int64), near.astype(np.int64))
    links = np.minimum(links, links.T)
    np.fill_diagonal(links, 0)
    return links
