"""Random QPs shaped like a condensed MPC, shared by the QP benchmarks (qp_bench.py,
qp_compaction.py): n decision variables with box rows |x_i| ≤ 1 plus m − n general rows
l ≤ G x ≤ u around a feasible point, strongly convex P (eigenvalues ≳ 0.1), random q."""

import numpy as np


def mpc_like(rng, batch, n, m):
    """A batch of random strongly convex feasible QPs shaped like a condensed MPC (float64)."""
    M = rng.standard_normal((batch, n, n)) / np.sqrt(n)
    P = M @ np.swapaxes(M, -1, -2) + 0.1 * np.eye(n)
    q = rng.standard_normal((batch, n))
    G = rng.standard_normal((batch, m - n, n)) / np.sqrt(n)
    x_f = rng.uniform(-0.5, 0.5, (batch, n))
    Gx = np.einsum("bij,bj->bi", G, x_f)
    A = np.concatenate([np.broadcast_to(np.eye(n), (batch, n, n)), G], axis=1)
    l = np.concatenate([-np.ones((batch, n)), Gx - rng.uniform(0.05, 0.5, (batch, m - n))], axis=1)
    u = np.concatenate([np.ones((batch, n)), Gx + rng.uniform(0.05, 0.5, (batch, m - n))], axis=1)
    return P, q, A, l, u
