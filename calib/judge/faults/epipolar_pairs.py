"""Every pair of cameras' samples of the moving wand at the same time, as epipolar products: the
evidence :mod:`wandcal.calib.judge.faults.timing_pairs` judges a camera's timing from.

Two cameras that see a point at the same time see it on each other's epipolar lines
(``x_c^T E x_d = 0``, ``E = [t_cd]x R_cd`` from the final poses). Each pair sample is that product,
Sampson-normalised, with its derivatives in the two cameras' time offsets (each camera's own image
velocity, from its samples at the frames before and after). Only samples with a time take part: the
wand's ends, or the point tracks where there is no wand (a moving marker).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.observations import PointTracks, WandPairs


@dataclass(frozen=True, eq=False)
class Samples:
    """Every timed sample: camera (S,), frame (S,) capture frame numbers, xy (S, 2) normalised."""

    camera: np.ndarray
    frame: np.ndarray
    xy: np.ndarray


def timed_samples(labelled: WandPairs, tracks: PointTracks | None) -> Samples:
    """The wand's ends, or the point tracks where there is no wand."""
    if len(labelled):
        frame = labelled.frames[labelled.frame]
        return Samples(np.repeat(labelled.camera, 2), np.repeat(frame, 2), labelled.xy.reshape(-1, 2))
    if tracks is not None and len(tracks):
        return Samples(tracks.camera, tracks.frames[tracks.track], tracks.xy)
    return Samples(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 2)))


def _essential(R: np.ndarray, t: np.ndarray, c: int, d: int) -> np.ndarray:
    """E with ``x_c^T E x_d = 0`` for normalised homogeneous x of one point in cameras c and d."""
    Rcd = R[c] @ R[d].T
    tcd = t[c] - Rcd @ t[d]
    skew = np.array([[0, -tcd[2], tcd[1]], [tcd[2], 0, -tcd[0]], [-tcd[1], tcd[0], 0]])
    return skew @ Rcd


@dataclass(frozen=True, eq=False)
class Track:
    """One camera's timed samples by frame: frames (F,) ascending capture frame numbers; count (F,)
    blobs at each (1 or 2; frames with more are left out); xy (F, 2, 2) the blobs (the second a
    copy of the first where there is one); v (F, 2, 2) each blob's image velocity per frame (its
    nearest blobs at the frames before and after), NaN where it has no neighbour."""

    frames: np.ndarray
    count: np.ndarray
    xy: np.ndarray
    v: np.ndarray

    def __len__(self) -> int:
        return len(self.frames)


def camera_track(s: Samples, c: int) -> Track:
    """Camera c's samples as a :class:`Track`."""
    mine = s.camera == c
    frames, xy = s.frame[mine], s.xy[mine]
    order = np.argsort(frames, kind="stable")
    frames, xy = frames[order], xy[order]
    uf, first, count = np.unique(frames, return_index=True, return_counts=True)
    ok = count <= 2
    uf, first, count = uf[ok], first[ok], count[ok]
    pad = np.stack([xy[first], xy[first + count - 1]], axis=1)
    pos = {"before": np.searchsorted(uf, uf - 1), "after": np.searchsorted(uf, uf + 1)}
    near = {}
    for side, found in pos.items():
        at = np.clip(found, 0, len(uf) - 1)
        has = uf[at] == uf + (1 if side == "after" else -1)
        cand = pad[at]  # (F, 2, 2): the neighbour's blobs
        dist = np.linalg.norm(pad[:, :, None, :] - cand[:, None, :, :], axis=3)  # (F, blob, neighbour blob)
        pick = np.argmin(dist, axis=2)
        blob = np.take_along_axis(cand, pick[:, :, None], axis=1)
        near[side] = np.where(has[:, None, None], blob, np.nan)
    both = (near["after"] - near["before"]) / 2
    one_after, one_before = near["after"] - pad, pad - near["before"]
    v = np.where(np.isfinite(both), both, np.where(np.isfinite(one_after), one_after, one_before))
    return Track(uf, count, pad, v)


def _essential_rows(E: np.ndarray, xc: np.ndarray, xd: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For (J, 2) blobs of c and d: the epipolar products x_c^T E x_d, E x_d and E^T x_c (J, 3)."""
    pc, pd = _hom(xc), _hom(xd)
    Ex, Etx = pd @ E.T, pc @ E
    return np.einsum("ji,ji->j", pc, Ex), Ex, Etx


@dataclass(frozen=True, eq=False)
class PairRows:
    """Pair samples: first, second (J,) cameras; value (J,) the Sampson-normalised epipolar
    product; a, b (J,) its derivatives in the first's and the second's offsets (normalised the
    same; NaN where a camera's blob has no velocity)."""

    first: np.ndarray
    second: np.ndarray
    value: np.ndarray
    a: np.ndarray
    b: np.ndarray


def _hom(x: np.ndarray) -> np.ndarray:
    return np.concatenate([x, np.ones((len(x), 1))], axis=1)


def pair_rows(R: np.ndarray, t: np.ndarray, tracks: list[Track], shifts: np.ndarray,
              only: int | None = None) -> PairRows:
    """Every pair of cameras' samples at the same time (of pairs with camera ``only`` where it is
    given), camera c's frames shifted by shifts[c] (its sample at frame k + shifts[c] taken as time
    k). Two blobs a frame (the wand's ends) are matched the way that agrees best."""
    out: list[list[np.ndarray]] = [[], [], [], [], []]
    n = len(tracks)
    for c in range(n):
        for d in range(c + 1, n):
            if only is not None and only not in (c, d):
                continue
            tc, td = tracks[c], tracks[d]
            _, ic, id_ = np.intersect1d(tc.frames - int(shifts[c]), td.frames - int(shifts[d]), assume_unique=True,
                                        return_indices=True)
            same = tc.count[ic] == td.count[id_]
            ic, id_ = ic[same], id_[same]
            if not len(ic):
                continue
            E = _essential(R, t, c, d)
            xc, xd, vc, vd = tc.xy[ic], td.xy[id_].copy(), tc.v[ic], td.v[id_].copy()
            straight = np.abs(_essential_rows(E, xc[:, 0], xd[:, 0])[0]) + np.abs(_essential_rows(E, xc[:, 1], xd[:, 1])[0])
            crossed = np.abs(_essential_rows(E, xc[:, 0], xd[:, 1])[0]) + np.abs(_essential_rows(E, xc[:, 1], xd[:, 0])[0])
            swap = (crossed < straight) & (tc.count[ic] == 2)
            xd[swap], vd[swap] = xd[swap][:, ::-1], vd[swap][:, ::-1]
            two = tc.count[ic] == 2
            for i in (0, 1):
                sel = np.ones(len(ic), bool) if i == 0 else two
                prod, Ex, Etx = _essential_rows(E, xc[sel, i], xd[sel, i])
                norm = np.sqrt(Ex[:, 0] ** 2 + Ex[:, 1] ** 2 + Etx[:, 0] ** 2 + Etx[:, 1] ** 2)
                good = norm > 0
                out[0].append(np.full(int(good.sum()), c))
                out[1].append(np.full(int(good.sum()), d))
                out[2].append(prod[good] / norm[good])
                out[3].append(-np.einsum("ji,ji->j", vc[sel, i], Ex[:, :2])[good] / norm[good])
                out[4].append(-np.einsum("ji,ji->j", vd[sel, i], Etx[:, :2])[good] / norm[good])
    if not out[0]:
        z = np.zeros(0)
        return PairRows(z.astype(np.int64), z.astype(np.int64), z, z, z)
    first, second, value, a, b = (np.concatenate(v) for v in out)
    return PairRows(first.astype(np.int64), second.astype(np.int64), value, a, b)
