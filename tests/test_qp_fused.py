"""hlip_jax.core.qp_fused: the fused ADMM block (a Pallas kernel; interpreted on the CPU) against an
independent numpy loop of OSQP's iteration, against the XLA loop of hlip_jax.core.qp, and, through
the solver, against OSQP.

Tolerances (float64): the kernel, the XLA loop and the numpy loop evaluate the same formulas
with sums in different orders, so one block's iterates agree to rounding (1e-12 relative);
whole solves agree in iteration counts and statuses exactly and in their solutions well within
the stopping tolerance (each test says why its figure).  Against OSQP, the module doc of
test_qp.py: x to 1e-5 relative at eps 1e-7.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hlip_jax.core import qp, qp_fused
from test_qp import (TIGHT64, dual_infeasible_qp, osqp_solve, primal_infeasible_qp, random_qp,
                     rel_err, stack)


def _numpy_block(prob, st, sigma, alpha, iterations, max_iter):
    """The block's steps, one problem at a time, with numpy's matrix products."""
    out = [np.array(a, copy=True) for a in st]
    for b in range(prob.A.shape[0]):
        Kinv, A, q, l, u, rho = (np.asarray(a[b]) for a in prob)
        x, z, y, dx, dy, it = (a[b] for a in out)
        for _ in range(iterations):
            if it >= max_iter:
                break
            xt = Kinv @ (sigma * x - q + A.T @ (rho * z - y))
            zr = alpha * (A @ xt) + (1 - alpha) * z
            xn = alpha * xt + (1 - alpha) * x
            zn = np.clip(zr + y / rho, l, u)
            yn = y + rho * (zr - zn)
            dx, dy, x, z, y, it = xn - x, yn - y, xn, zn, yn, it + 1
        for a, v in zip(out, (x, z, y, dx, dy, it)):
            a[b] = v
    return out


@pytest.mark.parametrize("n,m,B", [(5, 7, 3), (16, 32, 9)])
def test_block_matches_a_numpy_loop(n, m, B):
    # odd sizes (padded to 8 × 8) and batches that do not fill the last tile; iteration
    # counts near max_iter stop mid-block (5, 2 and 0 steps taken); infinite bounds on some
    # rows.  The iterates are random, not a converging state, so values reach ~1e4 and the
    # tolerance is 1e-12 relative to the largest
    rng = np.random.default_rng(n * 100 + m)
    M = rng.standard_normal((B, n, n))
    K = M @ np.swapaxes(M, 1, 2) + n * np.eye(n)
    A = rng.standard_normal((B, m, n))
    l = -rng.uniform(0.1, 1, (B, m))
    u = rng.uniform(0.1, 1, (B, m))
    l[:, 0], u[:, 1] = -np.inf, np.inf
    prob = qp_fused.Problems(np.linalg.inv(K), A, rng.standard_normal((B, n)), l, u,
                             rng.uniform(0.05, 5, (B, m)))
    st = qp_fused.Iterates(rng.standard_normal((B, n)), np.clip(rng.standard_normal((B, m)), l, u),
                           rng.standard_normal((B, m)), np.zeros((B, n)), np.zeros((B, m)),
                           np.resize([0, 28, 30, 20], B).astype(np.int32))
    got = qp_fused.admm_block(jax.tree.map(jnp.asarray, prob), jax.tree.map(jnp.asarray, st),
                              sigma=1e-6, alpha=1.6, iterations=5, max_iter=30)
    want = _numpy_block(prob, st, 1e-6, 1.6, 5, 30)
    np.testing.assert_array_equal(got.it, want[5])
    for g, w in zip(got[:5], want[:5]):  # random iterates: values up to ~1e4
        np.testing.assert_allclose(g, w, atol=1e-12 * max(1.0, np.abs(w).max()), rtol=0)
    assert set(np.asarray(got.it) - st.it) == {5, 2, 0}


def test_tile_size():
    # tile × padded m × padded n stays within 2048 elements, a power of two, at least 1
    assert qp_fused.tile_size(16, 32) == 4
    assert qp_fused.tile_size(5, 7) == 32
    assert qp_fused.tile_size(24, 64) == 1
    assert qp_fused.tile_size(64, 128) == 1


def _mixed_batch(rng, count, n, m):
    makers = [lambda: random_qp(rng, n, m), lambda: random_qp(rng, n, m, "ill"),
              lambda: random_qp(rng, n, m, "lp"), lambda: random_qp(rng, n, m, "psd"),
              lambda: primal_infeasible_qp(rng, n, m), lambda: dual_infeasible_qp(rng, n, m)]
    probs = [makers[k % len(makers)]() for k in range(count - 1)]
    nan = [a.copy() for a in probs[0]]
    nan[2][0, 0] = np.nan
    return stack(probs + [nan])


@pytest.mark.parametrize("compact,warm", [(False, False), (True, False), (True, True)])
def test_solutions_equal_the_xla_loops(compact, warm):
    # every kind of problem (both infeasibilities, invalid data), a budget that ends mid-block
    # for some (max_iter 990 with blocks of 25), float64, compacted (600 → 300 problems) and
    # plain loops, against the XLA loop.  The two kernels sum in different orders; the
    # iteration amplifies that 1e-16 rounding (measured: up to 2e-8 on LPs that run to the
    # budget), and where an adaptive-ρ or stopping test sits that close to its threshold the
    # path changes (1 of 600 problems here).  So: the same statuses everywhere; the same
    # iteration counts for at least 99 %, whose solved x and y agree to 1e-6, the stopping
    # tolerance (measured: up to 2e-7); every other solved problem to 1e-4, what two solutions with
    # 1e-6 residuals can differ by on P's smallest curvature (1e-2, the "ill" kind)
    rng = np.random.default_rng(600 + compact + 2 * warm)
    args = _mixed_batch(rng, 600 if compact else 60, 6, 14)
    ws = None
    if warm:
        coarse = qp.solve(*args, settings=qp.Settings(eps_abs=1e-2, eps_rel=1e-2))
        ws = (np.nan_to_num(np.asarray(coarse.x)), np.nan_to_num(np.asarray(coarse.y)))
    s = qp.Settings(eps_abs=1e-6, eps_rel=1e-6, max_iter=990, linsys="inverse")
    a, b = (qp.solve(*args, settings=s._replace(block_kernel=k), warm_start=ws,
                     batch_chunk=1 << 20, compact=compact) for k in ("xla", "fused"))
    np.testing.assert_array_equal(a.status, b.status)
    same = np.asarray(a.iterations) == np.asarray(b.iterations)
    assert same.mean() >= 0.99
    solved = np.asarray(a.status) == qp.SOLVED
    for u, v in ((a.x, b.x), (a.y, b.y)):
        u, v = np.asarray(u), np.asarray(v)
        np.testing.assert_allclose(u[solved & same], v[solved & same], atol=1e-6, rtol=0)
        np.testing.assert_allclose(u[solved], v[solved], atol=1e-4, rtol=0)
    assert set(np.unique(np.asarray(a.status))) >= {qp.SOLVED, qp.PRIMAL_INFEASIBLE,
                                                    qp.DUAL_INFEASIBLE, qp.UNSOLVED}


def test_single_problems_and_an_external_vmap_match_osqp():
    # one problem (a batch of one inside), and a per-problem solve vmapped by its caller (the
    # Cassie tick's shape): OSQP's solutions to 1e-5 relative at eps 1e-7
    rng = np.random.default_rng(1632)
    probs = [random_qp(rng, 16, 32) for _ in range(3)]
    s = TIGHT64._replace(linsys="inverse", block_kernel="fused")
    one = qp.solve(*probs[0], settings=s)
    batch = jax.vmap(lambda *p: qp.solve(*p, settings=s))(*(jnp.asarray(a) for a in stack(probs)))
    for k, p in enumerate(probs):
        ref = osqp_solve(*p)
        assert rel_err(np.asarray(batch.x[k]), ref.x) < 1e-5
    assert rel_err(np.asarray(one.x), osqp_solve(*probs[0]).x) < 1e-5
    assert int(one.status) == qp.SOLVED


@pytest.mark.parametrize("settings,field", [
    (qp.Settings(block_kernel="pallas"), "block_kernel"),
    (qp.Settings(block_kernel="fused"), "block_kernel"),            # needs linsys "inverse"
])
def test_bad_kernel_settings_name_the_field(settings, field):
    with pytest.raises(ValueError, match=field):
        qp.validate_settings(settings)
    qp.validate_settings(qp.Settings(block_kernel="fused", linsys="inverse"))
