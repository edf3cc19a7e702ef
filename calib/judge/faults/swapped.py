"""Two cameras whose observations are swapped (mislabelled columns, two cameras' files exchanged),
found by solving the rig again with the two cameras' intrinsics exchanged.

When cameras a's and b's observations are swapped, each is calibrated with intrinsics that are
not its own: a's observations came through b's lens. Where their intrinsics differ, the rig fits
its observations better with a's and b's intrinsics exchanged than as rig.json gives them. The
two fits are two models of the same observations with the same parameters (the poses and the
points), so they are compared observation by observation:

- **The test.** Per observation ``g_i = e_given,i^2 - e_exchanged,i^2`` (pixels squared, each
  against its point, :func:`wandcal.calib.judge.residuals.observation_residuals`; the model with
  the smaller expected squared error is the one that made the pixels: Vuong's, or Diebold and
  Mariano's, test of two non-nested fits). Its mean over its standard error, the delete-a-block
  jackknife's over blocks of the capture (:func:`wandcal.calib.judge.faults.leave_one_out.capture_blocks`:
  residuals run on along a track, decision 0069, so rows are not independent), is ``t``, and
  ``t^2 ~ F(1, G - 1)`` on the G blocks. The two fits share every observation: a ratio of their
  residual sums as F(n, n) would take them as independent and not hold its level; the paired
  difference does. The pair is named where the whole rig's gain passes :data:`SWAP_ALPHA`
  (one-sided) and **each** of the two cameras' own gain is positive: a camera with a lens fault
  of its own gains from an exchange that brings its intrinsics nearer its truth, but its partner
  then loses (it fits its images with the faulty camera's intrinsics).
- **The screen.** A re-solve costs a refinement, so only pairs where the exchange already helps
  one of the two cameras without it are solved again: each camera's observations of the points
  the others triangulate (:func:`wandcal.calib.judge.faults.leave_one_out.held_out_views`), its
  pose refitted (:func:`wandcal.calib.judge.faults.screen.resect`) with its own intrinsics and
  with its partner's; a pair goes on where either camera's mean squared residual falls.

Two cameras with the very same intrinsics are not tried: a swap of them changes nothing the data
could show (the solve is a consistent rig with the names exchanged). Rigs of 3 to
:data:`wandcal.calib.judge.faults.leave_one_out.MAX_CAMERAS` cameras only (as the comparison of
:mod:`wandcal.calib.judge.faults.leave_one_out`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.geometry import undistort_by_camera, undistort_points
from wandcal.calib.judge.faults.f_distribution import f_survival
from wandcal.calib.judge.faults.leave_one_out import (
    MAX_CAMERAS,
    MIN_VIEWS,
    HeldOut,
    capture_blocks,
    held_out_views,
    seen_again,
)
from wandcal.calib.judge.faults.screen import resect
from wandcal.calib.judge.residuals import Residuals, observation_residuals
from wandcal.calib.observations import PointTracks, WandPairs
from wandcal.calib.rig import Rig

# one-sided level of the exchange's gain: the lens pattern's (leave_one_out.LENS_ALPHA).
# bench_real_subsamples' 240 clean runs try at most six pairs each; where intrinsics differ the
# given labels' expected gain is negative, not zero, and each camera's own gain must be positive too
SWAP_ALPHA = 1e-4
# ... and takes this share of the pair's squared residual away: the lens pattern's (leave_one_out.
# LENS_SHARE). Any change of intrinsics that leans the way of another fault gains a little, and
# consistently: Ushichka's cam2 and cam3 (k1 0.003 apart) exchanged beside cam1's fy 3% off gained
# t 4.5 for 1% of their residual; the swaps found take 40-90% of it
SWAP_SHARE = 0.25
# a half of the exchange that loses by this many standard errors (one-sided 2.3%) speaks against a
# swap: MultiCamSelfCal's true swap has one half at t -0.8 (the other camera still bends the solve)
HALF_LOSS_T = 2.0
MIN_BLOCKS = 4  # blocks of the capture before the jackknife's error is taken as an error

# a solve of the rig again: (rig, labelled, tracks, R, t) -> (R, t), the caller's refinement (the
# judge does not import the run layer); it may raise CalibrationError or LinAlgError
Solve = Callable[[Rig, WandPairs, "PointTracks | None", np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class Gain:
    """The exchange's gain: ``mean_px2`` per observation in squared pixels (positive: the
    exchanged intrinsics fit better), ``std_px2`` its block-jackknife standard error, ``blocks`` G,
    ``observations`` compared."""

    mean_px2: float
    std_px2: float
    blocks: int
    observations: int

    @property
    def t(self) -> float:
        return self.mean_px2 / self.std_px2 if self.std_px2 > 0 else 0.0

    @property
    def p(self) -> float:
        """One-sided p-value of a positive gain: t^2 ~ F(1, G - 1)."""
        if self.mean_px2 <= 0 or self.blocks < MIN_BLOCKS or not self.std_px2 > 0:
            return 1.0
        return 0.5 * f_survival(1, self.blocks - 1, self.t**2)


@dataclass(frozen=True)
class Swap:
    """A pair judged by the re-solve: cameras a, b; the whole rig's gain and each camera's own;
    ``halves``: the rig's gain with a given b's intrinsics alone, and b a's alone (None: not tried)."""

    a: int
    b: int
    rig: Gain
    own_a: Gain
    own_b: Gain
    rms_given_px: tuple[float, float]  # a's and b's RMS residual as given, and exchanged below
    rms_exchanged_px: tuple[float, float]
    explained: float = 0.0  # the share of the pair's squared residual the exchange takes away
    halves: tuple[Gain, Gain] | None = None

    @property
    def significant(self) -> bool:
        """The whole exchange fits the rig better at :data:`SWAP_ALPHA` and explains
        :data:`SWAP_SHARE` of the pair's squared residual."""
        return self.rig.p < SWAP_ALPHA and self.explained >= SWAP_SHARE

    @property
    def found(self) -> bool:
        """Significant, and neither half of the exchange loses by more than :data:`HALF_LOSS_T` of
        its standard errors: one camera's lens fault gains from the half that corrects it, and loses
        from the half that gives its wrong intrinsics to its partner; in a swap each half corrects
        one camera (its gain may be small: the other still bends the solve)."""
        return self.significant and self.halves is not None and min(h.t for h in self.halves) > -HALF_LOSS_T


def block_gain(g: np.ndarray, block: np.ndarray) -> Gain:
    """The mean of g (K,) and its delete-a-block jackknife standard error over ``block`` (K,)."""
    if not len(g):
        return Gain(0.0, 0.0, 0, 0)
    ids, inverse = np.unique(block, return_inverse=True)
    G = len(ids)
    sums, counts = np.bincount(inverse, g, G), np.bincount(inverse, minlength=G).astype(float)
    total, n = float(sums.sum()), float(counts.sum())
    left = (total - sums) / np.maximum(n - counts, 1.0)
    d = left - left.mean()
    return Gain(total / n, float(np.sqrt((G - 1) / G * float(d @ d))), G, int(n))


def exchanged(rig: Rig, labelled: WandPairs, tracks: PointTracks | None, a: int, b: int, both: bool = True
              ) -> tuple[Rig, WandPairs, PointTracks | None]:
    """The rig with cameras a's and b's intrinsics (K, distortion, model) exchanged (``both``), or
    a given b's alone (half the exchange), and the observations normalised again from their raw
    pixels with them."""
    cams = list(rig.cameras)
    ca, cb = rig.cameras[a], rig.cameras[b]
    cams[a] = replace(ca, K=cb.K, dist=cb.dist, model=cb.model)
    if both:
        cams[b] = replace(cb, K=ca.K, dist=ca.dist, model=ca.model)
    out = replace(rig, cameras=tuple(cams))
    labelled = replace(labelled, xy=undistort_by_camera(out.cameras, labelled.camera, labelled.uv))
    if tracks is not None and len(tracks):
        tracks = replace(tracks, xy=undistort_by_camera(out.cameras, tracks.camera, tracks.uv))
    return out, labelled, tracks


def _alike(rig: Rig, a: int, b: int) -> bool:
    """Cameras a and b have the very same intrinsics: an exchange changes nothing."""
    ca, cb = rig.cameras[a], rig.cameras[b]
    return ca.model == cb.model and np.array_equal(ca.K, cb.K) and np.array_equal(np.asarray(ca.dist), np.asarray(cb.dist))


def _seen_through(labelled: WandPairs, tracks: PointTracks | None, c: int, lens) -> tuple[WandPairs, PointTracks | None]:
    """The observations with camera c's alone normalised again from its raw pixels through ``lens``
    (another camera's intrinsics); the others' as they are, so that the points they triangulate
    stay those of the solve."""
    mine = labelled.camera == c
    xy = labelled.xy.copy()
    xy[mine] = undistort_points(lens, labelled.uv[mine].reshape(-1, 2)).reshape(-1, 2, 2)
    labelled = replace(labelled, xy=xy)
    if tracks is not None and len(tracks):
        txy = tracks.xy.copy()
        txy[tracks.camera == c] = undistort_points(lens, tracks.uv[tracks.camera == c])
        tracks = replace(tracks, xy=txy)
    return labelled, tracks


def _resected_ms(R: np.ndarray, t: np.ndarray, held: HeldOut, focal: float) -> float:
    """Mean squared residual, pixels^2 at ``focal``, of a camera's pose refitted to ``held``."""
    _, _, r, keep = resect(R, t, held.X, held.xy)
    return float(np.mean(np.sum((r[keep] * focal) ** 2, axis=1))) if keep.sum() >= MIN_VIEWS else np.inf


def screened_pairs(rig: Rig, R: np.ndarray, t: np.ndarray, labelled: WandPairs, tracks: PointTracks | None,
                   held: list[HeldOut] | None = None) -> list[tuple[int, int]]:
    """Pairs (a < b) of cameras with intrinsics that differ where the exchange lowers either
    camera's mean squared residual against the points the others triangulate, its pose refitted.
    held: every camera's :func:`held_out_views` of these R, t and observations, where already made.
    The points the others triangulate do not read camera c's views, so c seen through another
    lens is judged against c's own held-out points (:func:`seen_again`): one triangulation a camera."""
    n = len(rig.cameras)
    views = [held_out_views(R, t, labelled, tracks, c) for c in range(n)] if held is None else held
    own = [_resected_ms(R[c], t[c], views[c], float(rig.cameras[c].focal.mean())) if len(views[c].X) >= MIN_VIEWS
           else np.inf for c in range(n)]
    out = []
    for a in range(n):
        for b in range(a + 1, n):
            if _alike(rig, a, b):
                continue
            for c, d in ((a, b), (b, a)):
                if not np.isfinite(own[c]):
                    continue
                through = seen_again(views[c], *_seen_through(labelled, tracks, c, rig.cameras[d]))
                if len(through.X) >= MIN_VIEWS and _resected_ms(R[c], t[c], through,
                                                                float(rig.cameras[d].focal.mean())) < own[c]:
                    out.append((a, b))
                    break
    return out


def _keys(res: Residuals, n: int) -> np.ndarray:
    """(M,) each observation's (point, camera) as one integer (a point track's point is negative)."""
    return (res.point.astype(np.int64) + 2**40) * n + res.camera


def _blocks(res: Residuals, labelled: WandPairs, tracks: PointTracks | None) -> np.ndarray:
    """(M,) each observation's block of the capture (:func:`capture_blocks`): the wand's rows by
    their frame, the point tracks' by theirs (timed where there is no wand)."""
    wand = res.point >= 0
    frame = np.zeros(len(res.point), np.int64)
    if len(labelled):
        frame[wand] = labelled.frames[res.point[wand] // 2]
    if tracks is not None and len(tracks):
        frame[~wand] = tracks.frames[-1 - res.point[~wand]]
    return capture_blocks(frame, wand if len(labelled) else np.ones(len(frame), bool))


def judge_swap(given: Residuals, swapped: Residuals, labelled: WandPairs, tracks: PointTracks | None,
               a: int, b: int) -> Swap:
    """The pair (a, b) judged from the residuals as given and with their intrinsics exchanged (the
    rig solved again): the whole rig's gain and each camera's own (:class:`Swap`). Observations
    that are gross outliers in either fit are left out."""
    n = int(max(given.camera.max(initial=0), swapped.camera.max(initial=0))) + 1
    rows = {int(k): i for i, k in enumerate(_keys(swapped, n))}
    j = np.array([rows.get(int(k), -1) for k in _keys(given, n)], np.int64)
    ok = (j >= 0) & ~given.outlier
    ok[ok] &= ~swapped.outlier[j[ok]]
    e0, e1 = given.error_px, np.where(j >= 0, swapped.error_px[np.maximum(j, 0)], np.nan)
    g = e0**2 - e1**2
    ok &= np.isfinite(g)
    block = _blocks(given, labelled, tracks)

    def gain(mask: np.ndarray) -> Gain:
        return block_gain(g[mask], block[mask])

    def rms(e: np.ndarray, c: int) -> float:
        m = ok & (given.camera == c)
        return float(np.sqrt(np.mean(e[m] ** 2))) if m.any() else float("nan")
    pair = ok & np.isin(given.camera, (a, b))
    explained = float(g[pair].sum() / (e0[pair] ** 2).sum()) if pair.any() and (e0[pair] ** 2).sum() > 0 else 0.0
    return Swap(a, b, gain(ok), gain(ok & (given.camera == a)), gain(ok & (given.camera == b)),
                (rms(e0, a), rms(e0, b)), (rms(e1, a), rms(e1, b)), explained)


def swapped_pair(rig: Rig, labelled: WandPairs, tracks: PointTracks | None, R: np.ndarray, t: np.ndarray,
                 solve: Solve, held: list[HeldOut] | None = None) -> Swap | None:
    """The pair of cameras whose observations look swapped (:class:`Swap`, ``found``), the most
    significant of the screened pairs (:func:`screened_pairs`), each solved again with ``solve``;
    None where none is found or the rig is not of 3 to :data:`MAX_CAMERAS` cameras. held: as
    :func:`screened_pairs` takes it."""
    n = len(rig.cameras)
    if not 3 <= n <= MAX_CAMERAS:
        return None
    pairs = screened_pairs(rig, R, t, labelled, tracks, held)
    if not pairs:
        return None
    try:  # the given intrinsics solved again the same way, so that the two fits differ by the exchange alone
        R0, t0 = solve(rig, labelled, tracks, R, t)
    except (CalibrationError, np.linalg.LinAlgError):
        return None
    given = observation_residuals(R0, t0, labelled, tracks, np.array([c.focal for c in rig.cameras]))
    best = None
    for a, b in pairs:
        found = _judged(rig, labelled, tracks, R, t, solve, given, a, b)
        if found is None or not found.significant:
            continue
        first = _judged(rig, labelled, tracks, R, t, solve, given, a, b, both=False)
        second = _judged(rig, labelled, tracks, R, t, solve, given, b, a, both=False)
        if first is None or second is None:
            continue
        found = replace(found, halves=(first.rig, second.rig))
        if found.found and (best is None or found.rig.t > best.rig.t):
            best = found
    return best


def _judged(rig: Rig, labelled: WandPairs, tracks: PointTracks | None, R: np.ndarray, t: np.ndarray, solve: Solve,
            given: Residuals, a: int, b: int, both: bool = True) -> Swap | None:
    """:func:`judge_swap` of the rig solved again with a's and b's intrinsics :func:`exchanged`
    (``both``, else a given b's alone); None where that solve fails."""
    rig2, lab2, tr2 = exchanged(rig, labelled, tracks, a, b, both)
    try:
        R2, t2 = solve(rig2, lab2, tr2, R, t)
    except (CalibrationError, np.linalg.LinAlgError):
        return None
    return judge_swap(given, observation_residuals(R2, t2, lab2, tr2, np.array([c.focal for c in rig2.cameras])),
                      labelled, tracks, a, b)


def swap_faults(rig: Rig, labelled: WandPairs, tracks: PointTracks | None, R: np.ndarray, t: np.ndarray,
                solve: Solve, held: list[HeldOut] | None = None) -> list[dict]:
    """The swapped pair (:func:`swapped_pair`) as two ``intrinsics`` faults, one on each camera,
    whose message says that their observations look swapped (``{"kind", "camera", "message",
    "evidence"}``, evidence ``swap``); empty where none is found. held: as :func:`screened_pairs` takes it."""
    found = swapped_pair(rig, labelled, tracks, R, t, solve, held)
    if found is None:
        return []
    ids = [rig.cameras[found.a].id, rig.cameras[found.b].id]
    g = found.rig
    evidence = {"swap": {"cameras": ids, "rms_given_px": [round(x, 3) for x in found.rms_given_px],
                         "rms_exchanged_px": [round(x, 3) for x in found.rms_exchanged_px],
                         "gain_px2": round(g.mean_px2, 4), "gain_std_px2": round(g.std_px2, 4),
                         "t": round(g.t, 2), "p": float(f"{g.p:.3g}"), "blocks": g.blocks,
                         "explained_share": round(found.explained, 3)}}
    out = []
    for k, cam in enumerate(ids):
        other = ids[1 - k]
        out.append({"kind": "intrinsics", "camera": cam, "evidence": evidence, "message": (
            f"{cam} and {other} look swapped: the rig fits their observations better with their intrinsics "
            f"exchanged ({cam} {found.rms_given_px[k]:.2f} -> {found.rms_exchanged_px[k]:.2f} px RMS, {other} "
            f"{found.rms_given_px[1 - k]:.2f} -> {found.rms_exchanged_px[1 - k]:.2f} px; t = {g.t:.1f} over "
            f"{g.blocks} blocks of the capture): check which camera's file or column is which, or whether "
            f"rig.json gives {cam}'s intrinsics to {other}, then calibrate again")})
    return out
