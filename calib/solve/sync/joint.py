"""The time offsets refined inside the bundle adjustment, over every wand frame.

:func:`~wandcal.calib.solve.sync.fit.fit_timing` fits the offsets on at most ``MAX_FIT_FRAMES``
frames; the frames are then resampled with them and ``ba`` solves the rig from all of them. What
the fit's offsets still miss (~0.003 frame at 16 x 2500, every frame the same way) is left as a
per-camera error of ``dt v`` pixels along each blob's image velocity v. Here ``ba`` takes one more
column per camera (:class:`wandcal.calib.solve.reprojection.TimeFit`): the observation of a camera whose
offset moves by dt is ``xy - dt v``, so its residual moves by ``+dt v`` (pixels), and poses, wand
ends and offsets are solved together. The reference camera's offset stays at 0 (the gauge: a
common shift of all cameras is the wand's own time). The increments are a few thousandths of a
frame (at most 0.004 at 16 x 2500), and the first-order move differs from resampling the blobs
again by 0.001 px (median; 0.015 px at most), against 0.3 px of blob noise: the frames are not
resampled again (docs/decisions/0022-sync-cost-and-standard-error.md).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from wandcal.calib.observations import WandPairs
from wandcal.calib.solve.reprojection import TimeFit
from wandcal.calib.solve.sync.fit import Timing
from wandcal.calib.solve.sync.tracks import Tracks

# frames either side whose wand gives an end's 3D motion: a resampled blob at frame f is the cubic
# through its camera's samples up to two frames either side of f, so the wand 5 frames away shares
# none of them (with +-1 one 16-camera rig's offsets had a mean z^2 of 5.9, 0.4 with 5); the
# motion's own error there (the path's third derivative) only scales a column by a few percent
SPAN = 5


class TimeColumns:
    """Each resampled observation's image velocity, for the offsets' columns in ``ba``.

    Args:
        pairs: the labelled pairs **before** resampling; tracks: ``Tracks(pairs, N)``.
        timing: the fitted offsets; focal: (N, 2) pixels.

    After construction ``resampled`` holds the pairs brought to the reference instants (as
    :func:`wandcal.calib.solve.sync.fit.resample`), ``keep`` (P,) the rows that could be.
    Calling it with a refinement's ``Setup`` gives the :class:`TimeFit` of its observations.
    """

    def __init__(self, pairs: WandPairs, tracks: Tracks, timing: Timing, focal: np.ndarray) -> None:
        xy, vel, keep, uv, spread = tracks.resample(timing.phase, timing.drift, timing.centre, velocity=True)
        self.resampled = WandPairs(pairs.frame, pairs.camera, xy, uv, pairs.frames, pairs.dropped).subset(keep)
        self.keep = keep
        self.timing = timing
        self.tracks = tracks
        p = self.resampled
        # (P, 2, 2) each end's image velocity in pixels a frame (the secant over the outer two of
        # the cubic's samples: :func:`~wandcal.calib.solve.sync.tracks.interpolate`)
        self.velocity = vel[keep] * focal[p.camera][:, None, :]
        self.spread = spread[keep]
        f = p.frames[p.frame]
        self.first = int(f.min()) if len(f) else 0
        self.table = np.full((int(f.max()) - self.first + 1 if len(f) else 0, len(focal)), -1, np.int64)
        self.table[f - self.first, p.camera] = np.arange(len(p))
        self.held = timing.held.copy() if timing.held is not None else np.zeros(len(focal), bool)
        self.share = 1.0

    def markers(self, xy: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Every marker of a multi-marker wand's rows brought to the reference instants as the
        ends are: ``xy`` (P, K, 2) normalised and ``uv`` (P, K, 2) pixels, the pairs' rows with
        their end 0 first and end 1 last; returns (xy, uv) (Q, K, 2) of the rows ``resampled``
        holds (``keep``)."""
        t = self.timing
        out_xy, _, _, out_uv, _ = self.tracks.resample(t.phase, t.drift, t.centre, markers=(xy, uv))
        return out_xy[self.keep], out_uv[self.keep]

    def rows(self, setup) -> tuple[np.ndarray, np.ndarray]:
        """(row (M,), end (M,)) of each observation of ``setup`` (a refinement's problem, any subset
        of the resampled pairs) in ``resampled``: its camera and capture frame name the row, its
        raw pixels the end (the setup's end may have been relabelled)."""
        p = setup.problem
        row = self.table[setup.frames[p.frame] - self.first, p.camera]
        uv = self.resampled.uv[row]
        d0 = np.sum((uv[:, 0] - setup.uv) ** 2, axis=1)
        d1 = np.sum((uv[:, 1] - setup.uv) ** 2, axis=1)
        return row, (d1 < d0).astype(np.int64)

    def __call__(self, setup) -> TimeFit | None:
        """The offsets' columns for ``setup``'s observations; None for a wand of more than two
        markers (its interior markers have no track of their own here).

        Each observation's velocity is the wand end's 3D motion at its frame (the central
        difference of the setup's start wand ``SPAN`` frames either side) projected into its
        camera: so every camera's column is the image of one motion, and a shift common to all
        cameras stays the wand's own time. Each camera's own track secant carries that camera's
        blob noise; with it the columns disagreed, and holding the reference left every other
        camera 2-3 standard errors off together (docs/decisions/0022-sync-cost-and-standard-error.md).
        Where one of those frames is not in the setup, the track's secant."""
        p, model = setup.problem, setup.model
        if p.along is not None or not len(p.camera):
            return None
        row, end = self.rows(setup)
        # the resampled blobs' share of a blob's noise variance, over the observations ba uses
        self.share = float(np.mean(self.spread[row]))
        wand = model.wand(model.x0())  # (F, 2, 3) metres
        motion = _wand_motion(wand, setup.frames)
        X, dX = wand[p.frame, p.end], motion[p.frame, p.end]
        R, t = model.R0[p.camera], model.t0[p.camera]
        xc = np.einsum("mij,mj->mi", R, X) + t
        dxc = np.einsum("mij,mj->mi", R, dX)
        v = (dxc[:, :2] - xc[:, :2] / xc[:, 2:3] * dxc[:, 2:3]) / xc[:, 2:3] * p.focal[p.camera]
        v = np.where(np.isfinite(v).all(axis=1)[:, None], v, self.velocity[row, end])
        return TimeFit(v, self.held)

    def folded(self, dt: np.ndarray | None, std: np.ndarray | None) -> Timing:
        """The fitted offsets with ``ba``'s increments ``dt`` (N,) frames added, and each offset's
        variance from ``ba``'s covariance: ``std`` (N,) its standard error there, scaled by the blob
        noise before resampling over the resampled residuals' (ba's sigma is of the resampled
        blobs, whose own noise is ``share`` of a blob's, though consecutive ones add up to a whole
        blob's: :mod:`wandcal.calib.solve.sync.fit`). The fit's as it was when ``dt`` is None."""
        t = self.timing
        if dt is None or std is None:
            return t
        var = (std / np.sqrt(self.share)) ** 2
        cov = t.cov.copy()
        old = np.sqrt(np.maximum(cov[:, 0, 0], 0.0))
        # the phase's new standard error; its covariance with the drift scaled alike
        ratio = np.where(old > 0, np.sqrt(var) / np.where(old > 0, old, 1.0), 0.0)
        cov[:, 0, 0] = var
        cov[:, 0, 1] *= ratio
        cov[:, 1, 0] *= ratio
        return replace(t, phase=t.phase + dt, cov=cov)


def _wand_motion(wand: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """(F, 2, 3) each wand end's motion, metres a frame: the difference of its positions ``SPAN``
    frames either side over 2 ``SPAN`` (capture frame numbers ``frames`` (F,)), those frames' ends
    matched by proximity (a frame's end order is its own); NaN where one is missing."""
    F = len(frames)
    out = np.full_like(wand, np.nan)
    if not F:
        return out
    lo = int(frames.min())
    index = np.full(int(frames.max()) - lo + 1 + 2 * SPAN, -1)
    index[frames - lo + SPAN] = np.arange(F)
    before, after = index[frames - lo], index[frames - lo + 2 * SPAN]
    both = (before >= 0) & (after >= 0)

    def matched(k: np.ndarray) -> np.ndarray:
        w = wand[k]
        same = np.linalg.norm(w - wand[both], axis=2).sum(1)
        cross = np.linalg.norm(w[:, ::-1] - wand[both], axis=2).sum(1)
        return np.where((cross < same)[:, None, None], w[:, ::-1], w)

    out[both] = (matched(after[both]) - matched(before[both])) / (2 * SPAN)
    return out
