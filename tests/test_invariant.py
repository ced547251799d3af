"""Tests for hlip_jax.core.invariant: W estimation, mRPI sets, zonotope facets, coverage."""

import jax

import itertools

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial import ConvexHull

from hlip_jax.core import hlip
from hlip_jax.core import invariant as inv
from hlip_jax.core import sets
from hlip_jax.presentation import set_figures

Z0, TS, TD = 0.8, 0.3, 0.1
_lqr_gain = jax.jit(hlip.lqr_gain)  # one compile per shape instead of eager op-by-op


def _deadbeat2():
    A, B = hlip.s2s_matrices(Z0, TS, TD, with_position=False)
    K = hlip.deadbeat_gain(Z0, TS, TD)
    return np.asarray(A + jnp.outer(B, K))


def _acl3(kind):
    A, B = hlip.s2s_matrices(Z0, TS, TD, with_position=True)
    if kind == "deadbeat":
        K = hlip.deadbeat_gain(Z0, TS, TD, with_position=True)
    else:
        K = _lqr_gain(A, B, jnp.eye(3), jnp.array(1.0))
    return np.asarray(A + jnp.outer(B, K))


def _lqr2():
    A, B = hlip.s2s_matrices(Z0, TS, TD, with_position=False)
    K = _lqr_gain(A, B, jnp.eye(2), jnp.array(0.5))
    return np.asarray(A + jnp.outer(B, K))


def _sphere(n, k, seed=0):
    d = np.random.default_rng(seed).normal(size=(k, n))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


# ------------------------------------------------------------------ analytic mRPI


@pytest.mark.parametrize("a", [0.5, -0.5, 0.9])
def test_scalar_box_matches_closed_form(a):
    # e⁺ = a e + w, w ∈ [lo, hi]:  F_∞ = [c/(1−a) − r/(1−|a|), c/(1−a) + r/(1−|a|)]
    # (c, r centre and half-width of W).  Raković: F_s ⊆ F_∞ ⊆ F_s/(1−α), outer within ε.
    lo, hi, eps = -1.0, 2.0, 1e-6
    E = inv.mrpi(np.array([[a]]), inv.Box(jnp.array([lo]), jnp.array([hi])), eps=eps)
    c, r = 0.5 * (lo + hi), 0.5 * (hi - lo)
    exact = np.array([c / (1 - a) + r / (1 - abs(a)), -(c / (1 - a) - r / (1 - abs(a)))])
    d = np.array([[1.0], [-1.0]])
    h_in = np.asarray(E.inner.support(d))
    h_out = np.asarray(E.outer.support(d))
    # 1e-12: float64 summation error over s ≤ ~150 terms of size ≤ 3
    assert np.all(h_in <= exact + 1e-12)
    assert np.all(h_out >= exact - 1e-12)
    assert np.all(h_out - exact <= eps)
    assert float(E.volume()) == pytest.approx(2 * r / (1 - abs(a)), abs=2 * eps)


def test_diagonal_3d_box_matches_closed_form():
    # diagonal A_cl decouples the axes: half-widths r_j/(1−|a_j|), centre c_j/(1−a_j).
    a = np.array([0.5, -0.3, 0.8])
    lo, hi = np.array([-0.01, -0.02, -0.05]), np.array([0.03, 0.02, 0.04])
    eps = 1e-7
    E = inv.mrpi(np.diag(a), inv.Box(jnp.asarray(lo), jnp.asarray(hi)), eps=eps)
    c, r = 0.5 * (lo + hi), 0.5 * (hi - lo)
    up, dn = c / (1 - a) + r / (1 - np.abs(a)), c / (1 - a) - r / (1 - np.abs(a))
    d = np.concatenate([np.eye(3), -np.eye(3)])
    exact = np.concatenate([up, -dn])
    h_in, h_out = np.asarray(E.inner.support(d)), np.asarray(E.outer.support(d))
    assert np.all(h_in <= exact + 1e-14)  # 1e-14: float64 sums of ~100 terms of size 1e-2
    assert np.all(h_out >= exact - 1e-14)
    assert np.all(h_out - exact <= eps)
    # a diagonal A keeps each generator on its axis: E is a box, volume Π 2r/(1−|a|)
    assert float(E.volume()) == pytest.approx(np.prod(up - dn), rel=1e-4)
    assert not E.exact and 0 < E.alpha < 1


# ------------------------------------------------------------------ nilpotent (deadbeat)


def test_deadbeat_finite_sum_is_exact():
    Acl = _deadbeat2()
    # (A+BK)² = 0 up to rounding (DESIGN.md); 1e-12 relative to |A_cl| ~ 1
    assert np.abs(Acl @ Acl).max() < 1e-12
    W = inv.Box(jnp.array([-0.01, -0.04]), jnp.array([0.02, 0.05]))
    E = inv.mrpi(Acl, W, eps=1e-9)
    assert E.exact and E.alpha == 0.0 and E.s == 2
    D = _sphere(2, 300)
    # independent support of W ⊕ A W (off-centre W: F_∞ = W ⊕ A W exactly)
    hW = lambda d: np.asarray(W.support(d))
    ref = hW(D) + hW(D @ Acl)
    np.testing.assert_allclose(np.asarray(E.support(D)), ref, atol=1e-14)
    np.testing.assert_allclose(np.asarray(E.inner.support(D)), ref, atol=1e-14)
    Wc = inv.Box(jnp.array([-0.015, -0.045]), jnp.array([0.015, 0.045]))  # centred W
    for s in range(2, 7):  # every truncation beyond the nilpotency index equals F_2
        Fs = inv.truncated_sum(Acl, Wc, s)
        np.testing.assert_allclose(np.asarray(Fs.support(D)), np.asarray(E_ref_support(Acl, Wc, D)),
                                   atol=1e-14)  # 1e-14: terms A^i, i ≥ 2, are ~1e-17


def E_ref_support(Acl, W, D):
    return np.asarray(W.support(D)) + np.asarray(W.support(D @ Acl))


def test_deadbeat_3state_exact_at_index_3():
    Acl = _acl3("deadbeat")
    W = inv.Box(-jnp.array([0.01, 0.01, 0.05]), jnp.array([0.012, 0.01, 0.04]))
    E = inv.mrpi(Acl, W)
    assert E.exact and E.s == 3
    D = _sphere(3, 300)
    ref = sum(np.asarray(W.support(D @ np.linalg.matrix_power(Acl, i))) for i in range(3))
    # 1e-12: Ackermann gain built in float64 leaves A_cl³ ~1e-15
    np.testing.assert_allclose(np.asarray(E.support(D)), ref, atol=1e-12)


# ------------------------------------------------------------------ zonotope facets vs Qhull


def _brute_zonotope(c, G):
    corners = np.array(list(itertools.product([-1.0, 1.0], repeat=len(G))))
    return c + corners @ G


@pytest.mark.parametrize("n", [2, 3])
def test_zonotope_facets_match_convex_hull(n):
    rng = np.random.default_rng(n)
    G = rng.normal(size=(7, n)) * 0.1
    G = np.concatenate([G, 2 * G[:1], -0.5 * G[1:2], np.zeros((1, n))])  # parallel + zero
    c = rng.normal(size=n)
    z = inv.zonotope(c, G)
    hull = ConvexHull(_brute_zonotope(c, G))
    lo, hi = hull.points.min(0), hull.points.max(0)
    P = rng.uniform(lo - 0.1 * (hi - lo), hi + 0.1 * (hi - lo), size=(100_000, n))
    signed = np.max(P @ hull.equations[:, :-1].T + hull.equations[:, -1], axis=1)
    ref = signed <= 0
    # boundary band: |signed distance| ≤ 1e-9 × set size excluded (rounding decides there)
    away = np.abs(signed) > 1e-9 * np.max(hi - lo)
    got = np.asarray(z.contains(P, tol=0.0))
    assert away.sum() > 99_000 and 0.05 < ref.mean() < 0.95
    assert np.array_equal(got[away], ref[away])
    # exact volume 2ⁿ Σ|det| against Qhull (rel 1e-9: Qhull's float64 facet sums)
    assert float(z.volume()) == pytest.approx(hull.volume, rel=1e-9)
    # every facet of the H-rep touches the brute-force vertices (no redundant offsets)
    N, b = inv.zonotope_halfspaces(z)
    touch = np.max(hull.points @ N.T, axis=0)
    np.testing.assert_allclose(touch, b, atol=1e-12)


def test_flat_zonotope_in_3d():
    # generators in the plane z = 0 → normals ±e_z plus the in-plane facets
    G = np.array([[0.1, 0.0, 0.0], [0.05, 0.05, 0.0], [0.0, 0.08, 0.0]])
    z = inv.zonotope(np.zeros(3), G)
    assert np.asarray(z.contains(np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1e-3], [0.5, 0, 0]]))).tolist() \
        == [True, False, False]
    assert float(z.volume()) == 0.0


# ------------------------------------------------------------------ invariance


@pytest.mark.parametrize("acl", ["deadbeat2", "lqr2", "deadbeat3", "lqr3"])
def test_outer_set_is_robust_invariant(acl):
    A = {"deadbeat2": _deadbeat2, "lqr2": _lqr2,
         "deadbeat3": lambda: _acl3("deadbeat"), "lqr3": lambda: _acl3("lqr")}[acl]()
    n = A.shape[0]
    lo = -np.array([0.01, 0.03, 0.05])[:n]
    hi = np.array([0.02, 0.03, 0.04])[:n]
    W = inv.Box(jnp.asarray(lo), jnp.asarray(hi))
    E = inv.mrpi(A, W, eps=1e-5)
    D = _sphere(n, 2000, seed=1)
    # A E ⊕ W ⊆ E  ⇔  h_E(Aᵀd) + h_W(d) ≤ h_E(d) for all d (support functions)
    lhs = np.asarray(E.support(D @ A)) + np.asarray(W.support(D))
    rhs = np.asarray(E.support(D))
    assert np.all(lhs <= rhs + 1e-12 * np.abs(rhs).max())  # rounding on sums of ~100 terms
    # inner ⊆ outer and outer − inner ≤ ε/… in the coordinate directions (Raković bound)
    ax = np.concatenate([np.eye(n), -np.eye(n)])
    gap = np.asarray(E.outer.support(ax)) - np.asarray(E.inner.support(ax))
    assert np.all(gap >= -1e-15) and np.all(gap <= E.eps)


def test_hull_w_template_outer():
    Acl = _lqr2()
    rng = np.random.default_rng(3)
    W = inv.Hull(rng.uniform(-1, 1, size=(300, 2)) * [0.02, 0.05] + [0.005, 0.0])
    E = inv.mrpi(Acl, W, eps=1e-5)
    assert isinstance(E.outer, inv.TemplatePolytope) and E.outer.is_outer_approximation
    D = np.asarray(E.outer.normals)
    # template offsets = h_{F_s}(D)/(1−α) about the centre; inner is the exact F_s
    c = np.asarray(E.outer.center)
    h_in = np.asarray(E.inner.support(D)) - D @ c
    np.testing.assert_allclose(np.asarray(E.outer.offsets) - D @ c, h_in / (1 - E.alpha),
                               rtol=1e-9)
    # the inner F_s support equals the sum of supports of A^i W₀ (independent of the hull sum)
    Wc = W.canonical()
    V0 = np.asarray(Wc.vertices) - np.asarray(Wc.vertices).mean(0)
    ref = sum(np.max((D @ np.linalg.matrix_power(Acl, i)) @ V0.T, axis=1) for i in range(E.s))
    np.testing.assert_allclose(h_in, ref, atol=1e-12)
    # ... and the exact mRPI lies inside: long simulated trajectories stay in the outer set
    w = np.asarray(Wc.vertices)[rng.integers(0, len(Wc.vertices), 4000)]
    e = np.zeros(2)
    es = []
    for wk in w:
        e = Acl @ e + wk
        es.append(e)
    assert bool(np.all(np.asarray(E.contains(np.array(es)))))


# ------------------------------------------------------------------ coverage


def _simulate(Acl, lo, hi, n_scen, n_steps, seed):
    rng = np.random.default_rng(seed)
    n = len(lo)
    w = rng.uniform(lo, hi, size=(n_scen, n_steps, n))
    e = np.zeros((n_scen, n_steps, n))
    for k in range(1, n_steps):
        e[:, k] = e[:, k - 1] @ Acl.T + w[:, k - 1]
    return w, e


@pytest.mark.parametrize("acl", ["deadbeat2", "lqr3"])
def test_coverage_is_one_in_sample(acl):
    Acl = _deadbeat2() if acl == "deadbeat2" else _acl3("lqr")
    n = Acl.shape[0]
    lo, hi = -np.array([0.01, 0.02, 0.04])[:n], np.array([0.015, 0.02, 0.05])[:n]
    w, e = _simulate(Acl, lo, hi, 20, 60, seed=5)
    W = inv.estimate_w(w[:, :-1].reshape(-1, n))
    E = inv.mrpi(Acl, W)
    cov = inv.coverage(E, e)
    assert cov.outer == 1.0 and cov.n == e.shape[0] * e.shape[1]
    if E.exact:
        assert cov.inner == 1.0
    if n == 2:  # hull W from the same samples: every e_k = w_{k−1} + A w_{k−2} lies in E
        Eh = inv.mrpi(Acl, inv.estimate_w(w[:, :-1].reshape(-1, n), method="hull"))
        assert inv.coverage(Eh, e).outer == 1.0


def test_facet_widths_in_blocks_are_the_whole_arrays_sums(monkeypatch):
    # h_f = Σ_k |N_f·g_k| (and the prefix widths of the first facet rows) formed a few rows
    # at a time: the same numbers bit for bit as the sums over the whole |N Gᵀ|, also where
    # the prefix rows span several blocks
    monkeypatch.setattr(sets, "_WIDTH_ROWS", 7)
    rng = np.random.default_rng(3)
    G, N = rng.normal(size=(40, 3)), rng.normal(size=(53, 3))
    P = np.abs(sets._small_matmul_t(N, G))
    for n0, n_prefix in [(0, 0), (5, 9), (23, 12), (53, 40)]:
        h, h0 = sets._facet_widths(N, G, n0, n_prefix)
        assert np.array_equal(h, P.sum(axis=1))
        assert (h0 is None) if n0 == 0 else np.array_equal(h0, P[:n0, :n_prefix].sum(axis=1))
    z = sets.zonotope(np.zeros(3), G, n_prefix=10)
    monkeypatch.setattr(sets, "_WIDTH_ROWS", 1 << 30)
    whole = sets.zonotope(np.zeros(3), G, n_prefix=10)
    assert np.array_equal(z.offsets, whole.offsets)
    assert np.array_equal(z.prefix_offsets, whole.prefix_offsets)


def test_two_pass_membership_matches_full_facet_test():
    # LQR F_s has tens of terms: membership first uses the facets of the leading terms,
    # then the full facet set on the undecided band; it must equal the single full pass.
    E = inv.mrpi(_acl3("lqr"), inv.Box(-jnp.array([0.01, 0.01, 0.05]),
                                       jnp.array([0.012, 0.01, 0.06])))
    assert E.outer.prefix_offsets is not None
    scale = np.asarray(E.outer.support(np.eye(3)))
    P = np.random.default_rng(2).uniform(-1.1, 1.1, (60_000, 3)) * scale
    two = np.asarray(E.outer.contains(P))
    one = np.asarray(E.outer._replace(prefix_offsets=None).contains(P))
    assert np.array_equal(two, one) and 0.05 < two.mean() < 0.95
    # the prefix facets describe F_{s0}/(1−α) ⊆ E: its vertices satisfy E's facets
    F0 = E.outer.prefix_offsets.shape[0]
    sub = inv.Zonotope(E.outer.center, None, E.outer.normals[:F0], E.outer.prefix_offsets)
    N, b = sets.zonotope_halfspaces(sub._replace(generators=np.zeros((0, 3))))
    V = sets.halfspace_vertices(N, b, E.outer.center)
    assert np.all(np.asarray(E.outer._replace(prefix_offsets=None).contains(V, tol=1e-9)))


def test_contains_jits_and_vmaps():
    E = inv.mrpi(_acl3("lqr"), inv.Box(-jnp.ones(3) * 0.01, jnp.ones(3) * 0.02))
    P = np.random.default_rng(0).normal(size=(4, 50, 3)) * 0.03
    ref = np.asarray(E.contains(P))
    f = jax.jit(lambda S, x: S.contains(x))
    assert np.array_equal(np.asarray(f(E.outer, P)), ref)
    g = jax.vmap(lambda x: E.outer.contains(x))
    assert np.array_equal(np.asarray(g(jnp.asarray(P))), ref)
    b = inv.Box(jnp.zeros(3), jnp.ones(3))
    assert np.asarray(jax.jit(lambda S, x: S.contains(x))(b, np.array([[0.5, 0.5, 0.5], [2, 0, 0]]))).tolist() \
        == [True, False]


# ------------------------------------------------------------------ logs, analyse, end to end


def _log(n_scen, n_steps, seed, lo, hi):
    """Linear closed loop around the zero H-LIP orbit: x_HLIP = 0, u_HLIP = 0, so e = x and
    u_exec = K x (per plane; sagittal deadbeat, lateral LQR, 3-state [c, p, v])."""
    A, B = hlip.s2s_matrices(Z0, TS, TD, with_position=True)
    A, B = np.asarray(A), np.asarray(B)
    K = np.stack([np.asarray(hlip.deadbeat_gain(Z0, TS, TD, with_position=True)),
                  np.asarray(_lqr_gain(jnp.asarray(A), jnp.asarray(B), jnp.eye(3),
                                           jnp.array(1.0)))])
    rng = np.random.default_rng(seed)
    w = rng.uniform(lo, hi, size=(n_scen, n_steps, 2, 3))
    x = np.zeros((n_scen, n_steps, 2, 3))
    u = np.zeros((n_scen, n_steps, 2))
    for k in range(n_steps):
        u[:, k] = np.einsum("pj,spj->sp", K, x[:, k])
        if k + 1 < n_steps:
            x[:, k + 1] = x[:, k] @ A.T + B * u[:, k, :, None] + w[:, k]
    return A, B, K, x, u, w


def test_disturbances_recover_w_and_mask():
    lo, hi = np.array([-0.01, -0.01, -0.05]), np.array([0.01, 0.02, 0.05])
    A, B, K, x, u, w = _log(3, 12, 0, lo, hi)
    valid = np.ones((3, 12), bool)
    valid[1, 7] = False  # failure at step 7 of scenario 1: everything after is dropped
    d = inv.disturbances(x, u, valid, A, B, transient=2)
    # w recovered to rounding (1e-14: states ~0.1, products with |A| ~ 3)
    np.testing.assert_allclose(np.asarray(d.w), w[:, :-1], atol=1e-14)
    m = np.asarray(d.mask)
    assert m.shape == (3, 11)
    assert not m[:, :2].any() and m[0, 2:].all()
    assert m[1, 2:6].all() and not m[1, 6:].any()
    d2 = inv.disturbances(x, u, valid, A[1:, 1:], B[1:])  # [p, v] subsystem
    np.testing.assert_allclose(np.asarray(d2.w), w[:, :-1, :, 1:], atol=1e-14)
    with pytest.raises(ValueError, match="u_exec"):
        inv.disturbances(x, u[..., :1], valid, A, B)
    with pytest.raises(ValueError, match="A:"):
        inv.disturbances(x, u, valid, np.eye(4), B)


def test_end_to_end_w_converges_and_heldout_coverage():
    lo, hi = np.array([-0.01, -0.01, -0.05]), np.array([0.01, 0.02, 0.05])
    err = []
    for n_scen in (2, 20, 200):
        A, B, K, x, u, w = _log(n_scen, 25, 11, lo, hi)
        d = inv.disturbances(x, u, np.ones(x.shape[:2], bool), A, B)
        W = inv.estimate_w(np.asarray(d.w)[..., 0, :], np.asarray(d.mask))
        err.append(max(np.abs(np.asarray(W.lo) - lo).max(), np.abs(np.asarray(W.hi) - hi).max()))
    # min/max of N uniform samples: gap ~ width/N → shrinks by ~10× per 10× data
    assert err[0] > err[1] > err[2] and err[2] < 1e-3
    res = inv.analyse(x, u, np.ones(x.shape[:2], bool), x, A, B, K, transient=0,
                      holdout_fraction=0.25, seed=4)
    assert len(res.test) == 50 and len(np.intersect1d(res.test, res.train)) == 0
    for p in res.planes:
        assert p.coverage.outer == 1.0
        assert p.heldout.outer >= 0.99
        assert p.volume > 0 and p.s >= 1
    assert res.planes[0].E.exact  # sagittal deadbeat
    assert res.combined.outer == 1.0 and res.combined_heldout.outer >= 0.99
    # [p, v] analysis of the same log (A 2×2 drops c); quantile box reports fewer inside
    A2, B2 = A[1:, 1:], B[1:]
    K2 = np.stack([np.asarray(hlip.deadbeat_gain(Z0, TS, TD)),
                   np.asarray(_lqr_gain(jnp.asarray(A2), jnp.asarray(B2), jnp.eye(2),
                                            jnp.array(1.0)))])
    r2 = inv.analyse(x, u, np.ones(x.shape[:2], bool), x, A2, B2, K2, W_estimator="quantile",
                     quantile=0.95)
    assert r2.planes[0].E.dim == 2 and r2.planes[0].coverage.outer < 1.0


def test_placement_errors_enter_the_error_disturbance():
    """A robot that over-steps by 1 cm on average (sagittal, ±1.2 cm), with S2S noise w of
    ±1 mm: e⁺ = A_cl e + w + B δu.  placement_errors recovers δu from the log (1e-12 m:
    rounding of ~0.1 m sums); E from d = w + B δu covers every error in-sample (the recursion
    holds exactly, e_0 = 0 and W ∋ 0, so e_k ∈ ⊕_{i<k} A_cl^i W ⊆ F_∞ ⊆ F_s/(1−α); tolerance
    1e-9 of the membership test), while E from w alone misses the offset the bias drives
    (bound 0.5 of the sagittal errors inside)."""
    A, B = hlip.s2s_matrices(Z0, TS, TD, with_position=True)
    A, B = np.asarray(A), np.asarray(B)
    k = np.asarray(_lqr_gain(jnp.asarray(A), jnp.asarray(B), jnp.diag(jnp.array([0.05, 1.0, 0.25])),
                             jnp.array(4.0)))
    K = np.stack([k, k])
    rng = np.random.default_rng(3)
    n_scen, n_steps = 4, 60
    w = rng.uniform(-1e-3, 1e-3, size=(n_scen, n_steps, 2, 3))
    du = rng.uniform(-0.012, 0.012, size=(n_scen, n_steps, 2)) + np.array([0.01, 0.0])
    # the H-LIP walks under its own feedback plus random steps (open loop it diverges, and
    # the sums lose every digit of w)
    u_h = rng.uniform(-0.05, 0.05, size=(n_scen, n_steps, 2))
    x_h = np.zeros((n_scen, n_steps, 2, 3))
    x_r = np.zeros_like(x_h)
    u_r = np.zeros_like(u_h)
    for j in range(n_steps):
        u_h[:, j] += np.einsum("pj,spj->sp", K, x_h[:, j])
        e = x_r[:, j] - x_h[:, j]
        u_r[:, j] = u_h[:, j] + np.einsum("pj,spj->sp", K, e) + du[:, j]
        if j + 1 < n_steps:
            x_h[:, j + 1] = x_h[:, j] @ A.T + B * u_h[:, j, :, None]
            x_r[:, j + 1] = x_r[:, j] @ A.T + B * u_r[:, j, :, None] + w[:, j]
    e = x_r - x_h
    np.testing.assert_allclose(inv.placement_errors(u_r, u_h, e, K), du, atol=1e-12)
    np.testing.assert_allclose(inv.placement_errors(u_r, u_h, e, k), du, atol=1e-12)
    valid = np.ones((n_scen, n_steps), bool)
    with_du = inv.analyse(x_r, u_r, valid, e, A, B, K, u_hlip=u_h)
    d = w[:, :-1] + B * du[:, :-1, :, None]
    for p in range(2):
        W = with_du.planes[p].W
        np.testing.assert_allclose(np.asarray(W.lo), d[:, :, p].min(axis=(0, 1)), atol=1e-12)
        np.testing.assert_allclose(np.asarray(W.hi), d[:, :, p].max(axis=(0, 1)), atol=1e-12)
        assert np.all(np.asarray(W.lo) < 0) and np.all(np.asarray(W.hi) > 0)    # W ∋ 0
        assert with_du.planes[p].coverage.outer == 1.0
    without = inv.analyse(x_r, u_r, valid, e, A, B, K)
    assert without.planes[0].coverage.outer < 0.5, without.planes[0].coverage


def test_bad_inputs_name_the_field():
    with pytest.raises(ValueError, match="Schur"):
        inv.mrpi(np.array([[1.1]]), inv.Box(jnp.array([-1.0]), jnp.array([1.0])))
    with pytest.raises(ValueError, match="hi > lo"):
        inv.mrpi(np.array([[0.5]]), inv.Box(jnp.array([1.0]), jnp.array([1.0])))
    flat = inv.Box(jnp.array([-1.0, 0.0]), jnp.array([1.0, 0.0]))  # no disturbance on axis 1
    with pytest.raises(ValueError, match="min_halfwidth"):
        inv.mrpi(np.diag([0.5, 0.5]), flat)
    E = inv.mrpi(np.diag([0.5, 0.5]), flat, min_halfwidth=1e-6)
    # widened axis: half-width 1e-6/(1−0.5); ε = 1e-5 bound on the outer set
    assert float(E.support(np.array([0.0, 1.0]))) == pytest.approx(2e-6, abs=1e-5)
    with pytest.raises(ValueError, match="quantile"):
        inv.estimate_w(np.zeros((5, 2)), method="quantile", quantile=0.2)
    with pytest.raises(ValueError, match="method"):
        inv.estimate_w(np.zeros((5, 2)), method="ellipse")


def test_figures(tmp_path):
    import matplotlib
    matplotlib.use("Agg")
    E3 = inv.mrpi(_acl3("lqr"), inv.Box(-jnp.ones(3) * 0.01, jnp.ones(3) * 0.02))
    E2 = inv.mrpi(_deadbeat2(), inv.Box(-jnp.ones(2) * 0.01, jnp.ones(2) * 0.02))
    rng = np.random.default_rng(0)
    fig = set_figures.plot_planes((E3, E2), (rng.normal(size=(200, 3)) * 0.03,
                                     rng.normal(size=(200, 2)) * 0.02), title="E")
    fig.savefig(tmp_path / "e.png")
    assert (tmp_path / "e.png").stat().st_size > 1000
    ax = set_figures.plot_set_2d(E3, rng.normal(size=(100, 3)) * 0.03, dims=(1, 2))  # [p, v] projection
    assert ax.get_xlabel() == "p [m]"


def test_drawn_outlines_are_the_sets_projection_and_inside_the_set():
    """The figures' outlines of a 3-state mRPI zonotope: a 2-D projection's points span
    exactly the projection of the exact vertices (hull areas equal to 1e-9 relative, and each
    polygon inside the other to 1e-9 of the set's size); the 3-D outline's points lie in E
    (gauge ≤ 1 + 1e-9) and their hull holds at least 97 % of E's exact volume.  The same for a
    calibrated set, E scaled about its centre."""
    from scipy.spatial import ConvexHull
    E = inv.mrpi(_acl3("lqr"), inv.Box(np.array([-0.01, -0.02, -0.03]), np.array([0.02, 0.01, 0.05])))
    for S in (E, sets.Scaled(E, 0.7)):
        V = sets.vertices(S)
        size = np.ptp(V, axis=0).max()
        for dims in ((0, 1), (1, 2), (0, 2)):
            exact = ConvexHull(V[:, dims])
            P = set_figures.projected_outline(S, dims)
            assert ConvexHull(P).volume == pytest.approx(exact.volume, rel=1e-9)
            drawn = ConvexHull(P)
            for H, Q in ((drawn, V[:, dims]), (exact, P)):     # each polygon inside the other
                assert np.max(Q @ H.equations[:, :2].T + H.equations[:, 2]) < 1e-9 * size
        P3 = set_figures.outline(S)
        assert np.all(sets.gauge(S.base if isinstance(S, sets.Scaled) else S, P3)
                      <= (S.s if isinstance(S, sets.Scaled) else 1.0) * (1 + 1e-9))
        assert ConvexHull(P3).volume >= 0.97 * float(S.volume())


def test_analyse_with_hull_estimator():
    # deadbeat sagittal / LQR lateral on [p, v]: hull W from the same log covers every e_k
    lo, hi = np.array([-0.01, -0.01, -0.05]), np.array([0.01, 0.02, 0.05])
    A, B, _, x, u, _ = _log(12, 20, 7, lo, hi)
    A2, B2 = A[1:, 1:], B[1:]
    K2 = np.stack([np.asarray(hlip.deadbeat_gain(Z0, TS, TD)),
                   np.asarray(_lqr_gain(jnp.asarray(A2), jnp.asarray(B2), jnp.eye(2),
                                        jnp.array(1.0)))])
    # the log was closed with 3-state gains; recompute u so that the [p, v] loop is the one run
    x2 = np.zeros_like(x)
    u2 = np.zeros_like(u)
    w = np.random.default_rng(7).uniform(lo, hi, size=x.shape)
    for k in range(x.shape[1]):
        u2[:, k] = np.einsum("pj,spj->sp", K2, x2[:, k, :, 1:])
        if k + 1 < x.shape[1]:
            x2[:, k + 1] = x2[:, k] @ A.T + B * u2[:, k, :, None] + w[:, k]
    res = inv.analyse(x2, u2, np.ones(x.shape[:2], bool), x2, A2, B2, K2, W_estimator="hull",
                      holdout_fraction=0.25, seed=1)
    for p in res.planes:
        assert isinstance(p.W, inv.Hull) and p.coverage.outer == 1.0
        assert p.heldout.n > 0 and p.volume > 0


# ------------------------------------------------------------------ heading frame


def test_heading_frame_keeps_the_error_recursion():
    """World errors e⁺ = A_cl e + d (same A_cl in both planes, 3-state LQR) seen from a frame
    that turns with the path (random headings, up to ±0.6 rad between steps): the rotated
    errors obey e'⁺ = A_cl e' + d' with the returned d' (1e-12: float64 sums of ~0.1 terms);
    on a constant heading d' is d rotated (no turn term); rotations keep each component's
    length."""
    Acl = _acl3("lqr")
    rng = np.random.default_rng(5)
    S, K = 3, 30
    d = rng.uniform(-0.02, 0.02, size=(S, K - 1, 2, 3))
    e = np.zeros((S, K, 2, 3))
    e[:, 0] = rng.uniform(-0.05, 0.05, size=(S, 2, 3))
    for k in range(K - 1):
        e[:, k + 1] = e[:, k] @ Acl.T + d[:, k]
    th = np.cumsum(rng.uniform(-0.6, 0.6, size=(S, K)), axis=1)
    e_h, d_h = inv.heading_frame(e, d, th, Acl)
    np.testing.assert_allclose(e_h[:, 1:], e_h[:, :-1] @ Acl.T + d_h, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(e_h, axis=-2), np.linalg.norm(e, axis=-2),
                               atol=1e-12)
    th_c = np.full((S, K), 2.0)
    e_c, d_c = inv.heading_frame(e, d, th_c, np.stack([Acl, Acl]))
    np.testing.assert_allclose(d_c, inv.to_heading(d, th_c[:, 1:]), atol=1e-15)
    # walking along +y (θ = 90°): sagittal = world y, lateral = −world x
    np.testing.assert_allclose(inv.to_heading(e, np.full((S, K), np.pi / 2)),
                               np.stack([e[..., 1, :], -e[..., 0, :]], axis=-2), atol=1e-15)
    with pytest.raises(ValueError, match="same closed loop"):
        inv.heading_frame(e, d, th, np.stack([Acl, _acl3("deadbeat")]))
    with pytest.raises(ValueError, match="heading"):
        inv.heading_frame(e, d, th[:, 1:], Acl)


def test_analyse_in_the_heading_frame_pools_a_walking_bias():
    """Robots that over-step by a ∈ [−0.5, 1.5] cm along their own walking direction and by
    b ∈ ±2 mm sideways, on straight paths heading 0°, 90°, 180° and 270° (x_HLIP = 0,
    u = K x + R(θ)ᵀ(a, b)).  In the heading frame every robot's disturbance is B·a in the
    sagittal plane and B·b in the lateral one: W's boxes are exactly those (1e-12).  Both
    frames cover every error in-sample (e_0 = 0 and W ∋ 0; membership tolerance 1e-9), but
    the world frame pools the bias pointing both ways along x and y: its box is 1.5× wider in
    each axis (≈ 3.4× in volume), and its sagittal E measured 3.3× the heading frame's volume
    (bound 2×)."""
    A, B = hlip.s2s_matrices(Z0, TS, TD, with_position=True)
    A, B = np.asarray(A), np.asarray(B)
    k = np.asarray(_lqr_gain(jnp.asarray(A), jnp.asarray(B), jnp.eye(3), jnp.array(1.0)))
    K = np.stack([k, k])
    rng = np.random.default_rng(2)
    S, n = 8, 40
    th = np.repeat(np.deg2rad([0.0, 90.0, 180.0, 270.0]), 2)[:, None] * np.ones((S, n))
    a = rng.uniform(-0.005, 0.015, size=(S, n))
    b = rng.uniform(-0.002, 0.002, size=(S, n))
    x = np.zeros((S, n, 2, 3))
    u = np.zeros((S, n, 2))
    for j in range(n):
        c, s = np.cos(th[:, j]), np.sin(th[:, j])
        u[:, j] = np.einsum("pj,spj->sp", K, x[:, j]) + np.stack(
            [c * a[:, j] - s * b[:, j], s * a[:, j] + c * b[:, j]], axis=-1)
        if j + 1 < n:
            x[:, j + 1] = x[:, j] @ A.T + B * u[:, j, :, None]
    valid = np.ones((S, n), bool)
    u_h = np.zeros_like(u)
    hd = inv.analyse(x, u, valid, x, A, B, K, u_hlip=u_h, heading=th)
    wd = inv.analyse(x, u, valid, x, A, B, K, u_hlip=u_h)
    for p, m in enumerate((a, b)):
        Bm = B[None, :] * m[:, :-1].reshape(-1, 1)
        W = hd.planes[p].W
        np.testing.assert_allclose(np.asarray(W.lo), Bm.min(axis=0), atol=1e-12)
        np.testing.assert_allclose(np.asarray(W.hi), Bm.max(axis=0), atol=1e-12)
        assert hd.planes[p].coverage.outer == 1.0 and wd.planes[p].coverage.outer == 1.0
    assert hd.planes[0].volume * 2.0 < wd.planes[0].volume


def test_membership_of_traced_sets_and_host_points():
    """Host points (numpy or a list) against a set inside jit (its leaves traced) and outside
    it: the same answer, exactly (points at ±0.5 and ±2 from a unit box's facets)."""
    z = sets.zonotope(np.zeros(2), np.eye(2))
    P = np.array([[0.5, 0.5], [2.0, 0.0], [-0.5, 0.9]])
    want = [True, False, True]
    assert np.asarray(jax.jit(lambda z: z.contains(P))(z)).tolist() == want
    assert np.asarray(z.contains(P)).tolist() == want
    assert np.asarray(z.contains(P.tolist())).tolist() == want


def test_closed_loop_per_anchor():
    """:func:`inv.closed_loop` in closed form on the paper's example H-LIP (z0 0.75 m, T_S 0.35 s,
    T_D 0.05 s) with its 3-state deadbeat gain: the tube's A + BK (nilpotent: (A + BK)³ = 0);
    anchoring c zeroes A's c column (c no longer integrates: the c column of A_cl is B K_c);
    anchoring everything ("measured") leaves e⁺ = w (A_cl = 0, no placement term).  Exact up
    to float64 rounding (1e-12 on O(10) entries)."""
    from hlip_jax.core import hlip
    A, B = (np.asarray(m, np.float64) for m in hlip.s2s_matrices(0.75, 0.35, 0.05, 9.81))
    K = np.asarray(hlip.deadbeat_gain(0.75, 0.35, 0.05, 9.81, with_position=True), np.float64)
    tube, beta = inv.closed_loop(A, B, K)
    np.testing.assert_allclose(tube[0], A + np.outer(B, K), atol=1e-12)
    np.testing.assert_allclose(np.linalg.matrix_power(tube[1], 3), 0, atol=1e-6)
    assert beta == 1.0
    pos, beta = inv.closed_loop(A, B, K, [1.0, 0.0, 0.0])
    np.testing.assert_allclose(pos[0][:, 0], B * K[0], atol=1e-12)
    np.testing.assert_allclose(pos[0][:, 1:], tube[0][:, 1:], atol=1e-12)
    assert beta == 1.0
    meas, beta = inv.closed_loop(A, B, K, [1.0, 1.0, 1.0])
    assert not meas.any() and beta == 0.0
