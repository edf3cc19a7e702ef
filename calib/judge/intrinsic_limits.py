"""How far a camera's position hinges on the intrinsics that were given, not refined: the honest sigma.

The geometry sigma of a solve (:mod:`wandcal.calib.solve.gauge_free`) treats the intrinsics in
rig.json as exact. Real ones are not: a nominal lens focal length, or one from a calibration of
another day, is off by one or a few per cent (the published eWand session's refined focal lengths
lie 1.2-2.6% above its own yaml files), and a camera given a focal length off by ``d`` moves along
its axis by about ``d`` times its distance from the points, to keep its image's scale: on the Brown
wind-tunnel sessions 3-4 mm for each 1%, ten to twenty times their geometry sigma.

Each camera's pose is refitted, to first order, to the points it sees (with the final poses) with a
focal length ``1 + d`` times its own: the observations' normalised coordinates scale by ``1 / (1 + d)``,
so the pose must take up ``-d x`` (x: (K, 2) the projected points). Least squares of that column on
the pose's six (:func:`wandcal.calib.judge.faults.screen._pose_columns`) gives the pose's change, hence the
centre's, per unit of ``d``. The honest sigma adds that change, times the focal length's own
relative sigma, to the geometry sigma in quadrature. The focal length's sigma is rig.json's
``focal_std_px`` where the camera gives one, else :data:`DEFAULT_FOCAL_REL_STD`.

The judgement's lens screens do not shrink that sigma: on Brown 1 and 2 a focal length 3% off went
unseen (the pose and the points took it up) although the camera's own residuals would give its
focal length to 0.1-0.2%.

The same fit with the focal column beside the pose's says whether the data could determine the
focal length (its standard error from the residual's scatter): then ``--refine-intrinsics focal``
is the advice, else a lens calibration.

Every other intrinsic given (cx, cy, k1, k2, p1, p2: :mod:`wandcal.calib.judge.lens_sigmas`) enters the same way
(:func:`lens_limits`): its column is how the observations' normalised coordinates move with the
parameter off by its assumed sigma (:func:`lens_columns`, the pixels undistorted again), its part of
the honest sigma the centre's change for that sigma, and whether the data determine it its standard
error beside the pose, in sigmas (under a quarter of it: determined). The sigmas assumed are measured
(:func:`lens_sigmas`; docs/verdict.md, "The honest sigma").

An intrinsic is named as what limits the camera (the verdict's ``limits``) where its part is
material: it raises the geometry sigma past that sigma's own standard error (:data:`LIMIT_RATIO`,
decision 0086), with whether this capture determines it and what to do.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.geometry import finite_rows, rotvec_to_matrix
from wandcal.calib.judge.faults.screen import _pose_columns
from wandcal.calib.judge.lens_sigmas import (  # noqa: F401  (the honest sigma's names, importable from here)
    DEFAULT_NOMINAL_PRINCIPAL_WIDTH_STD,
    DEFAULT_PRINCIPAL_WIDTH_STD,
    DEFAULT_RADIAL_CORNER_STD,
    DEFAULT_TANGENTIAL_STD,
    REFINABLE,
    WHY,
    WORDS,
    LensLimit,
    lens_columns,
    lens_sigmas,
    nominal_principal,
)
from wandcal.calib.judge.verdict import SIGMA_REL_SE

GIVEN_IN_RIG = "given"  # the source of a focal sigma the rig gives (the camera's focal_std_px); else "default"

# a focal length given, not refined, is taken as known to 2% (1 sigma) unless rig.json gives its
# own sigma: a lens's nominal focal length is marked to 5% and the sensor's pixel pitch is exact,
# a calibration of another day with the focus touched keeps it to 1-3% (the eWand session's yaml
# focal lengths sit 1.2-2.6% below those its own wand data give); docs/verdict.md
DEFAULT_FOCAL_REL_STD = 0.02
# a given intrinsic limits a camera's position when its part of the honest sigma is *material*: added
# to the geometry sigma in quadrature it raises that sigma by more than the sigma's own standard error
# (SIGMA_REL_SE, 11%: what a camera's sigma varies by between random halves of a session, the same
# figure that puts a verdict "at the limit"), i.e. sqrt(geo^2 + part^2) > (1 + SE) geo, so
# part > sqrt((1 + SE)^2 - 1) geo = 0.48 geo. Under it the part is lost in the sigma's own scatter:
# giving that intrinsic exactly would not change what the result can say about the camera. One rule
# for the focal length and every other intrinsic (docs/decisions/0086)
LIMIT_RATIO = float(np.sqrt((1.0 + SIGMA_REL_SE) ** 2 - 1.0))
# the data determine the focal length when its standard error from the camera's own residuals is
# under this share: refining it (--refine-intrinsics focal) is then the advice (the refined focal
# length's own warning, wandcal.calib.run.camera_reports.FOCAL_REL_STD_WARN, is 0.5%)
DETERMINED_REL_STD = 0.005
MAX_ROWS = 1000  # observations per camera the fit uses: a first-order fit of seven columns needs no more
MIN_ROWS = 12


@dataclass(frozen=True)
class FocalLimit:
    """One camera's centre against its focal length. shift_m_per_unit: (3,) the centre's change,
    metres (or the rig's units), per unit relative focal error (0.01 is 1%); along_axis_m_per_unit:
    its component along the camera's optical axis; focal_rel_std: the focal length's assumed
    relative sigma, and ``source`` where it comes from (``rig.json`` or ``default``);
    data_rel_std: the focal length's relative standard error the camera's own data would give."""

    shift_m_per_unit: np.ndarray
    along_axis_m_per_unit: float
    focal_rel_std: float
    source: str
    data_rel_std: float

    @property
    def std(self) -> float:
        """The centre's sigma from the focal length alone (3D RMS), metres."""
        return float(np.linalg.norm(self.shift_m_per_unit) * self.focal_rel_std)


def _centre(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    return -R.T @ t


def focal_limit(R: np.ndarray, t: np.ndarray, xy_projected: np.ndarray, depth: np.ndarray, residual: np.ndarray,
                views: np.ndarray, focal_rel_std: float, source: str) -> FocalLimit | None:
    """The centre's first-order change per unit focal error of one camera (pose R (3, 3), t (3,)),
    from its observations: xy_projected (K, 2) normalised projections of its points, depth (K,)
    their depths, residual (K, 2) normalised residuals (their scatter gives the data's own focal
    standard error), views (K,) how many cameras see each one's point. None with fewer than
    :data:`MIN_ROWS` observations.

    A point seen by n cameras moves to share its error among them, so the pose takes up about
    ``1 - 1/n`` of it (a point of two views, half): the focal column is weighted so. On Brown 1 and
    2 with a focal length 3% off the cameras moved 3.3-4.5 mm per 1%; the fit with the points held
    gave 6-9, with this weighting about 4."""
    ok = np.isfinite(depth) & (depth > 0) & finite_rows(xy_projected)
    if ok.sum() < MIN_ROWS:
        return None
    idx = _fit_rows(np.flatnonzero(ok))
    # take: a 2-D gather at a tenth of indexing's cost
    return _focal_fit(R, t, np.take(xy_projected, idx, axis=0), depth[idx], np.take(residual, idx, axis=0), views[idx],
                      int(ok.sum()), focal_rel_std, source)


def _fit_rows(usable: np.ndarray) -> np.ndarray:
    """The rows the focal fit uses of a camera's ``usable`` ones: every k-th, :data:`MAX_ROWS` or so."""
    return usable[:: max(1, len(usable) // MAX_ROWS)]


def _focal_fit(R: np.ndarray, t: np.ndarray, x: np.ndarray, d: np.ndarray, residual: np.ndarray, views: np.ndarray,
               usable: int, focal_rel_std: float, source: str) -> FocalLimit | None:
    """:func:`focal_limit` on the rows its fit uses (:func:`_fit_rows`: x (K, 2) projections, d (K,)
    depths, residual (K, 2), views (K,)) of the camera's ``usable`` ones."""
    pose, share = _pose_and_share(R, t, x, d, views)
    got = _response(R, t, pose, -(x * share[:, None]).ravel(), residual, len(x), usable)
    if got is None:
        return None
    shift, data_std = got
    return FocalLimit(shift, float(shift @ R[2]), focal_rel_std, source, data_std)


def _pose_and_share(R: np.ndarray, t: np.ndarray, x: np.ndarray, d: np.ndarray, views: np.ndarray,
                    differences: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """(2K, 6) the pose's columns at the points of projections x (K, 2) and depths d (K,), and (K,)
    the share of an error the pose takes up at a point of ``views`` cameras (1 - 1/n)."""
    X_cam = np.concatenate([x * d[:, None], d[:, None]], axis=1)
    X = (X_cam - t) @ R  # world points: R^T (X_cam - t)
    pose = _pose_columns(R, t, X, differences=differences)  # the focal figures by differences, as before
    return pose, 1.0 - 1.0 / np.maximum(views, 2)


def _response(R: np.ndarray, t: np.ndarray, pose: np.ndarray, column: np.ndarray, residual: np.ndarray, rows: int,
              usable: int) -> tuple[np.ndarray, float] | None:
    """The centre's change (3,) when the observations move by ``column`` (2K,) (the pose's least
    squares to it), and the standard error of the column's coefficient from the residuals' scatter
    (residual (K, 2)) were it fitted beside the pose; the fit used ``rows`` of ``usable`` rows."""
    both = np.concatenate([pose, column[:, None]], axis=1)
    scale = np.linalg.norm(both, axis=0)
    scale[scale == 0] = 1.0
    A = both / scale
    G = A.T @ A  # the normal equations of the scaled columns: a 7 x 7 system (lstsq on the rows is slow)
    try:
        step = np.linalg.solve(G[:6, :6], A[:, :6].T @ A[:, 6]) * scale[6] / scale[:6]
        cov = np.linalg.inv(G)
    except np.linalg.LinAlgError:
        return None
    C0 = _centre(R, t)
    C1 = _centre(rotvec_to_matrix(step[:3]) @ R, t + step[3:])
    shift = C1 - C0  # linear in the step: the step is per unit d, small enough for the rotation's first order
    r = residual.ravel()
    sigma = float(np.sqrt(np.mean(r[np.isfinite(r)] ** 2))) if np.isfinite(r).any() else 0.0
    # the fit used every k-th observation: all of them would give sqrt(k) times less
    data_std = sigma * float(np.sqrt(max(cov[6, 6], 0.0) * rows / usable)) / scale[6]
    return shift, data_std


def _views_and_usable(res) -> tuple[np.ndarray, np.ndarray]:
    """(M,) how many cameras see each observation's point, and (M,) the observations the fits may
    use (in front, finite, no gross outlier), for every camera at once: only the rows a fit uses
    are gathered."""
    key = res.point - res.point.min() if len(res.point) else res.point
    views = np.bincount(key)[key]
    usable = np.isfinite(res.depth) & (res.depth > 0) & finite_rows(res.xy + res.residual) & ~res.outlier
    return views, usable


def focal_limits(rig, R: np.ndarray, t: np.ndarray, res, refined: set[str],
                 shared: tuple[np.ndarray, np.ndarray] | None = None) -> list[FocalLimit | None]:
    """Every camera's :class:`FocalLimit` (None where its focal length was refined, or it has too
    few observations). res: the judgement's :class:`wandcal.calib.judge.residuals.Residuals`;
    refined: the intrinsics the solve refined (``focal`` among them: none is given)."""
    out: list[FocalLimit | None] = []
    views, usable = shared if shared is not None else _views_and_usable(res)
    for c, cam in enumerate(rig.cameras):
        if "focal" in refined:
            out.append(None)
            continue
        rows = res.rows_of(c)
        rows = rows[usable[rows]]
        if len(rows) < MIN_ROWS:
            out.append(None)
            continue
        given = getattr(cam, "focal_std_px", None)
        rel, source = (float(given) / float(cam.K[0, 0]), GIVEN_IN_RIG) if given else (DEFAULT_FOCAL_REL_STD, "default")
        idx = _fit_rows(rows)
        residual = np.take(res.residual, idx, axis=0)  # take: a 2-D gather at a tenth of indexing's cost
        out.append(_focal_fit(R[c], t[c], np.take(res.xy, idx, axis=0) + residual, res.depth[idx], residual, views[idx],
                              len(rows), rel, source))
    return out


def lens_limits(rig, R: np.ndarray, t: np.ndarray, res, refined: set[str],
                shared: tuple[np.ndarray, np.ndarray] | None = None) -> list[list[LensLimit]]:
    """Every camera's :class:`LensLimit` of each given parameter (none of those refined: cx, cy
    with ``principal``, k1 with ``k1``; none with too few observations). res: the judgement's
    :class:`wandcal.calib.judge.residuals.Residuals`."""
    views, usable = shared if shared is not None else _views_and_usable(res)
    out: list[list[LensLimit]] = []
    for c, cam in enumerate(rig.cameras):
        rows = res.rows_of(c)
        rows = rows[usable[rows]]
        sigmas = {k: v for k, v in lens_sigmas(cam).items() if REFINABLE.get(k) not in refined}
        if len(rows) < MIN_ROWS or not sigmas:
            out.append([])
            continue
        idx = _fit_rows(rows)
        residual, xy = np.take(res.residual, idx, axis=0), np.take(res.xy, idx, axis=0)
        pose, share = _pose_and_share(R[c], t[c], xy + residual, res.depth[idx], views[idx], differences=False)
        columns = lens_columns(cam, xy, sigmas)
        got = _responses(R[c], t[c], pose, np.stack([(columns[n] * share[:, None]).ravel() for n in sigmas], axis=1),
                         residual, len(idx), len(rows))
        source = "nominal" if nominal_principal(cam) else "default"
        out.append([] if got is None else [
            LensLimit(n, shift, float(shift @ R[c][2]), sigmas[n], float(std), source if n in ("cx", "cy") else "default")
            for n, shift, std in zip(sigmas, *got)])
    return out


def _responses(R: np.ndarray, t: np.ndarray, pose: np.ndarray, columns: np.ndarray, residual: np.ndarray, rows: int,
               usable: int) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`_response` of P columns at once (columns (2K, P)): (P, 3) the centre's changes, (P,)
    each column's standard error beside the pose alone (its Schur complement: 1 / (G_jj - G_jp
    G_pp^-1 G_pj))."""
    both = np.concatenate([pose, columns], axis=1)
    scale = np.linalg.norm(both, axis=0)
    scale[scale == 0] = 1.0
    A = both / scale
    G = A.T @ A
    try:
        across = np.linalg.solve(G[:6, :6], G[:6, 6:])  # (6, P): each column's pose step, scaled
    except np.linalg.LinAlgError:
        return None
    steps = across * scale[6:] / scale[:6, None]
    C0 = _centre(R, t)
    shifts = np.array([_centre(rotvec_to_matrix(st[:3]) @ R, t + st[3:]) - C0 for st in steps.T])
    left = np.diag(G[6:, 6:]) - np.einsum("pj,pj->j", G[:6, 6:], across)
    r = residual.ravel()
    sigma = float(np.sqrt(np.mean(r[np.isfinite(r)] ** 2))) if np.isfinite(r).any() else 0.0
    with np.errstate(divide="ignore"):
        var = np.where(left > 0, 1.0 / np.maximum(left, 1e-300), np.inf)
    return shifts, sigma * np.sqrt(var * rows / usable) / scale[6:]


def limit_entry(limit: FocalLimit | None, geometry_std: float | None, scaled: bool,
                lens: list[LensLimit] | None = None) -> dict | None:
    """A camera's report entries: ``geometry_std_honest_mm`` (the geometry sigma with every given
    intrinsic's part, in quadrature; None without a scale), ``focal_limit`` (mm per 1% along the
    axis and in all, the sigma assumed and its source, the data's own; where the focal length was
    given) and ``lens_limits`` (each other given parameter's sigma, mm for that sigma along the
    axis and in all, and the data's own standard error in sigmas); None with neither."""
    lens = lens or []
    if limit is None and not lens:
        return None
    unit = 1000.0 if scaled else 1.0
    entry: dict[str, object] = {}
    if limit is not None:
        entry["focal_limit"] = {
            "mm_per_percent" if scaled else "per_percent": round(unit * 0.01 * float(np.linalg.norm(limit.shift_m_per_unit)), 4),
            "along_axis_mm_per_percent" if scaled else "along_axis_per_percent": round(unit * 0.01 * limit.along_axis_m_per_unit, 4),
            "focal_std_percent": round(100 * limit.focal_rel_std, 3), "source": limit.source,
            "data_focal_std_percent": round(100 * float(limit.data_rel_std), 3) if np.isfinite(limit.data_rel_std) else None}
    if lens:
        entry["lens_limits"] = {part.name: {
            "sigma": float(f"{part.sigma:.4g}"), "unit": "px" if part.name in ("cx", "cy") else "", "source": part.source,
            "mm_per_sigma" if scaled else "per_sigma": round(unit * part.std, 4),
            "along_axis_mm_per_sigma" if scaled else "along_axis_per_sigma": round(unit * part.along_axis_m_per_sigma, 4),
            "data_std_sigmas": round(float(part.data_std), 4) if np.isfinite(part.data_std) else None} for part in lens}
    honest = None
    if geometry_std is not None:
        parts = ([limit.std] if limit is not None else []) + [part.std for part in lens]
        honest = float(np.hypot(geometry_std, np.sqrt(sum(x ** 2 for x in parts))))
    entry["geometry_std_honest_mm" if scaled else "geometry_std_honest"] = \
        (round(unit * honest, 4) if honest is not None else None)
    return entry


def _length(x: float, scaled: bool) -> float:
    """A limit's length for its evidence: mm to 3 decimals, or (no scale) the rig's units to 4 figures."""
    return round(x, 3) if scaled else float(f"{x:.4g}")


def lens_limited(cam: str, lens: list[LensLimit], geo: float, scaled: bool) -> list[dict]:
    """Camera ``cam``'s parameters beyond the focal length whose part of its honest sigma is
    material (:data:`LIMIT_RATIO` times its geometry sigma ``geo`` or more), each a ``limits`` entry:
    whether this capture determines it, how many millimetres the camera moves for the parameter's
    assumed sigma, and what to do."""
    out = []
    k = 1000.0 if scaled else 1.0
    unit = "mm" if scaled else "units"
    for part in lens:
        if part.std < LIMIT_RATIO * geo:
            continue
        size = f"{part.sigma:.2g} px" if part.name in ("cx", "cy") else f"{part.sigma:.2g}"
        words = WORDS[part.name]
        if part.name in REFINABLE and part.determined:
            head = f"{cam}'s {words} is determined by this capture (to {part.data_std:.2f} of its assumed uncertainty)"
            todo = f"run with --refine-intrinsics {REFINABLE[part.name]}, or give it from a lens calibration"
        elif part.name in REFINABLE:
            head, todo = f"{cam}'s {words} cannot be determined from this capture", "give it from a lens calibration"
        else:
            head = f"{cam}'s {words} is not determined from this capture (wandcal does not refine it)"
            todo = "give it from a lens calibration"
        out.append({"camera": cam, "parameter": part.name, "evidence": {
            "sigma": float(f"{part.sigma:.4g}"), "unit": "px" if part.name in ("cx", "cy") else "",
            "parameter_sigma_mm" if scaled else "parameter_sigma": _length(part.std * k, scaled),
            "along_axis_mm" if scaled else "along_axis": _length(part.along_axis_m_per_sigma * k, scaled),
            "geometry_sigma_mm" if scaled else "geometry_sigma": _length(geo * k, scaled),
            "data_std_sigmas": round(float(part.data_std), 3) if np.isfinite(part.data_std) else None,
            "determined": part.determined},
            "message": f"{head}: off by its assumed uncertainty ({size}{WHY.get(part.source, '')}: docs/verdict.md, "
                       f"\"The honest sigma\") it moves the camera {part.std * k:.3g} {unit}, where the geometry alone "
                       f"places it to +-{geo * k:.3g} {unit}; {todo}"})
    return out


def limited_cameras(ids: list[str], limits: list[FocalLimit | None], geometry_std: list[float | None],
                    scaled: bool) -> list[dict]:
    """The cameras whose position hinges on their focal length (its part of the honest sigma
    material: :data:`LIMIT_RATIO` times the geometry sigma or more), each ``{"camera", "parameter",
    "message", "evidence"}``: how many millimetres along its axis each 1% moves it, and what to do."""
    out = []
    for cam, limit, geo in zip(ids, limits, geometry_std):
        if limit is None or geo is None or limit.std < LIMIT_RATIO * geo:
            continue
        per = 0.01 * abs(limit.along_axis_m_per_unit) * (1000.0 if scaled else 1.0)
        unit = "mm" if scaled else "units"
        if limit.data_rel_std < DETERMINED_REL_STD:
            todo = (f"the data determine it to +-{100 * limit.data_rel_std:.2f}%: run with --refine-intrinsics focal, "
                    "or give it from a lens calibration")
        else:
            todo = "the data cannot determine it: give it from a lens calibration"
        if limit.source == GIVEN_IN_RIG:
            why = "rig.json's focal_std_px"
        else:
            why = f"assumed, rig.json giving no focal_std_px for {cam}"
        k = 1000.0 if scaled else 1.0
        out.append({"camera": cam, "parameter": "focal length", "evidence": {
            "along_axis_mm_per_percent" if scaled else "along_axis_per_percent": _length(per, scaled),
            "focal_std_percent": round(100 * limit.focal_rel_std, 3),
            "focal_sigma_mm" if scaled else "focal_sigma": _length(limit.std * k, scaled),
            "geometry_sigma_mm" if scaled else "geometry_sigma": _length(geo * k, scaled)},
            "message": f"{cam}'s distance along its axis moves {per:{'.1f' if scaled else '.2g'}} {unit} for each 1% of its focal length: with "
                       f"the focal length known to {100 * limit.focal_rel_std:.2g}% ({why}) that moves the camera "
                       f"+-{limit.std * k:.3g} {unit}, where the geometry alone places it to +-{geo * k:.3g} {unit}; {todo}"})
    return out


def intrinsic_limit_entries(rig, geometry_std: list[float | None], R: np.ndarray, t: np.ndarray, res, scaled: bool,
                            refined: tuple[str, ...]) -> tuple[list[dict | None], list[dict]]:
    """Each camera's :func:`limit_entry` (None where every intrinsic was refined or it has too few
    observations) and the cameras whose position hinges on a given intrinsic, each named with the
    intrinsic (:func:`limited_cameras`, :func:`lens_limited`). geometry_std: (N,) each camera's
    geometry sigma, world units; refined: the intrinsics the solve refined."""
    shared = _views_and_usable(res)
    limits = focal_limits(rig, R, t, res, set(refined), shared)
    lens = lens_limits(rig, R, t, res, set(refined), shared)
    entries = [limit_entry(limit, geo, scaled, parts) for limit, geo, parts in zip(limits, geometry_std, lens)]
    named = limited_cameras(list(rig.ids), limits, geometry_std, scaled)
    out = []
    for cam, parts, geo in zip(rig.ids, lens, geometry_std):
        out += [entry for entry in named if entry["camera"] == cam]
        if geo is not None:
            out += lens_limited(cam, parts, geo, scaled)
    return entries, out
