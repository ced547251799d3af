"""Benchmark of hlip_jax.core.invariant: mRPI construction for a box W and batched membership tests.

    python benchmarks/invariant_bench.py [--device cpu|gpu] [--points 1000000] [--repeat 20]

Cases: the 3-state [c, p, v] H-LIP (z0 = 0.8 m, T_S = 0.3 s, T_D = 0.1 s) closed with the
deadbeat gain (A_cl³ = 0, exact finite sum) and with an LQR gain (Q = I, R = 1; spectral
radius 0.70, so the Raković procedure needs tens of terms), plus the 2-state deadbeat.
Reports the median wall time of `mrpi` (eager float64 construction: s/α choice, generators,
exact facets) and of `E.contains` on ``--points`` random states (jitted, after compile), and the
number of facets.  Output: a markdown table on stdout and a JSON line.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time


def _parse():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", choices=("cpu", "gpu"), default="cpu")
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=20)
    ap.add_argument("--eps", type=float, default=1e-5, help="Raković tolerance ε [state units]")
    ap.add_argument("--f32", action="store_true", help="float32 membership (default float64)")
    return ap.parse_args()


def _median_time(fn, repeat):
    """(median wall, min wall, median process CPU time) [s] after one warm-up call.  CPU time
    is reported too because the wall time on a shared machine includes waiting for a core."""
    fn()  # compile / warm caches
    ts, cs = [], []
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        ts.append(time.perf_counter() - t0)
        cs.append(time.process_time() - c0)
    return statistics.median(ts), min(ts), statistics.median(cs)


def main():
    args = _parse()
    os.environ.setdefault("JAX_PLATFORMS", "cuda" if args.device == "gpu" else "cpu")
    import jax

    if not args.f32:
        jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import numpy as np

    from hlip_jax.core import hlip
    from hlip_jax.core import invariant as inv

    z0, ts, td = 0.8, 0.3, 0.1
    A3, B3 = hlip.s2s_matrices(z0, ts, td, with_position=True)
    A2, B2 = hlip.s2s_matrices(z0, ts, td, with_position=False)
    cases = {
        "3-D deadbeat": np.asarray(A3 + jnp.outer(B3, hlip.deadbeat_gain(z0, ts, td, with_position=True))),
        "3-D LQR": np.asarray(A3 + jnp.outer(B3, jax.jit(hlip.lqr_gain)(A3, B3, jnp.eye(3), jnp.array(1.0)))),
        "2-D deadbeat": np.asarray(A2 + jnp.outer(B2, hlip.deadbeat_gain(z0, ts, td))),
    }
    half = {3: np.array([0.01, 0.01, 0.05]), 2: np.array([0.01, 0.05])}
    dtype = jnp.float32 if args.f32 else jnp.float64
    rows = []
    for name, Acl in cases.items():
        n = Acl.shape[0]
        W = inv.Box(jnp.asarray(-half[n]), jnp.asarray(1.2 * half[n]))
        build_med, build_min, build_cpu = _median_time(lambda: inv.mrpi(Acl, W, eps=args.eps), args.repeat)
        E = inv.mrpi(Acl, W, eps=args.eps)
        scale = np.asarray(E.outer.support(np.eye(n)))
        P = jnp.asarray(np.random.default_rng(0).uniform(-1.2, 1.2, (args.points, n)) * scale, dtype)
        outer = jax.tree_util.tree_map(lambda a: jnp.asarray(a, dtype), E.outer)

        def member():
            return outer.contains(P).block_until_ready()

        t0 = time.perf_counter()
        inside = member()
        first = time.perf_counter() - t0
        mem_med, mem_min, mem_cpu = _median_time(member, max(3, args.repeat // 4))
        rows.append(dict(case=name, s=E.s, alpha=E.alpha, facets=int(np.shape(E.outer.normals)[0]),
                         mrpi_ms=1e3 * build_med, mrpi_min_ms=1e3 * build_min,
                         mrpi_cpu_ms=1e3 * build_cpu, contains_s=mem_med, contains_min_s=mem_min,
                         contains_cpu_s=mem_cpu, first_call_s=first,
                         inside=float(np.mean(np.asarray(inside)))))
    dev = jax.devices()[0]
    try:
        load = os.getloadavg()[0]
    except OSError:
        load = float("nan")
    meta = dict(load_avg_1min=load, device=f"{dev.platform}:{dev.device_kind}", cpus=os.cpu_count(),
                machine=platform.processor() or platform.machine(), jax=jax.__version__,
                points=args.points, eps=args.eps, dtype=str(jnp.dtype(dtype)),
                command="python " + " ".join(sys.argv))
    print(f"device {meta['device']}, {meta['cpus']} CPUs, jax {meta['jax']}, {meta['dtype']}, "
          f"eps {args.eps:g}, {args.points} points, load average {load:.1f}")
    print("| case | s | α | facet pairs | mrpi wall median (min) / CPU [ms] | "
          f"contains {args.points:.0e} wall median (min) / CPU [s] | first call [s] |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['case']} | {r['s']} | {r['alpha']:.2e} | {r['facets']} | {r['mrpi_ms']:.2f} "
              f"({r['mrpi_min_ms']:.2f}) / {r['mrpi_cpu_ms']:.2f} | {r['contains_s']:.3f} "
              f"({r['contains_min_s']:.3f}) / {r['contains_cpu_s']:.3f} | {r['first_call_s']:.2f} |")
    print(json.dumps(dict(meta=meta, rows=rows)))


if __name__ == "__main__":
    main()
