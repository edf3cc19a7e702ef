"""Each camera's wand track over time, and its blobs resampled at other instants.

A camera's two wand ends are followed from frame to frame by proximity, so the same physical end
is interpolated; the interpolation is a cubic through four frames, a line through two at gaps
(:func:`interpolate`). Used by :mod:`wandcal.calib.solve.sync` to bring each camera's frames to
the reference camera's instants.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.observations import WandPairs

SMALL = 1e-9  # an instant within this of a frame is that frame
# a camera with fewer of its wand frames between two others is held at its whole-frame offset:
# a digitised session (easyWand's: every 10th frame, or where the wand was clear) has no track to
# interpolate, and a simulated or recorded one has 90% or more
DENSE_SHARE = 0.5
# and one whose track is rougher than this (median distance of an end from the cubic through its
# neighbouring frames) has frames too far apart in time to interpolate: 0.5 px on a simulated
# rig at 0.3 px noise, 600-1000 px on the Brown wind-tunnel sessions, digitised frame by frame apart
ROUGH_PX = 5.0
# two consecutive frames' ends are matched when one matching moves them this many times less than
# the other: a wand seen end-on (ends ~8 px apart) moving ~6 px a frame was matched crosswise, and
# the few such frames, the fastest, held the offsets 2-3 standard errors off when not cut as outliers
MATCH_MARGIN = 2.0


@dataclass(frozen=True, eq=False)
class TrackSmoothness:
    """Each camera's wand track judged for interpolation in time (what ``--sync auto`` needs to fit
    a fraction of a frame): ``dense_share`` (N,) the share of its frames with a frame on either side,
    ``rough_px`` (N,) the median distance, pixels, of an end from the cubic through its four
    neighbouring frames ((-p[-2] + 4 p[-1] + 4 p[1] - p[2]) / 6; NaN where no frame has all four)."""

    dense_share: np.ndarray
    rough_px: np.ndarray

    @property
    def interpolable(self) -> np.ndarray:
        """(N,) bool: at least ``DENSE_SHARE`` of the frames between two others and a track smoother
        than ``ROUGH_PX``."""
        with np.errstate(invalid="ignore"):
            return (self.dense_share >= DENSE_SHARE) & (self.rough_px < ROUGH_PX)

    def why_not(self, c: int) -> str:
        """Why camera c's track cannot be interpolated, with its figure beside the limit ("" where it can)."""
        if self.dense_share[c] < DENSE_SHARE:
            return (f"only {self.dense_share[c]:.0%} of its wand frames have a frame on either side (it needs "
                    f"{DENSE_SHARE:.0%}): the wand was digitised or seen in frames too far apart")
        if not self.rough_px[c] < ROUGH_PX:
            if not np.isfinite(self.rough_px[c]):
                return "none of its wand frames has two frames on either side to follow the wand through"
            return (f"its wand moves too far between frames to follow: an end lies {self.rough_px[c]:.1f} px from "
                    f"the curve through its neighbouring frames (median; the limit is {ROUGH_PX:g} px)")
        return ""


def track_smoothness(pairs: WandPairs, focal: np.ndarray, tracks: Tracks | None = None,
                     rows: np.ndarray | None = None) -> TrackSmoothness:
    """Each camera's :class:`TrackSmoothness`: the test by which ``--sync auto`` holds a camera at its
    whole-frame offset (:func:`wandcal.calib.solve.sync.fit.fit_timing`).

    Args:
        pairs: labelled wand pairs; focal: (N, 2) pixels (or (N, 1)); tracks: their tracks, when
        already built; rows: the pair rows judged (default all; a fit judges the frames it uses).
    """
    n = len(focal)
    tracks = tracks or Tracks(pairs, n)
    every = pairs.xy  # the neighbouring frames' rows index all the pairs
    parity = tracks.parity
    if rows is not None:
        pairs, parity = pairs.subset(rows), parity[rows]
    f = pairs.frames[pairs.frame] - tracks.first + 1
    span = len(tracks.table)
    idx = f[:, None] + np.array([-2, -1, 1, 2])[None, :]
    inside = (idx >= 0) & (idx < span)
    window = np.where(inside, tracks.table[np.clip(idx, 0, span - 1), pairs.camera[:, None]], -1)
    between = (window[:, 1] >= 0) & (window[:, 2] >= 0)
    count = np.maximum(np.bincount(pairs.camera, minlength=n), 1)
    dense_share = np.bincount(pairs.camera, between, minlength=n) / count
    full: np.ndarray = np.all(window >= 0, axis=1)
    err = np.zeros(len(pairs))
    for e in range(2):
        end = np.repeat(np.logical_xor(parity, bool(e)).astype(np.int64)[:, None], 4, axis=1)
        pts = np.where(full[:, None, None], tracks.track(window, end, every), 0.0)
        pred = (-pts[:, 0] + 4 * pts[:, 1] + 4 * pts[:, 2] - pts[:, 3]) / 6
        err = np.maximum(err, np.linalg.norm((pred - pairs.xy[:, e]) * focal[pairs.camera], axis=1))
    rough = np.array([np.median(err[full & (pairs.camera == c)]) if (full & (pairs.camera == c)).any() else np.nan
                      for c in range(n)])
    return TrackSmoothness(dense_share, rough)


class Tracks:
    """Each camera's wand ends over time, in an order continuous from frame to frame.

    Camera c's ends at consecutive frames are matched by proximity (a frame moves an end a few
    pixels, the two ends lie tens to hundreds apart), so end e of pair row p is the track's end
    ``e ^ parity[p]``.
    """

    def __init__(self, pairs: WandPairs, n: int) -> None:
        self.pairs = pairs
        f = pairs.frames[pairs.frame]
        self.first = int(f.min()) if len(f) else 0
        span = int(f.max()) - self.first + 1 if len(f) else 0
        self.table = np.full((span + 2, n), -1, np.int64)  # a spare row each side: neighbours past the ends are absent
        self.table[f - self.first + 1, pairs.camera] = np.arange(len(pairs))
        self.parity = np.zeros(len(pairs), bool)
        order = np.lexsort((f, pairs.camera))
        cam, fs, xy = pairs.camera[order], f[order], pairs.xy[order]
        same = np.linalg.norm(xy[1:] - xy[:-1], axis=2).sum(1)
        cross = np.linalg.norm(xy[1:] - xy[:-1, ::-1], axis=2).sum(1)
        # consecutive frames whose ends the proximity cannot tell apart (the wand foreshortened to a
        # few pixels and moving about as far a frame) are not linked: the track breaks there
        clear = np.maximum(same, cross) >= MATCH_MARGIN * np.minimum(same, cross)
        nxt = (cam[1:] == cam[:-1]) & (fs[1:] == fs[:-1] + 1) & clear
        flip = np.concatenate([[False], nxt & (cross < same)])
        # parity accumulates along each linked run of a camera's frames; a neighbour in another run
        # is not interpolated with (resample)
        run = np.concatenate([[0], np.cumsum(~np.concatenate([[False], nxt])[1:])])
        self.run = np.zeros(len(pairs), np.int64)
        self.run[order] = run
        parity = np.cumsum(flip) % 2
        start_parity = np.zeros(run.max() + 1, np.int64)
        first_of_run = np.concatenate([[True], ~nxt])
        start_parity[run[first_of_run]] = parity[first_of_run] - flip[first_of_run]
        self.parity[order] = ((parity - start_parity[run]) % 2).astype(bool)

    def resample(self, phase: np.ndarray, drift: np.ndarray, centre: np.ndarray, rows: np.ndarray | None = None,
                 pixels: bool = True, velocity: bool = False, markers: tuple[np.ndarray, np.ndarray] | None = None):
        """(xy (Q, 2, 2), velocity (Q, 2, 2) normalised units a frame, keep (Q,), uv (Q, 2, 2),
        spread (Q,)) of the pair rows ``rows`` (Q,) (default all), each camera c's frame f sampled
        at f - phi_c(f), phi_c(f) = phase[c] + drift[c] (f - centre[c]) (all (N,), frames);
        spread is the resampled blobs' share of a blob's noise variance (:func:`interpolate`).
        ``pixels=False`` leaves uv at zero and keeps only the cubic's values (a fit's; the
        calibration keeps the lines through gaps too); ``pixels=True`` leaves the velocity at zero
        unless ``velocity`` (the offsets refined in the bundle adjustment, :mod:`.joint`).
        ``markers``: (xy, uv), each (P, K, 2), every marker of a multi-marker wand's rows, end 0
        first and end K-1 last as the pairs' ends: resampled instead of the ends (the shapes then
        (Q, K, 2)); a neighbouring frame whose ends are the other way round is read backwards."""
        p = self.pairs if rows is None else self.pairs.subset(rows)
        parity = self.parity if rows is None else self.parity[rows]
        f = p.frames[p.frame].astype(float)
        phi = phase[p.camera] + drift[p.camera] * (f - centre[p.camera])
        tau = f - phi - self.first + 1
        i0 = np.floor(tau + SMALL).astype(np.int64)
        u = np.clip(tau - i0, 0.0, 1.0)
        u[u < SMALL] = 0.0
        span = len(self.table)
        idx = i0[:, None] + np.arange(-1, 3)[None, :]  # (P, 4) frames i0-1 .. i0+2
        inside = (idx >= 0) & (idx < span)
        window = np.where(inside, self.table[np.clip(idx, 0, span - 1), p.camera[:, None]], -1)
        centre_row = np.where(window[:, 1] >= 0, window[:, 1], window[:, 2])
        window = np.where((window >= 0) & (self.run[window] == self.run[centre_row][:, None]), window, -1)
        # row q's end e is the track's end e ^ parity[q], whichever frame holds it: both ends (and
        # their pixels) interpolated in one pass, (Q, 4, 4 or 8)
        ok_row = window >= 0
        r = np.where(ok_row, window, 0)
        e0 = parity[:, None] ^ self.parity[r]
        every_xy, every_uv = markers if markers is not None else (self.pairs.xy, self.pairs.uv)
        k = every_xy.shape[1]
        # marker j of row q is the neighbour's marker j, or K-1-j where their end order differs
        column = np.where(e0[..., None], k - 1 - np.arange(k), np.arange(k))  # (Q, 4, K)
        parts = [every_xy[r, column[..., j]] for j in range(k)]
        if pixels:
            parts += [every_uv[r, column[..., j]] for j in range(k)]
        pts = np.where(ok_row[..., None], np.concatenate(parts, axis=2), np.nan)
        value, slope, keep, spread = interpolate(pts, u, strict=not pixels, slopes=velocity or not pixels)
        xy, vel = value[:, : 2 * k].reshape(-1, k, 2), slope[:, : 2 * k].reshape(-1, k, 2)
        uv = value[:, 2 * k :].reshape(-1, k, 2) if pixels else np.zeros((len(p), k, 2))
        return xy, vel, keep, uv, spread

    def track(self, rows: np.ndarray, end: np.ndarray, what: np.ndarray) -> np.ndarray:
        """(P, 4, 2) the track end ``end`` (P, 4) (in the track's continuous order) at each row of
        ``rows`` (P, 4), NaN where absent."""
        ok = rows >= 0
        r = np.where(ok, rows, 0)
        e = end ^ self.parity[r]
        out = what[r, e]
        return np.where(ok[..., None], out, np.nan)


def _slope(have: np.ndarray, filled: np.ndarray) -> np.ndarray:
    """(P, D) the secant over the outer two samples, else the nearest secant there is (see
    :func:`interpolate`)."""
    slope = np.where((have[:, 0] & have[:, 3])[:, None], (filled[:, 3] - filled[:, 0]) / 3, 0.0)
    for lo, hi in ((1, 3), (0, 2), (1, 2), (0, 1)):
        fill = ~(have[:, 0] & have[:, 3]) & have[:, lo] & have[:, hi] & np.all(slope == 0, axis=1)
        slope = np.where(fill[:, None], (filled[:, hi] - filled[:, lo]) / (hi - lo), slope)
    return slope


def interpolate(pts: np.ndarray, u: np.ndarray, strict: bool = False, slopes: bool = True):
    """Value and slope (per frame) at i0 + u from samples at i0-1 .. i0+2 (P, 4, D), a sample
    present in all D columns or in none.

    The value is the cubic through the four where all four are there, else the line through
    i0 and i0 + 1, else at u = 0 the sample itself. The slope is the secant over the outer two,
    (p[i0+2] - p[i0-1]) / 3, else the nearest secant there is: a slope taken from the same
    samples as the value would share their noise, and the offset regressed on it would be
    biased (by sigma^2 / |v|^2 x 0.5 frame at u = 0, 0.001-0.003 frame at 0.3 px); the cubic's
    outer weights are small and nearly equal, so its value and this slope hardly share any.
    ``strict`` keeps only the cubic's values (and the samples themselves): a line through a
    gap is off by up to an eighth of the acceleration, along it, which an offset fitted to them
    partly takes up. ``slopes=False`` leaves the slope at zero (the calibration's resampling).
    Returns (value, slope, ok, spread): spread (P,) is the value's share of a sample's noise
    variance (1 at a frame, 0.64 half-way between two by the cubic), though over consecutive
    frames the values' noise adds up to a whole sample's again (the weights sum to 1)."""
    uu = u[:, None]
    w = np.stack([-uu * (uu - 1) * (uu - 2) / 6, (uu + 1) * (uu - 1) * (uu - 2) / 2,
                  -(uu + 1) * uu * (uu - 2) / 2, (uu + 1) * uu * (uu - 1) / 6], axis=1)  # Lagrange weights (P, 4, 1)
    have = np.isfinite(pts[..., 0])
    filled = np.where(have[..., None], pts, 0.0)
    cubic = have.all(1)
    line = have[:, 1] & have[:, 2]
    value = np.where(cubic[:, None], np.einsum("pj,pjd->pd", w[:, :, 0], filled),
                     filled[:, 1] + uu * (filled[:, 2] - filled[:, 1]))
    at_frame = (u == 0) & have[:, 1] & ~line
    value = np.where(at_frame[:, None], filled[:, 1], value)
    # the value's share of one sample's noise variance: the sum of its weights' squares
    spread = np.where(cubic, (w[:, :, 0] ** 2).sum(1), np.where(line, (1 - u) ** 2 + u**2, 1.0))
    slope = _slope(have, filled) if slopes else np.zeros_like(value)
    ok = cubic | line | at_frame
    exact = cubic | ((u == 0) & have[:, 1])  # no line through a gap: its error follows the acceleration
    return value, slope, np.where(strict, exact, ok), spread
