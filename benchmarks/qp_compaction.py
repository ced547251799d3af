"""Straggler compaction of hlip_jax.core.qp.solve: one batch solved by the plain vmapped while loop
(``compact=False``: it runs until the batch's slowest problem is done) and by compacted tiers
(``compact=True``: the unfinished problems continue in batches of 1/k of the size, k =
``--shrink``), in
one process, on the MPC-like QPs of qp_bench.py (float32, eps 1e-4, linsys "inverse", cold).

    python benchmarks/qp_compaction.py --batches 4096,65536

Prints, per size and batch: wall time of the jitted solve (best of 3 after a warm-up),
QPs/s, mean and largest iteration count, fraction solved, whether statuses and iteration counts
equal the plain loop's, and the largest |Δx| from the plain loop's solution.
"""

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

from hlip_jax.core import qp
from qp_problems import mpc_like  # benchmarks/qp_problems.py


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--batches", default="4096,65536")
    p.add_argument("--sizes", default="16x32,24x64")
    p.add_argument("--shrink", default="8",
                   help="tier shrink factors to time, comma-separated (qp.Settings.compaction_shrink)")
    a = p.parse_args()
    rng = np.random.default_rng(0)
    print(f"jax {jax.__version__}, device {jax.devices()[0].device_kind}")
    s = qp.Settings(eps_abs=1e-4, eps_rel=1e-4, linsys="inverse")
    for n, m in (tuple(int(v) for v in z.split("x")) for z in a.sizes.split(",")):
        for B in (int(b) for b in a.batches.split(",")):
            data = [jnp.asarray(x, jnp.float32) for x in mpc_like(rng, B, n, m)]
            ref = None
            for k in [None] + [int(v) for v in a.shrink.split(",")]:
                compact = k is not None
                sk = s._replace(compaction_shrink=k) if compact else s
                f = lambda: qp.solve(*data, settings=sk, batch_chunk=B, compact=compact)
                jax.block_until_ready(f())
                best = np.inf
                for _ in range(3):
                    t0 = time.perf_counter()
                    sol = jax.block_until_ready(f())
                    best = min(best, time.perf_counter() - t0)
                ref = sol if ref is None else ref
                it = np.asarray(sol.iterations)
                same = bool(np.all(it == np.asarray(ref.iterations))
                            and np.all(np.asarray(sol.status) == np.asarray(ref.status)))
                print(f"| {n} | {m} | {B} | {f'compacted ÷{k}' if compact else 'plain'} | {best * 1e3:.2f} | "
                      f"{B / best:,.0f} | {it.mean():.0f} | {it.max()} | "
                      f"{np.mean(np.asarray(sol.status) == qp.SOLVED):.4f} | {same} | "
                      f"{float(jnp.max(jnp.abs(sol.x - ref.x))):.1e} |", flush=True)


if __name__ == "__main__":
    main()
