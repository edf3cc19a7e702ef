"""The columns of the pose-step test (:mod:`wandcal.calib.judge.faults.pose_steps`), whitened, with
the points projected out (what fitting each point again takes away, :mod:`wandcal.calib.judge.faults.own_errors`):
the views of the points a camera sees (:func:`rows_of`), its pose's (:func:`pose_columns`), every
camera's lens (:func:`every_lens`; decision 0076) and another camera's two poses (:func:`partner_columns`,
for the nested test of :func:`wandcal.calib.judge.faults.moved.explained_by`).
"""

from __future__ import annotations

import weakref

import numpy as np

from wandcal.calib.geometry import projection_derivative, turn_response
from wandcal.calib.judge.faults.own_errors import Eliminated

MIN_SIDE = 6  # timed views of the camera on either side of a split: three wand frames, more than the step's three columns can fit alone


def rows_of(el: Eliminated, c: int):
    """Every view of the points camera c sees: (rows (K,) view indices, own (K,) c's view of each
    row's point, proj) where proj(G) takes c's columns G (K, 2, n) (whitened, zero where the row is
    not c's) to the same with the points projected out: ``G_i [i is c's] - J_i Ainv J_c^T G_c``,
    what fitting each point again takes away."""
    v = el.views
    mine = np.flatnonzero(v.camera == c)
    at = np.full(v.n_points, -1)
    at[v.point[mine]] = mine
    rows = np.flatnonzero(at[v.point] >= 0)
    own = at[v.point[rows]]
    is_own = rows == own

    def proj(G: np.ndarray) -> np.ndarray:
        u = np.einsum("kmi,kmj->kij", el.J[own], G)
        out = -np.einsum("kmi,kij,kjl->kml", el.J[rows], el.Ainv[v.point[rows]], u)
        out[is_own] += G[is_own]
        return out
    return rows, own, proj


def pose_columns(el: Eliminated, c: int, rows: np.ndarray, own: np.ndarray, proj) -> tuple[np.ndarray, np.ndarray]:
    """Camera c's pose columns over ``rows`` (:func:`rows_of`), whitened, the points projected out:
    (turn (K, 2, 3) about its centre, shift (K, 2, 3) of its position in its own frame)."""
    Xc = el.Xc[own]
    D = projection_derivative(Xc) / el.sigma[c]
    return proj(np.einsum("kij,kjl->kil", D, turn_response(Xc))), proj(D)


def every_lens(el: Eliminated, rows: np.ndarray) -> np.ndarray:
    """(K, 2, 4 N) every camera's lens columns (focal length, k1, principal point) over ``rows``
    (every view of the points one camera sees: :func:`rows_of`), whitened, each camera's four
    nonzero on its own views only, the points projected out (``G_i - J_i Ainv J_p^T G_p``, the sums
    over each point's views); the columns of cameras without a view among ``rows`` dropped.

    Why: a lens error of any camera bends the points as a function of where they are; where the
    marker drifts through the volume in time (MultiCamSelfCal's one LED), that bend reaches the
    other cameras' residuals as a change in time, and the step read it as a knock (decision 0076).
    With these columns in the step's base the F test's null is "no step, whatever lens error any
    camera has" (an exact linear F test with nuisance columns): a knock is a step in time at any
    place, which no camera's lens pattern explains. The camera's own four columns are those the
    test fitted before; k2 is left out as it was (k1 takes most of a k2 error over the image).

    Where ``rows`` are half of ``el``'s views or more (a rig of few cameras, each seeing most
    points), made once for every view of ``el`` (:func:`lens_of_every_view`) and read at ``rows``:
    ``rows`` holds every view of each of its points, so each point's sums are those over all its
    views, in the same order; a camera without a view among ``rows`` has zero columns there (none of
    its points' sums holds it), which are dropped. Every camera's step test on one fit (a clean
    rig's: :class:`wandcal.calib.judge.faults.moved._Refits`) shares them. In a larger rig a camera
    sees a small part of the views and every camera's columns over all of them would be large: made
    over ``rows`` alone (the same numbers)."""
    if 2 * len(rows) < len(el.views.point):
        return lens_columns(el, rows)[0]
    full, cameras = lens_of_every_view(el)
    present = np.unique(el.views.camera[rows])
    cols = (4 * np.searchsorted(cameras, present)[:, None] + np.arange(4)).ravel()
    return full[rows][:, :, cols]


# lens_of_every_view's answers, while their Eliminated lives
_lens_made: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def lens_of_every_view(el: Eliminated) -> tuple[np.ndarray, np.ndarray]:
    """(every view's lens columns (M, 2, 4 C), the C cameras with views, ascending): as
    :func:`every_lens` describes them, over all of ``el``'s views; made once for each ``el``."""
    made = _lens_made.get(el)
    if made is None:
        made = _lens_made[el] = lens_columns(el, np.arange(len(el.views.point)))
    return made


def lens_columns(el: Eliminated, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the lens columns over ``rows`` (K, 2, 4 C), the C cameras with a view among them, ascending):
    :func:`every_lens`'s columns, made over ``rows``."""
    cam = el.views.camera[rows]
    xy = el.Xc[rows][:, :2] / el.Xc[rows][:, 2:]
    r2 = np.sum(xy**2, axis=1, keepdims=True)
    G = np.stack([xy, xy * r2, np.broadcast_to([1.0, 0.0], xy.shape), np.broadcast_to([0.0, 1.0], xy.shape)],
                 axis=2) / el.sigma[cam][:, None, None]
    present = np.unique(cam)
    full = np.zeros((len(rows), 2, 4 * len(present)))
    for j, d in enumerate(present):
        full[cam == d, :, 4 * j : 4 * j + 4] = G[cam == d]
    return projected(el, rows, full), present


def projected(el: Eliminated, rows: np.ndarray, full: np.ndarray) -> np.ndarray:
    """Columns full (K, 2, n) over ``rows`` (every view of each of their points: :func:`rows_of`),
    whitened, with the points projected out: ``G_i - J_i Ainv J_p^T G_p``, the sums over each
    point's views (what fitting each point again takes away)."""
    pt = el.views.point[rows]
    u = np.zeros((el.views.n_points, 3, full.shape[2]))
    np.add.at(u, pt, np.einsum("kmi,kmj->kij", el.J[rows], full))
    return full - np.einsum("kmi,kij,kjl->kml", el.J[rows], el.Ainv[pt], u[pt])


def partner_columns(el: Eliminated, rows: np.ndarray, d: int, frame: int) -> np.ndarray:
    """(2K, 9 or 12) camera d's two poses over ``rows`` (:func:`rows_of` of another camera),
    whitened, the points projected out: its turn and shift (six columns), its turn after capture
    frame ``frame`` on its timed views (three: d's own step at its split), and a turn of their own for
    its views without a time where it has :data:`MIN_SIDE` of them (as :func:`wandcal.calib.judge.faults.pose_steps.pose_step` gives d).
    With these in a camera's step test its null is "camera d moved at ``frame``" (:func:`wandcal.calib.judge.faults.moved.explained_by`)."""
    v = el.views
    on = v.camera[rows] == d
    Xc = el.Xc[rows][on]
    D = projection_derivative(Xc) / el.sigma[d]
    T = np.einsum("kij,kjl->kil", D, turn_response(Xc))
    timed = v.timed[rows][on]
    cols = [T, D, T * (timed & (v.time[rows][on] > frame))[:, None, None]]
    if (~timed).sum() >= MIN_SIDE:
        cols.append(T * (~timed)[:, None, None])
    full = np.zeros((len(rows), 2, 3 * len(cols)))
    full[on] = np.concatenate(cols, axis=2)
    return projected(el, rows, full).reshape(2 * len(rows), -1)
