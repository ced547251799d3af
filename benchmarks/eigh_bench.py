"""The condensation's linear algebra on the device: a batch of 28 × 28 symmetric positive
definite matrices (the size of G = J M⁻¹ Jᵀ in :func:`hlip_jax.plants.cassie.dynamics.condense`)
solved against 11 right-hand sides (nu + 1) two ways:

    eigh pinv   G⁺ b through the symmetric eigendecomposition, eigenvalues below 1e-9 of the
                largest dropped (``dynamics.eigen_forces``, what ``condense`` does by default)
    cholesky    (G + 1e-6 I)⁻¹ b through a Cholesky factor

Each is timed as 20 calls in a ``lax.scan`` whose every input depends on the previous call's
output (nothing is hoisted out of the loop), best of 3 after a compile, in the dtype JAX uses.

    python benchmarks/eigh_bench.py --batch 1024 8192
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp

from hlip_jax.plants.cassie import dynamics

N_ROWS, N_RHS = 28, 11


def per_call(f, x, calls: int = 20, repeats: int = 3) -> tuple[float, float]:
    """(compile + first run [s], best time per call [s]) of ``f`` in a dependent scan."""
    def run(x):
        body = lambda a, _: (a + 1e-9 * jnp.tanh(jnp.sum(f(x + a))), None)
        return jax.lax.scan(body, jnp.zeros((), x.dtype), None, length=calls)[0]

    g = jax.jit(run)
    t0 = time.perf_counter()
    jax.block_until_ready(g(x))
    first = time.perf_counter() - t0
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(g(x))
        best = min(best, time.perf_counter() - t0)
    return first, best / calls


def solvers(rhs):
    """name → G ↦ solution (B, 28, 11)."""
    def pinv(G):
        return jax.vmap(dynamics.eigen_forces)(G, rhs)

    def chol(G):
        eye = jnp.eye(N_ROWS, dtype=G.dtype)
        return jax.scipy.linalg.cho_solve(jax.scipy.linalg.cho_factor(G + 1e-6 * eye), rhs)

    return {"eigh pinv": pinv, "cholesky": chol}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, nargs="+", default=[1024])
    args = ap.parse_args(argv)
    print(f"backend {jax.default_backend()}, device {jax.devices()[0].device_kind}")
    print("| batch | solve | compile + first [s] | per call [ms] |")
    print("|---:|---|---:|---:|")
    for B in args.batch:
        k = jax.random.normal(jax.random.PRNGKey(0), (B, N_ROWS, N_ROWS))
        G = k @ jnp.swapaxes(k, -1, -2) + 1e-3 * jnp.eye(N_ROWS)
        rhs = jax.random.normal(jax.random.PRNGKey(1), (B, N_ROWS, N_RHS))
        for name, f in solvers(rhs).items():
            first, per = per_call(f, G)
            print(f"| {B} | {name} | {first:.1f} | {per * 1e3:.3f} |", flush=True)


if __name__ == "__main__":
    main()
