"""benchmarks/eigh_bench.py's two solves of the condensation's 28 × 28 systems agree with
numpy's dense solve on well-conditioned matrices (what the benchmark compares must be the same
answer)."""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))

from eigh_bench import N_RHS, N_ROWS, solvers  # noqa: E402


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
