"""benchmarks/tube_w_shapes.py's box and hull supports of the mRPI set, against closed forms and
against hlip_jax.core.robust's box tables."""


import numpy as np


from hlip_jax.core import robust
from support import load_benchmark

shape_bounds = load_benchmark("tube_w_shapes").shape_bounds


def test_scalar_geometric_series():
    # e⁺ = a e + d, |d| ≤ w: h_E(1) = w / (1 − a) exactly (1e-11: the tail bound's slack)
    A = np.diag([0.5, 0.0, 0.0])
    got = shape_bounds(A, np.zeros(3), np.array([[0.2, 0.0, 0.0], [-0.1, 0.0, 0.0]]))
    for ec, eu in got.values():
        np.testing.assert_allclose(ec, 0.2 / 0.5, atol=1e-11)
        assert eu == 0.0


def test_box_matches_the_tube_tables():
    # for a box W the series is the support of F_∞ that robust.plane_bounds brackets from
    # below (its rows m are F_m) and from above (its last row, the outer mRPI bound): the
    # value lies between its second-last and last rows, within sets.mrpi's ε (1e-5)
    A = np.array([[1.0, 0.2, 0.05], [0.0, 1.0, 0.3], [0.0, 0.9, 1.0]])
    B = np.array([0.0, 1.0, 0.9])
    K = np.array([-0.3, -1.2, -0.5])
    A_cl = A + np.outer(B, K)
    assert np.max(np.abs(np.linalg.eigvals(A_cl))) < 1
    w = np.array([0.02, 0.07, 0.12])
    samples = np.random.default_rng(0).uniform(-1, 1, (200, 3)) * w
    samples[0] = w                                   # the box of the samples is [−w, w]
    got = np.array(shape_bounds(A_cl, K, samples)["box"])
    table = robust.plane_bounds(A_cl, K, w)
    assert np.all(got >= table[-2] - 1e-12)
    np.testing.assert_allclose(got, table[-1], atol=1e-5)


def test_symmetric_hull_of_box_corners_is_the_box():
    # the hull of ±(every corner of the box, and points inside it) is the box: the same bounds
    w = np.array([0.02, 0.07, 0.12])
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * w
    inside = np.random.default_rng(1).uniform(-0.9, 0.9, (50, 3)) * w
    A_cl = np.diag([0.6, 0.3, -0.4])
    got = shape_bounds(A_cl, np.array([0.3, -1.0, 0.5]), np.concatenate([inside, corners]))
    np.testing.assert_allclose(got["symmetric hull"], got["box"], atol=1e-12)
