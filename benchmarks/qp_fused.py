"""The ADMM block as XLA operations against one fused Pallas kernel (``qp.Settings.block_kernel``
"xla" / "fused"), in one process, on the MPC-like QPs of qp_bench.py (eps 1e-4, linsys
"inverse", cold start; the batch solved in one piece, with and without straggler compaction).

    python benchmarks/qp_fused.py --sizes 16x32,24x64 --batches 4096,65536

Prints, per size, batch and loop: wall time of the jitted solve (best of ``--repeats`` after a
warm-up), QPs/s, the first call's time (compile + run), mean and largest iteration count,
fraction solved, whether statuses and iteration counts equal the XLA kernel's, and the largest
|Δx| from its solution.  On a CPU the fused kernel runs in Pallas's interpreter (a correctness
check, not a speed figure).
"""

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

from hlip_jax.core import qp
from qp_problems import mpc_like  # benchmarks/qp_problems.py


def timed(f, repeats):
    """(first call's seconds, best of ``repeats`` later calls, last result)."""
    t0 = time.perf_counter()
    sol = jax.block_until_ready(f())
    first = time.perf_counter() - t0
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        sol = jax.block_until_ready(f())
        best = min(best, time.perf_counter() - t0)
    return first, best, sol


def row(n, m, B, loop, kernel, first, best, sol, ref):
    it = np.asarray(sol.iterations)
    same = bool(np.all(it == np.asarray(ref.iterations))
                and np.all(np.asarray(sol.status) == np.asarray(ref.status)))
    dx = float(jnp.max(jnp.abs(sol.x - ref.x)))
    return (f"| {n} | {m} | {B} | {loop} | {kernel} | {best * 1e3:.2f} | {B / best:,.0f} | "
            f"{first:.1f} | {it.mean():.0f} | {it.max()} | "
            f"{np.mean(np.asarray(sol.status) == qp.SOLVED):.4f} | {same} | {dx:.1e} |")


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--batches", default="4096,65536")
    p.add_argument("--sizes", default="16x32,24x64")
    p.add_argument("--loops", default="compacted,plain", help="compacted and/or plain")
    p.add_argument("--dtype", default="float32", choices=("float32", "float64"))
    p.add_argument("--repeats", type=int, default=3)
    a = p.parse_args()
    if a.dtype == "float64":
        jax.config.update("jax_enable_x64", True)
    rng = np.random.default_rng(0)
    print(f"jax {jax.__version__}, backend {jax.default_backend()}, "
          f"device {jax.devices()[0].device_kind}, {a.dtype}")
    print("| n | m | batch | loop | kernel | time [ms] | QPs/s | first call [s] | mean iters | "
          "max iters | solved | same as xla | max |Δx| |")
    print("|---|---|---:|---|---|---:|---:|---:|---:|---:|---:|---|---:|")
    s = qp.Settings(eps_abs=1e-4, eps_rel=1e-4, linsys="inverse")
    for n, m in (tuple(int(v) for v in z.split("x")) for z in a.sizes.split(",")):
        for B in (int(b) for b in a.batches.split(",")):
            data = [jnp.asarray(x, a.dtype) for x in mpc_like(rng, B, n, m)]
            for loop in a.loops.split(","):
                ref = None
                for kernel in ("xla", "fused"):
                    sk = s._replace(block_kernel=kernel)
                    f = lambda: qp.solve(*data, settings=sk, batch_chunk=B,
                                         compact=loop == "compacted")
                    first, best, sol = timed(f, a.repeats)
                    ref = sol if ref is None else ref
                    print(row(n, m, B, loop, kernel, first, best, sol, ref), flush=True)


if __name__ == "__main__":
    main()
