"""Tests of hlip_jax.core.qp against OSQP 1.x (the C solver whose algorithm qp.py implements).

Reference solutions come from OSQP at eps 1e-9 with solution polishing, i.e. accurate to
near machine precision, so the tolerances below are set by our own stopping tolerance:
  * float64, eps_abs = eps_rel = 1e-7: x agrees to 1e-5 relative (‖Δx‖∞ ≤ 1e-5·max(1, ‖x*‖∞));
    with ∞-norm residuals ≤ ~1e-7 and the smallest curvature ≥ 1e-2 (or a vertex solution for
    LPs) the error bound r/λ_min ≈ 1e-5 is what the residual test guarantees.
  * float32, eps = 1e-4: x agrees to 1e-3 relative, by the same argument at 1e-4 residuals.
"""

import jax
import jax.numpy as jnp
import numpy as np
import osqp
import pytest
import scipy.sparse as sp

from hlip_jax.core import qp

TIGHT64 = qp.Settings(eps_abs=1e-7, eps_rel=1e-7, max_iter=20000)
LOOSE32 = qp.Settings(eps_abs=1e-4, eps_rel=1e-4, max_iter=20000)


# --- problem generators -------------------------------------------------------------------------
def random_qp(rng, n, m, kind="pd"):
    """A random feasible QP with inequality, equality and one-sided rows.

    kind: "pd" well-conditioned P ≻ 0; "ill" P with eigenvalues in [1e-2, 1e2] (cond 1e4);
    "lp" P = 0 (box rows |x_i| ≤ 1 keep it bounded); "psd" rank-deficient P (n/2) + box rows.
    """
    if kind == "pd":
        M = rng.standard_normal((n, n))
        P = M @ M.T / n + 0.1 * np.eye(n)
    elif kind == "ill":
        Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
        P = (Q * np.logspace(-2, 2, n)) @ Q.T
    elif kind == "lp":
        P = np.zeros((n, n))
    elif kind == "psd":
        M = rng.standard_normal((n, max(1, n // 2)))
        P = M @ M.T / n
    else:
        raise ValueError(kind)
    P = 0.5 * (P + P.T)
    q = rng.standard_normal(n)
    x_feas = rng.uniform(-0.5, 0.5, n)
    m_gen = m - n if kind in ("lp", "psd") else m
    A = rng.standard_normal((m_gen, n))
    Ax = A @ x_feas
    l = Ax - rng.uniform(0.1, 1.0, m_gen)
    u = Ax + rng.uniform(0.1, 1.0, m_gen)
    row = rng.permutation(m_gen)
    n_eq = min(max(1, m_gen // 8), n // 2)
    eq, upper, lower = row[:n_eq], row[n_eq:n_eq + m_gen // 6], row[n_eq + m_gen // 6:n_eq + m_gen // 3]
    l[eq] = u[eq] = Ax[eq]
    l[upper] = -np.inf
    u[lower] = 1e30  # ≥ 1e20 counts as infinite in both solvers
    if kind in ("lp", "psd"):
        A = np.vstack([A, np.eye(n)])
        l = np.concatenate([l, -np.ones(n)])
        u = np.concatenate([u, np.ones(n)])
    return P, q, A, l, u


def primal_infeasible_qp(rng, n, m):
    """Rows a·x ≥ 1 and a·x ≤ −1 together: no feasible point."""
    P, q, A, l, u = random_qp(rng, n, m)
    A[1] = A[0]
    l[0], u[0] = 1.0, np.inf
    l[1], u[1] = -np.inf, -1.0
    return P, q, A, l, u


def dual_infeasible_qp(rng, n, m):
    """The last variable has no curvature, no constraint and negative cost: unbounded below."""
    P, q, A, l, u = random_qp(rng, n, m)
    P[-1, :] = 0.0
    P[:, -1] = 0.0
    A[:, -1] = 0.0
    q[-1] = -1.0
    return P, q, A, l, u


def osqp_solve(P, q, A, l, u, eps=1e-9):
    prob = osqp.OSQP()
    prob.setup(P=sp.csc_matrix(np.triu(P)), q=q, A=sp.csc_matrix(A), l=l, u=u,
               eps_abs=eps, eps_rel=eps, polishing=True, verbose=False, max_iter=200000)
    return prob.solve(raise_error=False)


def stack(problems):
    return [np.stack(a) for a in zip(*problems)]


def rel_err(x, ref):
    return np.max(np.abs(x - ref)) / max(1.0, np.max(np.abs(ref)))


# --- accuracy against OSQP ----------------------------------------------------------------------
CASES = [  # (n, m, kind); each case is a batch of 3 random problems solved in one call
    (2, 3, "pd"),
    (5, 12, "pd"),
    (16, 32, "pd"),
    (64, 128, "pd"),
    (12, 24, "ill"),
    (8, 20, "lp"),
    (20, 44, "lp"),
    (10, 24, "psd"),
]


@pytest.mark.parametrize("n,m,kind", CASES)
def test_float64_matches_osqp(n, m, kind):
    rng = np.random.default_rng(1000 * n + m)
    probs = [random_qp(rng, n, m, kind) for _ in range(3)]
    sol = qp.solve(*stack(probs), settings=TIGHT64)
    assert sol.x.dtype == jnp.float64
    for k, prob in enumerate(probs):
        ref = osqp_solve(*prob)
        assert ref.info.status_val == qp.SOLVED
        assert int(sol.status[k]) == qp.SOLVED
        # 1e-5 relative at eps 1e-7 (see module docstring).
        assert rel_err(np.asarray(sol.x[k]), ref.x) < 1e-5
        P, q = prob[0], prob[1]
        obj = lambda x: 0.5 * x @ P @ x + q @ x
        assert abs(obj(np.asarray(sol.x[k])) - obj(ref.x)) < 1e-5 * max(1.0, abs(obj(ref.x)))
        if kind in ("pd", "ill"):  # unique multipliers for strictly convex generic problems
            assert rel_err(np.asarray(sol.y[k]), ref.y) < 1e-4


@pytest.mark.parametrize("n,m,kind", [(10, 24, "psd"), (16, 32, "pd"), (20, 44, "lp")])
def test_iteration_counts_match_osqp(n, m, kind):
    # Same algorithm, same defaults (check every 25, adaptive ρ every 50): OSQP (duality-gap test
    # off, no polishing) stops at the same check; one check of slack allows for rounding.
    rng = np.random.default_rng(1000 * n + m)
    probs = [random_qp(rng, n, m, kind) for _ in range(3)]
    sol = qp.solve(*stack(probs), settings=TIGHT64)
    for k, (P, q, A, l, u) in enumerate(probs):
        prob = osqp.OSQP()
        prob.setup(P=sp.csc_matrix(np.triu(P)), q=q, A=sp.csc_matrix(A), l=l, u=u, eps_abs=1e-7,
                   eps_rel=1e-7, polishing=False, check_dualgap=False, verbose=False,
                   max_iter=TIGHT64.max_iter)
        ref = prob.solve(raise_error=False)
        assert abs(int(sol.iterations[k]) - ref.info.iter) <= TIGHT64.check_interval


@pytest.mark.parametrize("n,m,kind", [(5, 12, "pd"), (16, 32, "pd"), (8, 20, "lp")])
def test_float32_matches_osqp(n, m, kind):
    rng = np.random.default_rng(7 * n + m)
    probs = [random_qp(rng, n, m, kind) for _ in range(3)]
    args = [a.astype(np.float32) for a in stack(probs)]
    sol = qp.solve(*args, settings=LOOSE32)
    assert sol.x.dtype == jnp.float32
    for k, prob in enumerate(probs):
        ref = osqp_solve(*prob)
        assert int(sol.status[k]) == qp.SOLVED
        # 1e-3 relative at eps 1e-4 (see module docstring).
        assert rel_err(np.asarray(sol.x[k]), ref.x) < 1e-3


@pytest.mark.parametrize("make,status", [(primal_infeasible_qp, qp.PRIMAL_INFEASIBLE),
                                         (dual_infeasible_qp, qp.DUAL_INFEASIBLE)])
def test_infeasibility_statuses_match_osqp(make, status):
    rng = np.random.default_rng(3)
    probs = [make(rng, 6, 14) for _ in range(3)]
    sol = qp.solve(*stack(probs), settings=qp.Settings(eps_abs=1e-6, eps_rel=1e-6))
    for k, prob in enumerate(probs):
        ref = osqp_solve(*prob, eps=1e-6)
        assert ref.info.status_val == status
        assert int(sol.status[k]) == status


def test_warm_start_converges_within_one_check_interval():
    rng = np.random.default_rng(1000 * 16 + 32)  # the (16, 32) accuracy problems (compile reused)
    probs = [random_qp(rng, 16, 32) for _ in range(3)]
    args = stack(probs)
    sol = qp.solve(*args, settings=TIGHT64)
    assert np.all(np.asarray(sol.status) == qp.SOLVED)
    assert np.all(np.asarray(sol.iterations) > TIGHT64.check_interval)
    warm = qp.solve(*args, settings=TIGHT64, warm_start=(sol.x, sol.y))
    assert np.all(np.asarray(warm.status) == qp.SOLVED)
    assert np.all(np.asarray(warm.iterations) == TIGHT64.check_interval)
    np.testing.assert_allclose(warm.x, sol.x, atol=1e-6)  # both within the 1e-7 residual ball


# --- batching semantics ---------------------------------------------------------------------------
def test_infeasible_and_nan_problems_do_not_change_the_others():
    rng = np.random.default_rng(5)
    good = [random_qp(rng, 6, 14) for _ in range(3)]
    bad_p = primal_infeasible_qp(rng, 6, 14)
    nan = [a.copy() for a in good[1]]
    nan[0][0, 0] = np.nan
    ref = qp.solve(*stack(good), settings=TIGHT64)
    for bad in (bad_p, nan):
        mixed = qp.solve(*stack([good[0], bad, good[2]]), settings=TIGHT64)
        for k in (0, 2):  # same compiled program, frozen iterates: bitwise identical results
            np.testing.assert_array_equal(mixed.x[k], ref.x[k])
            np.testing.assert_array_equal(mixed.y[k], ref.y[k])
            assert int(mixed.iterations[k]) == int(ref.iterations[k])
    mixed = qp.solve(*stack([good[0], nan, good[2]]), settings=TIGHT64)
    assert int(mixed.status[1]) == qp.UNSOLVED
    assert np.all(np.isnan(np.asarray(mixed.x[1])))
    assert np.all(np.isfinite(np.asarray(mixed.x)[[0, 2]]))


def test_leading_batch_axes_broadcast_and_match_single_solves():
    rng = np.random.default_rng(6)
    P, q, A, l, u = random_qp(rng, 4, 9)
    qs = rng.standard_normal((2, 3, 4))
    sol = qp.solve(P, qs, A, l, u, settings=TIGHT64)
    assert sol.x.shape == (2, 3, 4) and sol.y.shape == (2, 3, 9) and sol.status.shape == (2, 3)
    one = qp.solve(P, qs[1, 2], A, l, u, settings=TIGHT64)
    np.testing.assert_allclose(sol.x[1, 2], one.x, atol=1e-9)


def test_jit_and_external_vmap():
    rng = np.random.default_rng(8)
    probs = stack([random_qp(rng, 5, 12) for _ in range(3)])
    f = jax.jit(jax.vmap(lambda *a: qp.solve(*a, settings=TIGHT64)))
    a = f(*probs)
    b = qp.solve(*probs, settings=TIGHT64)
    np.testing.assert_allclose(a.x, b.x, atol=1e-9)
    np.testing.assert_array_equal(a.status, b.status)


@pytest.mark.parametrize("max_iter,check", [(37, 10), (40, 20), (1, 5)])
def test_max_iter_and_check_interval_are_honoured_exactly(max_iter, check):
    rng = np.random.default_rng(9)
    probs = stack([random_qp(rng, 5, 12, "ill") for _ in range(2)])
    s = qp.Settings(eps_abs=1e-12, eps_rel=1e-12, max_iter=max_iter, check_interval=check,
                    adaptive_rho_interval=check)
    sol = qp.solve(*probs, settings=s)
    np.testing.assert_array_equal(sol.iterations, [max_iter, max_iter])
    assert set(np.asarray(sol.status).tolist()) <= {qp.MAX_ITER, qp.SOLVED_INACCURATE}


def test_iterations_are_multiples_of_check_interval():
    rng = np.random.default_rng(10)
    probs = stack([random_qp(rng, 5, 12) for _ in range(3)])
    s = qp.Settings(eps_abs=1e-6, eps_rel=1e-6, check_interval=7, adaptive_rho_interval=21)
    sol = qp.solve(*probs, settings=s)
    assert np.all(np.asarray(sol.status) == qp.SOLVED)
    assert np.all(np.asarray(sol.iterations) % 7 == 0)


def test_unconstrained_closed_form():
    # m = 0: x* = −P⁻¹q exactly (numpy solve as the independent reference).
    rng = np.random.default_rng(12)
    P, q, *_ = random_qp(rng, 5, 5)
    sol = qp.solve(P, q, np.zeros((0, 5)), np.zeros(0), np.zeros(0), settings=TIGHT64)
    assert int(sol.status) == qp.SOLVED and sol.y.shape == (0,)
    np.testing.assert_allclose(sol.x, -np.linalg.solve(P, q), atol=1e-6)


def test_inverse_linsys_matches_cholesky():
    rng = np.random.default_rng(1000 * 16 + 32)
    probs = stack([random_qp(rng, 16, 32) for _ in range(3)])
    a = qp.solve(*probs, settings=TIGHT64)
    b = qp.solve(*probs, settings=TIGHT64._replace(linsys="inverse"))
    np.testing.assert_array_equal(b.status, qp.SOLVED)
    np.testing.assert_allclose(a.x, b.x, atol=1e-5)  # two 1e-7-accurate solutions


@pytest.mark.parametrize("field,value", [("alpha", 2.0), ("rho", 0.0), ("max_iter", 0),
                                         ("scaling", -1), ("adaptive_rho_interval", 30),
                                         ("linsys", "lu"), ("eps_prim_inf", -1.0),
                                         ("early_exit", 1)])
def test_bad_settings_name_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        qp.solve(np.eye(2), np.zeros(2), np.eye(2), -np.ones(2), np.ones(2),
                 settings=qp.Settings()._replace(**{field: value}))


def test_bad_shapes_name_the_argument():
    with pytest.raises(ValueError, match="q must"):
        qp.solve(np.eye(2), np.zeros(3), np.eye(2), -np.ones(2), np.ones(2))
    with pytest.raises(ValueError, match="l must"):
        qp.solve(np.eye(2), np.zeros(2), np.eye(2), -np.ones(3), np.ones(2))


def test_batch_chunks_do_not_change_results():
    # Chunked (lax.map over vmapped chunks, last chunk padded) vs one vmapped batch: each problem
    # runs the same iterations, so results agree to rounding of the differently compiled programs.
    rng = np.random.default_rng(1000 * 5 + 12)
    probs = stack([random_qp(rng, 5, 12) for _ in range(3)])
    a = qp.solve(*probs, settings=TIGHT64)
    b = qp.solve(*probs, settings=TIGHT64, batch_chunk=2)
    np.testing.assert_array_equal(a.iterations, b.iterations)
    np.testing.assert_array_equal(a.status, b.status)
    np.testing.assert_allclose(a.x, b.x, atol=1e-10)


@pytest.mark.parametrize("max_iter,check", [(400, 25), (37, 10)])
def test_fixed_trip_count_loop_gives_the_same_solutions(max_iter, check):
    # early_exit=False runs ceil(max_iter / check) blocks whatever the batch does; the blocks
    # after a problem is done leave it frozen, so every problem runs the same iterations as in
    # the while loop.  Iterations and statuses must agree exactly; x and y to 1e-12 (float64):
    # the two loops are different compiled programs, whose fusions may round differently.
    rng = np.random.default_rng(77)
    probs = [random_qp(rng, 6, 14) for _ in range(3)] + [primal_infeasible_qp(rng, 6, 14)]
    nan = [a.copy() for a in probs[0]]
    nan[1][0] = np.nan
    args = stack(probs + [nan])
    s = TIGHT64._replace(max_iter=max_iter, check_interval=check, adaptive_rho_interval=check)
    a = qp.solve(*args, settings=s)
    b = qp.solve(*args, settings=s._replace(early_exit=False))
    np.testing.assert_array_equal(a.status, b.status)
    np.testing.assert_array_equal(a.iterations, b.iterations)
    for u, v in ((a.x, b.x), (a.y, b.y)):
        np.testing.assert_allclose(u, v, atol=1e-12, rtol=0)
    assert qp.n_blocks(s) * check >= max_iter > (qp.n_blocks(s) - 1) * check
    # at 37 iterations the budget ends some problem early: the max_iter path ran in both loops
    if max_iter < 100:
        assert np.any(np.isin(np.asarray(a.status), [qp.MAX_ITER, qp.SOLVED_INACCURATE,
                                                     qp.PRIMAL_INFEASIBLE_INACCURATE]))


def test_compaction_tiers():
    # by default each tier half the one above, none below 256 problems
    assert qp.Settings().compaction_shrink == 2
    assert qp.compaction_tiers(65536) == (65536, 32768, 16384, 8192, 4096, 2048, 1024, 512, 256)
    assert qp.compaction_tiers(2047) == (2047, 1023, 511)
    assert qp.compaction_tiers(511) == (511,)
    assert qp.compaction_tiers(1) == (1,)
    # an eighth (Settings.compaction_shrink = 8)
    assert qp.compaction_tiers(65536, 8) == (65536, 8192, 1024)
    assert qp.compaction_tiers(2048, 8) == (2048, 256)
    assert qp.compaction_tiers(2047, 8) == (2047,)
    with pytest.raises(ValueError, match="compaction_shrink"):
        qp.validate_settings(qp.Settings(compaction_shrink=1))


@pytest.mark.parametrize("warm", [False, True])
def test_straggler_compaction_gives_the_same_solutions(warm):
    # 2048 problems of every kind (well and badly conditioned, LP, PSD, both infeasibilities,
    # invalid data) solved as one batch: plain vmapped loop vs compacted tiers (2048 → 256).
    # Each problem runs the same iterations in whichever tier it finishes, so iterations and
    # statuses agree exactly and x, y to 1e-12 (float64; the tiers are differently compiled
    # programs whose fusions may round differently).
    rng = np.random.default_rng(2048)
    makers = [lambda: random_qp(rng, 6, 14), lambda: random_qp(rng, 6, 14, "ill"),
              lambda: random_qp(rng, 6, 14, "lp"), lambda: random_qp(rng, 6, 14, "psd"),
              lambda: primal_infeasible_qp(rng, 6, 14), lambda: dual_infeasible_qp(rng, 6, 14)]
    probs = [makers[k % len(makers)]() for k in range(2047)]
    nan = [a.copy() for a in probs[0]]
    nan[2][0, 0] = np.nan
    args = stack(probs + [nan])
    ws = None
    if warm:  # a warm start from a coarse solve: the iteration counts spread differently
        coarse = qp.solve(*args, settings=qp.Settings(eps_abs=1e-2, eps_rel=1e-2))
        ws = (np.nan_to_num(np.asarray(coarse.x)), np.nan_to_num(np.asarray(coarse.y)))
    s = qp.Settings(eps_abs=1e-6, eps_rel=1e-6, max_iter=4000)
    a = qp.solve(*args, settings=s, warm_start=ws, batch_chunk=1 << 20, compact=False)
    b = qp.solve(*args, settings=s, warm_start=ws, batch_chunk=1 << 20, compact=True)
    its = np.asarray(a.iterations)
    assert its.max() > 4 * np.median(its)  # a tail for the compaction to cut off
    np.testing.assert_array_equal(a.status, b.status)
    np.testing.assert_array_equal(a.iterations, b.iterations)
    for u, v in ((a.x, b.x), (a.y, b.y)):
        np.testing.assert_allclose(u, v, atol=1e-12, rtol=0)
    assert set(np.unique(np.asarray(a.status))) >= {qp.SOLVED, qp.PRIMAL_INFEASIBLE,
                                                    qp.DUAL_INFEASIBLE, qp.UNSOLVED}


def test_bad_compact_names_the_argument():
    with pytest.raises(ValueError, match="compact"):
        qp.solve(np.eye(2), np.zeros(2), np.eye(2), -np.ones(2), np.ones(2), compact=1)


def test_compaction_under_an_external_vmap():
    # A per-problem function vmapped by its caller (as the Cassie tick is over its robots):
    # with compact=True the batch of the vmap is solved in compacted tiers (2048 → 256) through
    # the custom batching rule; the results are the plain vmapped loop's (float64, 1e-12).
    rng = np.random.default_rng(4096)
    probs = [random_qp(rng, 6, 14, ("pd", "ill", "lp")[k % 3]) for k in range(2048)]
    args = [jnp.asarray(a) for a in stack(probs)]
    s = qp.Settings(eps_abs=1e-6, eps_rel=1e-6, max_iter=4000)
    one = lambda compact: jax.jit(jax.vmap(
        lambda P, q, A, l, u: qp.solve(P, q, A, l, u, settings=s, compact=compact)))
    a, b = one(False)(*args), one(True)(*args)
    its = np.asarray(a.iterations)
    assert its.max() > 4 * np.median(its)
    np.testing.assert_array_equal(a.iterations, b.iterations)
    np.testing.assert_array_equal(a.status, b.status)
    np.testing.assert_allclose(a.x, b.x, atol=1e-12, rtol=0)
    # unbatched, the same call is the plain solve
    c = qp.solve(*(x[0] for x in args), settings=s, compact=True)
    np.testing.assert_allclose(c.x, a.x[0], atol=1e-12, rtol=0)


def test_rho_start_sets_the_starting_step_size():
    # rho_start is the ADMM step size the iteration starts from (kept to the end without
    # adaptation), the solution is OSQP's whatever ρ (1e-5 relative at eps 1e-7, module doc);
    # Settings.rho, and entries that are not positive and finite, give the default solve
    # exactly.
    rng = np.random.default_rng(1000 * 16 + 32)
    probs = [random_qp(rng, 16, 32) for _ in range(3)]
    args = stack(probs)
    fixed = TIGHT64._replace(adaptive_rho=False)
    rhos = np.array([0.01, 1.0, 10.0])
    sol = qp.solve(*args, settings=fixed, rho_start=rhos)
    np.testing.assert_array_equal(np.asarray(sol.rho), rhos)
    for k, prob in enumerate(probs):
        assert int(sol.status[k]) == qp.SOLVED
        assert rel_err(np.asarray(sol.x[k]), osqp_solve(*prob).x) < 1e-5
    # the same problem from three starting ρ: different iteration counts, one solution
    same = [args[0][:1].repeat(3, 0)] + [a[:1].repeat(3, 0) for a in args[1:]]
    spread = qp.solve(*same, settings=fixed, rho_start=rhos)
    assert len(set(np.asarray(spread.iterations).tolist())) == 3
    default = qp.solve(*args, settings=TIGHT64)
    for start in (np.full(3, TIGHT64.rho), np.array([np.nan, 0.0, -1.0])):
        other = qp.solve(*args, settings=TIGHT64, rho_start=start)
        np.testing.assert_array_equal(default.x, other.x)
        np.testing.assert_array_equal(default.iterations, other.iterations)
