"""The flat, chunked kernels of triangulation and labelling against their plain reference forms."""

import numpy as np
import pytest

from wandcal.calib import triangulate
from wandcal.calib.sim.scenes import prepared_scene
from wandcal.calib.start import labels
from wandcal.calib.start.labels import flatten, label_ends
from wandcal.calib.triangulate import solve_symmetric_3x3, triangulate_points


@pytest.fixture(scope="module")
def scene():
    return prepared_scene(cameras=5, frames=200, noise_px=0.5, seed=4)


def test_symmetric_3x3_solve_matches_lapack():
    rng = np.random.default_rng(0)
    B = rng.normal(size=(500, 3, 3))
    A = B @ np.swapaxes(B, 1, 2) + 1e-3 * np.eye(3)
    g = rng.normal(size=(500, 3))
    x = solve_symmetric_3x3(A[:, 0, 0], A[:, 0, 1], A[:, 0, 2], A[:, 1, 1], A[:, 1, 2], A[:, 2, 2], *g.T)
    ref = np.linalg.solve(A, g[:, :, None])[:, :, 0]
    assert np.allclose(x.T, ref, rtol=1e-8, atol=1e-10)


def test_symmetric_3x3_solve_of_a_singular_system_is_not_finite():
    z = np.zeros(1)
    x = solve_symmetric_3x3(z + 1, z + 1, z, z + 1, z, z, z + 1, z, z)  # rank 1 and rank-deficient
    assert not np.all(np.isfinite(x))


def test_triangulation_does_not_depend_on_the_chunk_size(scene, monkeypatch):
    R, t = scene.sim.truth.R, scene.sim.truth.t
    point, camera, xy = flatten(scene.labelled)
    n = 2 * len(scene.labelled.frames)
    whole = triangulate_points(R, t, point, camera, xy, n)
    monkeypatch.setattr(triangulate, "CHUNK", 97)
    chunked = triangulate_points(R, t, point, camera, xy, n)
    ok = np.isfinite(whole)
    assert np.array_equal(ok, np.isfinite(chunked))
    assert np.abs(whole[ok] - chunked[ok]).max() < 1e-12
    # and the ends are the truth's (in either order: labels are consistent, not named) to within
    # the blob noise: 0.5 px at ~1000 px focal length, a few metres away, is a few mm
    X, truth = whole.reshape(-1, 2, 3), scene.sim.truth.wand[scene.labelled.frames]
    err = np.minimum(np.abs(X - truth).max(axis=(1, 2)), np.abs(X[:, ::-1] - truth).max(axis=(1, 2)))
    assert np.nanmax(err) < 0.01


def _reference_sampson(E, xa, xb):
    """The Sampson distance in its textbook form, (M,), for x_b^T E x_a = 0; E (M, 3, 3)."""
    ha = np.concatenate([xa, np.ones((len(xa), 1))], 1)
    hb = np.concatenate([xb, np.ones((len(xb), 1))], 1)
    Ea = np.einsum("mij,mj->mi", E, ha)
    Etb = np.einsum("mji,mj->mi", E, hb)
    num = np.einsum("mi,mi->m", hb, Ea) ** 2
    return num / (Ea[:, 0] ** 2 + Ea[:, 1] ** 2 + Etb[:, 0] ** 2 + Etb[:, 1] ** 2)


def test_epipolar_costs_are_the_sampson_distances(scene, monkeypatch):
    pairs, R, t = scene.pairs, scene.init.R, scene.init.t
    rng = np.random.default_rng(1)
    a, b = rng.integers(0, len(pairs), 700), rng.integers(0, len(pairs), 700)
    keep = pairs.camera[a] != pairs.camera[b]
    a, b = a[keep], b[keep]
    monkeypatch.setattr(labels, "COST_CHUNK", 64)
    same, cross = labels._epipolar_costs(R, t, pairs, a, b)
    E = labels._essential_matrices(R, t)[pairs.camera[a], pairs.camera[b]]
    xa, xb = pairs.xy[a], pairs.xy[b]
    ref_same = _reference_sampson(E, xa[:, 0], xb[:, 0]) + _reference_sampson(E, xa[:, 1], xb[:, 1])
    ref_cross = _reference_sampson(E, xa[:, 0], xb[:, 1]) + _reference_sampson(E, xa[:, 1], xb[:, 0])
    assert np.allclose(same, ref_same, rtol=1e-12, atol=1e-300)
    assert np.allclose(cross, ref_cross, rtol=1e-12, atol=1e-300)


def test_labels_do_not_depend_on_the_cost_chunk(scene, monkeypatch):
    pairs, R, t = scene.pairs, scene.init.R, scene.init.t
    shuffled = pairs.swapped(np.random.default_rng(2).random(len(pairs)) < 0.5)
    known = np.ones(len(R), bool)
    whole, _ = label_ends(R, t, shuffled, known, scene.sim.rig.wand_length)
    monkeypatch.setattr(labels, "COST_CHUNK", 50)
    chunked, _ = label_ends(R, t, shuffled, known, scene.sim.rig.wand_length)
    assert np.array_equal(whole.xy, chunked.xy)


def test_two_view_frames_judged_from_the_rounds_triangulation_as_from_their_own(scene, monkeypatch):
    # frames left in two cameras (both matchings fit the epipolar geometry there: the wand's length
    # decides), and their swapped wands triangulated in the reprojection round's call: the same
    # labels, margins and ends to the last digit as triangulating them in calls of their own
    pairs, R, t = scene.pairs, scene.init.R, scene.init.t
    two = (pairs.frame % 2 == 0) & (pairs.camera >= 2)  # every other frame keeps cameras 0 and 1 only
    shuffled = pairs.subset(~two).swapped(np.random.default_rng(3).random(int((~two).sum())) < 0.5)
    known = np.ones(len(R), bool)
    assert labels._two_view_candidates(shuffled) is not None
    together = labels.labelled_ends(R, t, shuffled, known, scene.sim.rig.wand_length)
    own = labels._triangulated
    monkeypatch.setattr(labels, "_triangulated", lambda R, t, sub, part, two_view: (own(R, t, sub, part, None)[0], None))
    apart = labels.labelled_ends(R, t, shuffled, known, scene.sim.rig.wand_length)
    assert np.array_equal(together[0].xy, apart[0].xy)
    assert np.array_equal(together[1], apart[1])
    assert (together[2] is None) == (apart[2] is None)
    if together[2] is not None:
        assert np.array_equal(together[2], apart[2], equal_nan=True)


@pytest.mark.parametrize("dense", [False, True])
def test_shared_frames_counted_pair_by_pair_are_the_products(dense, monkeypatch):
    from wandcal.calib.start import chain

    rng = np.random.default_rng(5)
    for frames, cameras, most in [(400, 40, 4), (300, 8, 8), (0, 5, 2)]:
        seen = np.zeros((frames, cameras), bool)
        for f in range(frames):
            seen[f, rng.choice(cameras, rng.integers(0, most + 1), replace=False)] = True
        if dense:
            monkeypatch.setattr(chain, "MAX_SPARSE_PAIRS", -1)
        w = seen.astype(np.int64)
        assert np.array_equal(chain.co_seen(seen), w.T @ w)
