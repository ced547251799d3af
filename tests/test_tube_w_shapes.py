"""benchmarks/tube_w_shapes.py's support series of the mRPI set, against closed forms and
against hlip_jax.robust's tube tables."""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))

from tube_w_shapes import support_series  # noqa: E402

from hlip_jax import robust  # noqa: E402


def test_scalar_geometric_series():
    # e⁺ = a e + d, |d| ≤ w: h_E(1) = w / (1 − a) exactly (1e-12: the series' cut-off)
    A = np.diag([0.5, 0.0, 0.0])
    got = support_series(A, np.array([[1.0, 0.0, 0.0]]), lambda D: np.abs(D) @ [0.2, 0, 0])
    np.testing.assert_allclose(got, [0.2 / 0.5], atol=1e-11)


def test_box_matches_the_tube_tables():
    # for a box W the series is the support of F_∞ that robust.plane_bounds brackets from
    # below (its rows m are F_m) and from above (its last row, the outer mRPI bound): the
    # series lies between its second-last and last rows, within sets.mrpi's ε (1e-5)
    A = np.array([[1.0, 0.2, 0.05], [0.0, 1.0, 0.3], [0.0, 0.9, 1.0]])
    B = np.array([0.0, 1.0, 0.9])
    K = np.array([-0.3, -1.2, -0.5])
    A_cl = A + np.outer(B, K)
    assert np.max(np.abs(np.linalg.eigvals(A_cl))) < 1
    w = np.array([0.02, 0.07, 0.12])
    g = np.stack([np.eye(3)[0], K])
    got = support_series(A_cl, g, lambda D: np.abs(D) @ w)
    table = robust.plane_bounds(A_cl, K, w)
    assert np.all(got >= table[-2] - 1e-12)
    np.testing.assert_allclose(got, table[-1], atol=1e-5)


def test_symmetric_hull_of_box_corners_is_the_box():
    # the hull of ±(every corner of the box) is the box: the same support in every direction
    w = np.array([0.02, 0.07, 0.12])
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * w
    A_cl = np.diag([0.6, 0.3, -0.4])
    g = np.array([[1.0, 0.0, 0.0], [0.3, -1.0, 0.5]])
    box = support_series(A_cl, g, lambda D: np.abs(D) @ w)
    hull = support_series(A_cl, g, lambda D: np.abs(corners @ D.T).max(axis=0))
    np.testing.assert_allclose(hull, box, atol=1e-12)
