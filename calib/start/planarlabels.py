"""Label the blobs of a planar wand (a T such as Vicon's Active Wand) in one image, from its layout.

Four or more markers in a plane, seen by a camera of known intrinsics, fix the wand's pose: the
right labelling is the one whose pose reprojects onto the blobs (decision 0021).

1. Candidates (:func:`candidates`): a camera sees the plane from one side, so it keeps the
   orientation (clockwise or not) of every triple of markers that is not collinear, or turns all
   of them at once (seen from the other side). Of the K! assignments of blobs to markers, those
   whose image triples agree with the layout's in that way (up to one global sign) stand; for a
   T that leaves the right one and its mirror about the stem.
2. Pose (:func:`pose_errors`): for each candidate, the plane's homography to the image
   (normalised coordinates), the nearest rigid pose to it, and the blobs' RMS pixel distance
   from the markers reprojected with it. The mirror of an asymmetric layout is a projective
   image of it (a harmonic homology fixes the stem and swaps the bar's ends) but not a rigid
   one, so its pose misses the blobs by the asymmetry, tens of pixels.
"""

from __future__ import annotations

import itertools

import numpy as np

from wandcal.calib.geometry import euler_to_matrix

POSE_ITERATIONS = 4  # Gauss-Newton steps from the homography's pose: the right labelling's error then
# stops falling (its pose is within noise of the optimum; measured 3 px median after none)
RIDGE = 1e-9  # of the normal matrix's trace: far below its smallest useful eigenvalue, above rounding
COLLINEAR_AREA = 1e-4  # m^2: a layout triple spanning less (1 cm x 1 cm) has no reliable orientation
MAX_CANDIDATES = 8  # assignments whose pose is fitted per camera-frame (a T leaves 2; noise a few more)


def candidates(xy: np.ndarray, plane: np.ndarray) -> np.ndarray:
    """(P, C) indices into ``itertools.permutations(range(K))`` of the assignments to fit, best
    agreement first (padded with the best).

    Args:
        xy: (P, K, 2) each camera-frame's blobs, normalised; plane: (K, 2) the layout in its
            plane (wandcal.calib.wandlayout.plane_offsets), metres.
    """
    K = len(plane)
    perms = np.array(list(itertools.permutations(range(K))))  # (Pi, K): marker -> blob
    triples = np.array([t for t in itertools.combinations(range(K), 3)
                        if abs(_area(plane[t[0]], plane[t[1]], plane[t[2]])) > COLLINEAR_AREA])
    sign = np.sign(_area(plane[triples[:, 0]], plane[triples[:, 1]], plane[triples[:, 2]]))  # (T,)
    b = perms[:, triples]  # (Pi, T, 3) the blobs each marker triple falls on
    img = np.sign(_area(xy[:, b[..., 0]], xy[:, b[..., 1]], xy[:, b[..., 2]]))  # (P, Pi, T)
    agree = np.abs((img * sign).sum(axis=2))  # one side or the other: |sum| = T when every triple agrees
    order = np.argsort(-agree, axis=1, kind="stable")[:, :MAX_CANDIDATES]
    best = np.take_along_axis(agree, order, axis=1)
    return np.where(best == best[:, :1], order, order[:, :1])


def pose_errors(xy: np.ndarray, plane: np.ndarray, perm: np.ndarray, focal: np.ndarray) -> np.ndarray:
    """(P,) RMS pixel distance of each row's blobs from the layout reprojected at the rigid pose
    nearest the homography of the assignment ``perm`` (P, K) (marker -> blob); inf where the
    plane would lie behind the camera.

    Args:
        xy: (P, K, 2) normalised blobs; plane: (K, 2) metres; focal: (P,) pixels per unit.
    """
    P, K = perm.shape
    centre = plane.mean(axis=0)
    scale = np.abs(plane - centre).max()
    u = (plane - centre) / scale  # conditioned layout coordinates
    img = np.take_along_axis(xy, perm[:, :, None], axis=1)  # (P, K, 2): the blob of each marker
    A = np.zeros((P, 2 * K, 9))
    uh = np.concatenate([u, np.ones((K, 1))], axis=1)  # (K, 3)
    A[:, 0::2, 0:3] = uh
    A[:, 0::2, 6:9] = -img[:, :, :1] * uh
    A[:, 1::2, 3:6] = uh
    A[:, 1::2, 6:9] = -img[:, :, 1:] * uh
    H = np.linalg.svd(A)[2][:, -1].reshape(P, 3, 3)  # maps (u, 1) to the image
    H *= np.where(H[:, 2, 2] < 0, -1.0, 1.0)[:, None, None]  # the layout's centre in front of the camera
    h1, h2, h3 = H[:, :, 0], H[:, :, 1], H[:, :, 2]
    lam = np.sqrt(np.linalg.norm(h1, axis=1) * np.linalg.norm(h2, axis=1))  # (P,) = lambda * scale
    U, _, Vt = np.linalg.svd(np.stack([h1, h2], axis=2) / lam[:, None, None], full_matrices=False)
    r12 = U @ Vt  # (P, 3, 2): the nearest pair of orthonormal columns
    t = h3 * (scale / lam)[:, None] - r12 @ centre
    R = np.concatenate([r12, np.cross(r12[:, :, 0], r12[:, :, 1])[:, :, None]], axis=2)
    body = np.concatenate([plane, np.zeros((K, 1))], axis=1)  # (K, 3) markers in the wand's own frame
    for _ in range(POSE_ITERATIONS):
        R, t = _gauss_newton(R, t, body, img)
    X = np.einsum("pij,kj->pki", R, body) + t[:, None]  # (P, K, 3) markers in the camera
    z = X[..., 2]
    err = np.where(z > 0, 1.0, np.inf)[..., None] * (X[..., :2] / np.where(z > 0, z, 1.0)[..., None] - img)
    return np.sqrt(np.mean(np.sum(err**2, axis=2), axis=1)) * focal


def _gauss_newton(R: np.ndarray, t: np.ndarray, body: np.ndarray, img: np.ndarray):
    """One Gauss-Newton step of the poses R (P, 3, 3), t (P, 3) on the reprojection error of
    ``body`` (K, 3) against ``img`` (P, K, 2) normalised; rotations move by a left increment."""
    Y = np.einsum("pij,kj->pki", R, body)  # (P, K, 3)
    X = Y + t[:, None]
    z = np.where(np.abs(X[..., 2]) > 1e-9, X[..., 2], 1e-9)
    proj = X[..., :2] / z[..., None]
    r = (proj - img).reshape(len(R), -1)  # (P, 2K)
    D = np.zeros(X.shape[:2] + (2, 3))  # d proj / d X
    D[..., 0, 0] = D[..., 1, 1] = 1 / z
    D[..., :, 2] = -proj / z[..., None]
    J = np.concatenate([np.cross(Y[..., None, :], D), D], axis=3).reshape(len(R), -1, 6)  # d/dw = -D [Y]x
    A = np.einsum("pki,pkj->pij", J, J)
    g = -np.einsum("pki,pk->pi", J, r)
    bad = ~(np.isfinite(A).all(axis=(1, 2)) & np.isfinite(g).all(axis=1))
    A[bad], g[bad] = np.eye(6), 0.0  # a degenerate row (the plane edge on, behind the camera) keeps its pose
    # a ridge relative to the matrix's scale keeps an ill-conditioned row (a distant, foreshortened wand) solvable
    A += RIDGE * np.einsum("pii->p", A)[:, None, None] * np.eye(6)
    step = np.linalg.solve(A, g[..., None])[..., 0]
    return euler_to_matrix(step[:, :3]) @ R, t + step[:, 3:]


def label_planar(xy: np.ndarray, plane: np.ndarray, focal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(P, K) the blob of each marker (layout order) in each camera-frame, and (P,) the RMS pixel
    error of that labelling's pose.

    Args:
        xy: (P, K, 2) normalised blobs; plane: (K, 2) metres; focal: (P,) pixels per unit.
    """
    K = len(plane)
    perms = np.array(list(itertools.permutations(range(K))))
    cand = candidates(xy, plane)  # (P, C)
    P, C = cand.shape
    err = np.full((P, C), np.inf)
    for c in range(C):
        fresh = (c == 0) | (cand[:, c] != cand[:, 0])
        rows = np.flatnonzero(fresh)
        if not len(rows):  # every row's candidate c is its first: nothing new to fit
            continue
        err[rows, c] = pose_errors(xy[rows], plane, perms[cand[rows, c]], focal[rows])
    best = np.argmin(err, axis=1)
    return perms[cand[np.arange(P), best]], err[np.arange(P), best]


def _area(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Twice the signed area of the triangles (..., 2) a, b, c."""
    return (b[..., 0] - a[..., 0]) * (c[..., 1] - a[..., 1]) - (b[..., 1] - a[..., 1]) * (c[..., 0] - a[..., 0])
