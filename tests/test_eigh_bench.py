"""benchmarks/eigh_bench.py's two solves of the condensation's 28 × 28 systems agree with
numpy's dense solve on well-conditioned matrices (what the benchmark compares must be the same
answer)."""


import numpy as np

from support import load_benchmark

eigh_bench = load_benchmark("eigh_bench")
N_RHS, N_ROWS, solvers = eigh_bench.N_RHS, eigh_bench.N_ROWS, eigh_bench.solvers


def test_both_solves_match_a_dense_solve(float64):
    rng = np.random.default_rng(0)
    k = rng.standard_normal((4, N_ROWS, N_ROWS))
    G = k @ np.swapaxes(k, -1, -2) + N_ROWS * np.eye(N_ROWS)     # eigenvalues ≥ 28
    rhs = rng.standard_normal((4, N_ROWS, N_RHS))
    want = np.linalg.solve(G, rhs)
    for name, f in solvers(rhs).items():
        # 1e-7 of the largest entry: the Cholesky solve's 1e-6 shift moves the solution by at
        # most 1e-6 / λ_min ≤ 3.6e-8 relative; the eigendecomposition only by float64 round-off
        np.testing.assert_allclose(np.asarray(f(G)), want, rtol=0, atol=1e-7 * np.abs(want).max(),
                                   err_msg=name)
