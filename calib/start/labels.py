"""Tell the wand's two ends apart across cameras.

Blobs carry no labels, so each camera-frame's pair is in arbitrary order. With approximate
poses, one camera per frame is the reference; every other camera's order is chosen by epipolar
consistency with it, then re-checked against the triangulated ends (reprojection), which also
settles the cases where both ends lie near one epipolar line.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from wandcal.calib.observations import WandPairs
from wandcal.calib.triangulate import triangulate_points

RELABEL_ROUNDS = 2  # a second reprojection pass changes nothing on simulated rigs
# cameras per frame whose pairs vote with every other camera of the frame in the consensus: the
# least ambiguous ones; more only adds pairs (every pair votes while a frame has at most 17 cameras)
VOTERS = 16
COST_CHUNK = 32768  # camera-pair costs per pass: 2x faster than all at once (its temporaries stay in cache)


def flatten(pairs: WandPairs) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Observation arrays of labelled pairs: point (2P,) = 2*frame + end, camera (2P,), xy (2P, 2)."""
    point = np.concatenate([2 * pairs.frame, 2 * pairs.frame + 1])
    camera = np.concatenate([pairs.camera, pairs.camera])
    xy = np.concatenate([pairs.xy[:, 0], pairs.xy[:, 1]])
    return point, camera, xy


def wand_lengths(R: np.ndarray, t: np.ndarray, pairs: WandPairs) -> np.ndarray:
    """(F,) length of each frame's wand, each end triangulated on its own from labelled pairs
    (metres; NaN where fewer than two cameras see the frame)."""
    point, camera, xy = flatten(pairs)
    X = triangulate_points(R, t, point, camera, xy, 2 * len(pairs.frames)).reshape(-1, 2, 3)
    return np.linalg.norm(X[:, 1] - X[:, 0], axis=1)


def label_ends(
    R: np.ndarray, t: np.ndarray, pairs: WandPairs, known: np.ndarray, length: float | None = None
) -> tuple[WandPairs, np.ndarray]:
    """Order each pair's ends consistently across the cameras whose pose is known (shapes and
    returns: :func:`labelled_ends`, without its ends)."""
    labelled, margin, _ = labelled_ends(R, t, pairs, known, length)
    return labelled, margin


def labelled_ends(
    R: np.ndarray, t: np.ndarray, pairs: WandPairs, known: np.ndarray, length: float | None = None
) -> tuple[WandPairs, np.ndarray, np.ndarray | None]:
    """Order each pair's ends consistently across the cameras whose pose is known.

    Args:
        R: (N, 3, 3), t: (N, 3) approximate poses.
        pairs: camera-frame pairs, any order.
        known: (N,) bool, cameras whose pose may be used; pairs of other cameras are left as they are.
        length: the wand length, metres. In a frame seen by only two cameras both matchings can
            fit the epipolar geometry (a wand near an epipolar plane); the one whose triangulated
            wand is nearer this length is kept.

    Returns:
        (labelled pairs of known cameras, (P_known,) margin in normalised units: how much worse
        the other order fits; small margins are doubtful, and the wand ends (F, 2, 3), metres,
        that :func:`triangulate_points` gives from those labelled pairs (:func:`flatten`, 2F
        points), when the last reprojection round triangulated exactly them; else None). The
        ends spare a caller that triangulates the labelled pairs the same triangulation again
        (the start's resections: :func:`wandcal.calib.start.resection.placed_points`).
    """
    sub = pairs.subset(known[pairs.camera])
    if len(sub) == 0:
        return sub, np.zeros(0), None
    ranked = _Ranked(sub)  # swapping a pair's ends leaves its rank: one sort serves both passes
    # and one table of the essential matrices of the cameras these pairs come from: the start's
    # resections label a few cameras' frames at a time (at 256 cameras, the 65,536 pairs' table
    # built for each of them was the start's largest cost)
    E_table = _essential_table(R, t, np.unique(sub.camera))
    sub = sub.swapped(_epipolar_order(R, t, sub, ranked, E_table))
    sub = sub.swapped(_pairwise_consensus(R, t, sub, ranked, E_table))
    margin = np.zeros(len(sub))
    judged = np.ones(len(sub), bool)  # the pairs whose frames are triangulated again this round
    current = None  # the ends of sub as it stands, while a round has triangulated every pair and flipped none
    two_view = _two_view_candidates(sub) if length is not None else None  # the end order does not change them
    swapped = None  # with current: the two-view frames' ends with their candidates swapped
    for _ in range(RELABEL_ROUNDS):
        part = sub if judged.all() else sub.subset(judged)
        X, swapped = _triangulated(R, t, sub, part, two_view)
        current = X if part is sub else None
        ends = X[part.frame]  # (P', 2, 3)
        Rc, tc = R[part.camera], t[part.camera]
        proj = np.stack([_project(Rc, tc, ends[:, e]) for e in range(2)], axis=1)
        same = np.linalg.norm(proj - part.xy, axis=2).sum(1)
        other = np.linalg.norm(proj[:, ::-1] - part.xy, axis=2).sum(1)
        margin[judged] = np.where(np.isfinite(same), np.abs(other - same), 0.0)
        flip = np.zeros(len(sub), bool)
        flip[np.flatnonzero(judged)[np.isfinite(other) & (other < same)]] = True
        if not flip.any():
            break
        current = None
        sub = sub.swapped(flip)
        # only the frames where a pair flipped have new ends: the next round judges them alone (the
        # others' ends, projections and margins stay as they are), not every pair again
        changed = np.zeros(len(sub.frames), bool)
        changed[sub.frame[flip]] = True
        judged = changed[sub.frame]
    if length is not None:
        swap = _two_view_swaps(R, t, sub, length, current, swapped if current is not None else None)
        if swap is not None and swap.any():
            sub, current = sub.swapped(swap), None
    return sub, margin, current


def _triangulated(R: np.ndarray, t: np.ndarray, sub: WandPairs, part: WandPairs,
                  two_view: tuple[np.ndarray, np.ndarray] | None) -> tuple[np.ndarray, np.ndarray | None]:
    """The ends (F, 2, 3) of the pairs ``part`` of ``sub`` (NaN for frames without them), metres,
    and, when ``part`` is all of ``sub`` and ``two_view`` (:func:`_two_view_candidates`) is given,
    the ends (F, 2, 3) of its frames in play with their candidates swapped, for
    :func:`_two_view_swaps`, in the same call: a point's triangulation does not depend on the
    others triangulated with it, so both are the digits of triangulating each on its own (and the
    start's resections, ~50 pairs each, pay one call's overhead, not two)."""
    F = len(sub.frames)
    point, camera, xy = flatten(part)
    if two_view is None or part is not sub:
        return triangulate_points(R, t, point, camera, xy, 2 * F).reshape(-1, 2, 3), None
    candidate, rows = two_view
    p2, c2, xy2 = flatten(sub.subset(rows).swapped(candidate[rows]))
    X = triangulate_points(R, t, np.concatenate([point, p2 + 2 * F]), np.concatenate([camera, c2]),
                           np.concatenate([xy, xy2]), 4 * F).reshape(-1, 2, 3)
    return X[:F], X[F:]


def _two_view_candidates(pairs: WandPairs) -> tuple[np.ndarray, np.ndarray] | None:
    """In frames seen by exactly two cameras, the second camera's pairs (P,) bool, and the pairs
    of those frames (P,) bool (None: no frame is seen by two)."""
    views = np.bincount(pairs.frame, minlength=len(pairs.frames))
    two = views[pairs.frame] == 2
    if not two.any():
        return None
    # the second pair of each two-view frame (pairs are grouped by frame in camera order)
    order = np.lexsort((pairs.camera, pairs.frame))
    second = np.zeros(len(pairs), bool)
    sorted_frames = pairs.frame[order]
    second[order[1:]] = sorted_frames[1:] == sorted_frames[:-1]
    candidate = second & two
    in_play = np.zeros(len(pairs.frames), bool)
    in_play[pairs.frame[candidate]] = True
    return candidate, in_play[pairs.frame]


def _two_view_swaps(R: np.ndarray, t: np.ndarray, pairs: WandPairs, length: float,
                    ends: np.ndarray | None = None, swapped: np.ndarray | None = None) -> np.ndarray | None:
    """(P,) bool: in frames seen by exactly two cameras, the second camera's pairs whose ends,
    swapped, bring the triangulated wand nearer ``length`` (None: no frame is seen by two).
    ``ends``: (F, 2, 3) metres, the pairs' own triangulation as they stand, and ``swapped`` (F, 2,
    3) the same with the candidates swapped (:func:`_triangulated`), when the caller has them
    (:func:`labelled_ends`' last round): a point's triangulation does not depend on the others
    triangulated with it, so their lengths are the digits of triangulating the frames in play again."""
    two_view = _two_view_candidates(pairs)
    if two_view is None:
        return None
    candidate, rows = two_view
    # only the frames with a candidate can change: their wands alone are triangulated, both ways
    # (a point's triangulation does not depend on the others triangulated with it; the whole
    # capture twice was most of `wandcal check`'s labelling at 128 cameras of 2-4 a frame)
    part = pairs.subset(rows)
    now = wand_lengths(R, t, part) if ends is None else np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1)
    alt = (wand_lengths(R, t, part.swapped(candidate[rows])) if swapped is None
           else np.linalg.norm(swapped[:, 1] - swapped[:, 0], axis=1))
    better = np.abs(alt - length) < np.abs(now - length)
    return candidate & better[pairs.frame]


def _project(R: np.ndarray, t: np.ndarray, X: np.ndarray) -> np.ndarray:
    xc = np.einsum("mij,mj->mi", R, X) + t
    return xc[:, :2] / xc[:, 2:3]


def _epipolar_order(R: np.ndarray, t: np.ndarray, pairs: WandPairs, ranked: _Ranked | None = None,
                    E_table: _Essentials | None = None) -> np.ndarray:
    """(P,) bool: swap each pair so it agrees with its frame's reference pair (the one whose
    blobs are furthest apart, which is the least ambiguous)."""
    ranked = ranked or _Ranked(pairs)
    ref = np.empty(len(pairs), dtype=np.int64)
    ref[ranked.order] = ranked.order[ranked.first]
    a, b = ref, np.arange(len(pairs))
    same, swap = _epipolar_costs(R, t, pairs, a, b, E_table)
    return (swap < same) & (a != b)


def _pairwise_consensus(R: np.ndarray, t: np.ndarray, pairs: WandPairs, ranked: _Ranked | None = None,
                        E_table: _Essentials | None = None, max_passes: int = 8) -> np.ndarray:
    """(P,) bool flips that lower each frame's epipolar cost summed over its voting camera pairs.

    The reference-based order trusts one camera per frame; when the wand lies near an epipolar
    plane of that camera, other cameras can split into two camps. Here pairs of cameras in a
    frame vote, and single-camera flips are taken greedily (the best one per frame and pass)
    while they lower the frame's total. Every camera votes with the frame's :data:`VOTERS`
    least ambiguous ones (blobs furthest apart), so the work per frame grows with its cameras,
    not with their pairs; a frame seen by at most ``VOTERS + 1`` cameras has every pair vote.
    """
    P = len(pairs)
    a_idx, b_idx, worse = _votes(R, t, pairs, ranked, E_table)  # worse: what a vote gains when one of its pairs flips while they agree
    if len(a_idx) == 0:
        return np.zeros(P, bool)
    # the votes come grouped by frame, and within it by their first pair (`_votes`); the
    # second pair of a vote is one of its frame's VOTERS least ambiguous pairs
    F = len(pairs.frames)
    vote_frame = pairs.frame[a_idx]
    v_lo, v_hi = np.searchsorted(vote_frame, np.arange(F)), np.searchsorted(vote_frame, np.arange(F), side="right")
    first = np.r_[True, a_idx[1:] != a_idx[:-1]]
    a_lo = np.full(P, 0)
    a_hi = np.full(P, 0)
    starts = np.flatnonzero(first)
    a_lo[a_idx[starts]] = starts
    a_hi[a_idx[starts]] = np.r_[starts[1:], len(a_idx)]
    is_voter = np.zeros(P, bool)
    is_voter[b_idx] = True
    by_frame = np.argsort(pairs.frame, kind="stable")
    p_lo = np.searchsorted(pairs.frame[by_frame], np.arange(F))
    p_hi = np.searchsorted(pairs.frame[by_frame], np.arange(F), side="right")
    flip = np.zeros(P, bool)
    active = np.arange(F)
    # flipping a pair changes its agreement with every pair it votes with: it gains `worse` where
    # they agree now and loses it where they do not, and so does the other pair of the vote
    gain = np.bincount(a_idx, worse, minlength=P) + np.bincount(b_idx, worse, minlength=P)
    for _ in range(max_passes):
        # only the active frames (a pair flipped there in the pass before) can offer a flip
        mine = by_frame[_ranges(p_lo[active], p_hi[active])]  # the pairs of the active frames, by frame
        best = np.zeros(F)
        np.maximum.at(best, pairs.frame[mine], gain[mine])
        take = mine[(gain[mine] > 0) & (gain[mine] >= best[pairs.frame[mine]])]
        # one flip per frame and pass: the frame's best single flip (the first pair of a tie)
        _, first_of_frame = np.unique(pairs.frame[take], return_index=True)
        chosen = take[first_of_frame]
        if not len(chosen):
            break
        # the flipped pairs' votes change sides (no vote holds two: one flip per frame): the
        # gains are updated there alone. Re-scoring every vote of the active frames at each pass
        # grew as cameras^2 per frame (7.3M votes over the passes at 128 cameras, 1.3M at 64).
        # A pair's votes as the first pair are contiguous; as the second (a voter), in its frame.
        voters = chosen[is_voter[chosen]]
        in_frame = _ranges(v_lo[pairs.frame[voters]], v_hi[pairs.frame[voters]])
        votes = np.concatenate([_ranges(a_lo[chosen], a_hi[chosen]), in_frame[np.isin(b_idx[in_frame], voters)]])
        a, b = a_idx[votes], b_idx[votes]
        term = np.where(flip[a] == flip[b], worse[votes], -worse[votes])
        flipping = np.zeros(P, bool)
        flipping[chosen] = True
        gain -= 2 * (np.bincount(np.where(flipping[a], b, a), term, minlength=P))
        gain[chosen] = -gain[chosen]
        flip[chosen] ^= True
        active = pairs.frame[chosen]
    return flip


def _ranges(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The integers of the ranges [lo, hi) (each (K,)), concatenated."""
    n = hi - lo
    return np.repeat(lo - np.cumsum(n) + n, n) + np.arange(int(n.sum()))


def _votes(R: np.ndarray, t: np.ndarray, pairs: WandPairs, ranked: _Ranked | None = None,
           E_table: _Essentials | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The unordered pairs of pairs (a (K,), b (K,)) in the same frame that vote in
    :func:`_pairwise_consensus` (each pair with each of its frame's :data:`VOTERS` voters, the pairs
    whose blobs are furthest apart, each unordered pair once), with what each vote gains when one
    of its pairs flips while they agree (K,): ``same - cross`` of :func:`_epipolar_costs`. Made :data:`COST_CHUNK`
    votes at a time, each block's votes costed as they are made, so no vote-sized temporary leaves
    the cache (at 128 cameras x 3000 frames there are 5.4M votes, and the votes made whole took
    3.7x as long as at 64 cameras for 2.2x as many)."""
    ranked = ranked or _Ranked(pairs)
    costs = _EpipolarCosts(R, t, pairs, E_table)
    a_parts, b_parts, w_parts = [], [], []
    for lo, hi in ranked.blocks():
        a, b = ranked.votes(lo, hi)
        same, cross = costs(a, b)
        a_parts.append(a)
        b_parts.append(b)
        w_parts.append(same - cross)
    if not a_parts:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    return np.concatenate(a_parts), np.concatenate(b_parts), np.concatenate(w_parts)


class _Ranked:
    """The pairs sorted by frame, and within it by how far apart their blobs are (the widest
    first): each pair's rank in its frame and how many voters it meets (:data:`VOTERS` at most)."""

    def __init__(self, pairs: WandPairs) -> None:
        self.order = np.lexsort((-np.linalg.norm(pairs.xy[:, 0] - pairs.xy[:, 1], axis=1), pairs.frame))
        fr = pairs.frame[self.order]
        self.first = np.searchsorted(fr, fr, side="left")  # sorted position of the frame's first pair
        self.rank = np.arange(len(self.order)) - self.first  # 0 for the frame's widest pair
        count = np.bincount(fr, minlength=len(pairs.frames))[fr]
        self.voters = np.minimum(count, VOTERS)
        self.ends = np.cumsum(self.voters)  # candidate votes up to each sorted position

    def blocks(self):
        """[lo, hi) ranges of sorted positions, about :data:`COST_CHUNK` candidate votes each."""
        if not len(self.order):
            return
        cuts = np.searchsorted(self.ends, np.arange(COST_CHUNK, int(self.ends[-1]), COST_CHUNK), side="right")
        bounds = np.unique(np.r_[0, cuts, len(self.order)])
        yield from zip(bounds[:-1].tolist(), bounds[1:].tolist())

    def votes(self, lo: int, hi: int) -> tuple[np.ndarray, np.ndarray]:
        """The votes (a, b) of the pairs at sorted positions lo .. hi - 1, in order."""
        voters, rank = self.voters[lo:hi], self.rank[lo:hi]
        # each pair (sorted position s) against its frame's voters (sorted positions first .. first + voters)
        i_pos = np.repeat(np.arange(lo, hi), voters)
        offs = np.arange(len(i_pos)) - np.repeat(np.cumsum(voters) - voters, voters)
        j_pos = np.repeat(self.first[lo:hi], voters) + offs
        i_rank = np.repeat(rank, voters)
        # a voter meets another voter twice (once from each side): keep the one from the later rank
        keep = (j_pos != i_pos) & ((i_rank >= VOTERS) | (offs < i_rank))
        return self.order[i_pos[keep]], self.order[j_pos[keep]]


def _essential_matrices(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(N, N, 3, 3): E[a, b] with x_b^T E x_a = 0 for cameras a, b (normalised coordinates)."""
    R_ab = R[None, :] @ np.swapaxes(R, 1, 2)[:, None]  # [a, b] = R_b R_a^T
    t_ab = t[None, :] - np.einsum("abij,aj->abi", R_ab, t)
    return _skew(t_ab.reshape(-1, 3)).reshape(R_ab.shape) @ R_ab


def _skew(v: np.ndarray) -> np.ndarray:
    z = np.zeros(len(v))
    return np.stack(
        [np.stack([z, -v[:, 2], v[:, 1]], 1), np.stack([v[:, 2], z, -v[:, 0]], 1), np.stack([-v[:, 1], v[:, 0], z], 1)],
        axis=1,
    )


def _epipolar_costs(R: np.ndarray, t: np.ndarray, pairs: WandPairs, a: np.ndarray, b: np.ndarray,
                    E_table: _Essentials | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Epipolar costs of the pairs ``a`` (K,) against the pairs ``b`` (K,) of other cameras in the
    same frames: (same, cross), each (K,), the Sampson distances summed over both ends matched in
    their present order and crossed; :data:`COST_CHUNK` at a time so the temporaries stay in cache."""
    costs = _EpipolarCosts(R, t, pairs, E_table)
    same, cross = np.empty(len(a)), np.empty(len(a))
    for s in range(0, len(a), COST_CHUNK):
        same[s : s + COST_CHUNK], cross[s : s + COST_CHUNK] = costs(a[s : s + COST_CHUNK], b[s : s + COST_CHUNK])
    return same, cross


class _Essentials(NamedTuple):
    """The essential matrices of some cameras' pairs: ``table`` (9, U*U), column b * U + a holds
    E[a, b]'s nine entries (:func:`_essential_matrices`) for a, b the cameras' places in the table,
    ``place`` (N,) each camera's place (-1: not in it)."""

    table: np.ndarray
    place: np.ndarray
    n: int


def _essential_table(R: np.ndarray, t: np.ndarray, cameras: np.ndarray | None = None) -> _Essentials:
    """The essential matrices of the pairs of ``cameras`` (U,) (default every camera)."""
    # b-major: a frame's votes pair every camera a of the frame with a few voters b, whose columns
    # then lie side by side (at 128 cameras the table is 1.2 MB, and a-major columns had each vote
    # read nine cache lines of its own)
    cameras = np.arange(len(R)) if cameras is None else cameras
    n = len(cameras)
    index = np.full(len(R), -1)
    index[cameras] = np.arange(n)
    table = np.ascontiguousarray(np.swapaxes(_essential_matrices(R[cameras], t[cameras]), 0, 1).reshape(n * n, 9).T)
    return _Essentials(table, index, n)


class _EpipolarCosts:
    """The tables :func:`_epipolar_costs` reads: every camera pair's essential matrix (E's nine
    entries as nine rows, the pair's column b-major), and the blobs' x, y (four rows)."""

    def __init__(self, R: np.ndarray, t: np.ndarray, pairs: WandPairs, E_table: _Essentials | None = None) -> None:
        essentials = _essential_table(R, t) if E_table is None else E_table
        self.n, self.E_table = essentials.n, essentials.table
        self.xy_table = np.ascontiguousarray(pairs.xy.reshape(-1, 4).T)  # (4, P): x0, y0, x1, y1
        self.camera = essentials.place[pairs.camera]  # each pair's camera's place in the table

    def __call__(self, ca: np.ndarray, cb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(same, cross) of the pairs ``ca`` (K,) against ``cb`` (K,); worked on flat rows (E's
        nine entries, each blob's x and y), each end's epipolar line formed once for both matchings."""
        E = np.take(self.E_table, self.camera[cb] * self.n + self.camera[ca], axis=1)
        xa, xb = np.take(self.xy_table, ca, axis=1), np.take(self.xy_table, cb, axis=1)
        # E x_a (the line in b) of each end of a, and E^T x_b's first two entries of each end of b
        line = [[E[3 * r] * xa[2 * e] + E[3 * r + 1] * xa[2 * e + 1] + E[3 * r + 2] for r in range(3)] for e in range(2)]
        back = [[E[c] * xb[2 * e] + E[3 + c] * xb[2 * e + 1] + E[6 + c] for c in range(2)] for e in range(2)]

        def sampson(ea: int, eb: int) -> np.ndarray:
            la, lb = line[ea], back[eb]
            num = (xb[2 * eb] * la[0] + xb[2 * eb + 1] * la[1] + la[2]) ** 2
            den = la[0] ** 2 + la[1] ** 2 + lb[0] ** 2 + lb[1] ** 2
            return num / np.maximum(den, 1e-300)

        return sampson(0, 0) + sampson(1, 1), sampson(0, 1) + sampson(1, 0)
