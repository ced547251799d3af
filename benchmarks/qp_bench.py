"""Throughput of hlip_jax.core.qp.solve against OSQP on MPC-sized QPs.

Problems resemble a condensed MPC: n decision variables with box rows |x_i| ≤ 1 plus m − n general
rows l ≤ G x ≤ u around a feasible point, strongly convex P (eigenvalues ≳ 0.1), random q.
Both solvers use the same tolerance (eps_abs = eps_rel = --eps) and the same starting point:

* cold: x = 0, y = 0;
* warm: the solution of the same problem with q perturbed by 5 % (a receding-horizon step).

OSQP time is its own C-side timer ``res.info.solve_time`` (setup / factorisation excluded; one
thread), averaged over --osqp-problems problems; ours is wall time of a jitted batched solve
(including Ruiz scaling and factorisation) after a warm-up call, best of --repeats.

    python benchmarks/qp_bench.py --device cpu --batches 1,256,4096 --write
    python benchmarks/qp_bench.py --device gpu --batches 1,256,4096,65536 --write
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import time

SIZES = ((16, 32), (24, 64))


def parse():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", choices=("cpu", "gpu"), default="cpu")
    p.add_argument("--batches", default="1,256,4096", help="comma-separated batch sizes")
    p.add_argument("--sizes", default="16x32,24x64", help="comma-separated n x m")
    p.add_argument("--dtype", choices=("float32", "float64"), default=None,
                   help="default: float32 on gpu, float64 on cpu")
    p.add_argument("--eps", type=float, default=1e-4, help="eps_abs = eps_rel for both solvers")
    p.add_argument("--linsys", choices=("cholesky", "inverse"), default="inverse")
    p.add_argument("--modes", default="cold,warm")
    p.add_argument("--shrink", type=int, default=None,
                   help="tier shrink factor of the straggler compaction (qp.Settings.compaction_shrink; "
                   "default: the solver's)")
    p.add_argument("--block-kernel", choices=("xla", "fused"), default="xla",
                   help="qp.Settings.block_kernel: ADMM iterations as XLA operations, or each block "
                   "as one Pallas kernel (linsys inverse only)")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--osqp-problems", type=int, default=300)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--write", action="store_true", help="write the table into docs/benchmarks/qp_solver.md")
    p.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "..", "docs", "benchmarks", "qp_solver.md"))
    return p.parse_args()


ARGS = parse()
if ARGS.device == "cpu":
    os.environ.setdefault("JAX_PLATFORMS", "cpu")
DTYPE = ARGS.dtype or ("float32" if ARGS.device == "gpu" else "float64")

import jax  # noqa: E402

if DTYPE == "float64":
    jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import osqp  # noqa: E402
import scipy.sparse as sp  # noqa: E402

from hlip_jax.core import qp  # noqa: E402
from qp_problems import mpc_like  # noqa: E402  (benchmarks/qp_problems.py)


def osqp_time(P, q, A, l, u, warm, eps, count):
    """Mean OSQP solve_time [s] (C timer) and mean iterations over ``count`` problems."""
    times, iters, solved = [], [], 0
    for k in range(count):
        prob = osqp.OSQP()
        prob.setup(P=sp.csc_matrix(np.triu(P[k])), q=q[k], A=sp.csc_matrix(A[k]), l=l[k], u=u[k],
                   eps_abs=eps, eps_rel=eps, polishing=False, verbose=False)
        if warm is not None:
            prob.warm_start(x=warm[0][k], y=warm[1][k])
        res = prob.solve(raise_error=False)
        times.append(res.info.solve_time)
        iters.append(res.info.iter)
        solved += res.info.status_val == qp.SOLVED
    return float(np.mean(times)), float(np.mean(iters)), solved / count


def machine():
    cpu = "unknown CPU"
    try:
        with open("/proc/cpuinfo") as f:
            names = re.findall(r"model name\s*:\s*(.*)", f.read())
        cpu = f"{names[0].strip()} ({len(names)} logical cores)" if names else cpu
    except OSError:
        pass
    dev = jax.devices()[0]
    return f"{cpu}; jax {jax.__version__}, backend {jax.default_backend()}, device {dev.device_kind}"


def main():
    batches = [int(b) for b in ARGS.batches.split(",")]
    sizes = [tuple(int(v) for v in s.split("x")) for s in ARGS.sizes.split(",")]
    modes = ARGS.modes.split(",")
    settings = qp.Settings(eps_abs=ARGS.eps, eps_rel=ARGS.eps, linsys=ARGS.linsys,
                           block_kernel=ARGS.block_kernel)
    if ARGS.shrink is not None:
        settings = settings._replace(compaction_shrink=ARGS.shrink)
    rng = np.random.default_rng(ARGS.seed)
    dev = jax.devices()[0]
    rows = []
    for n, m in sizes:
        bmax = max(batches)
        P, q, A, l, u = mpc_like(rng, bmax, n, m)
        q_prev = q * (1.0 + 0.05 * rng.standard_normal(q.shape))
        # warm start: the accurately solved previous (perturbed) problem
        tight = 1e-6 if DTYPE == "float64" else 1e-5
        prev = qp.solve(P, q_prev, A, l, u, settings=qp.Settings(eps_abs=tight, eps_rel=tight))
        warm_np = (np.asarray(prev.x), np.asarray(prev.y))
        for mode in modes:
            warm = warm_np if mode == "warm" else None
            cnt = min(ARGS.osqp_problems, bmax)
            t_osqp, it_osqp, ok_osqp = osqp_time(P, q, A, l, u, warm, ARGS.eps, cnt)
            for b in batches:
                data = [jax.device_put(jnp.asarray(a[:b], DTYPE), dev) for a in (P, q, A, l, u)]
                ws = None if warm is None else tuple(jax.device_put(jnp.asarray(w[:b], DTYPE), dev)
                                                     for w in warm)
                run = lambda: qp.solve(*data, settings=settings, warm_start=ws)
                t0 = time.perf_counter()
                sol = jax.block_until_ready(run())  # compile + first run
                t_first = time.perf_counter() - t0
                best = np.inf
                for _ in range(ARGS.repeats):
                    t0 = time.perf_counter()
                    sol = jax.block_until_ready(run())
                    best = min(best, time.perf_counter() - t0)
                st = np.asarray(sol.status)
                rate = b / best
                rows.append(dict(n=n, m=m, mode=mode, batch=b, qps=rate, t=best, first=t_first,
                                 it=float(np.mean(np.asarray(sol.iterations))),
                                 ok=float(np.mean(st == qp.SOLVED)), osqp_qps=1.0 / t_osqp,
                                 osqp_it=it_osqp, osqp_ok=ok_osqp, speedup=rate * t_osqp))
                r = rows[-1]
                print(f"n={n} m={m} {mode:4s} batch={b:6d}: {rate:12.0f} QP/s  ({best * 1e3:.2f} ms, "
                      f"first {t_first:.1f} s, mean it {r['it']:.0f}, solved {r['ok']:.3f})  "
                      f"OSQP {1 / t_osqp:9.0f} QP/s (it {it_osqp:.0f})  ratio {r['speedup']:.2f}",
                      flush=True)
    table = render(rows)
    print(table)
    if ARGS.write:
        write_section(table)


def render(rows):
    cmd = "python " + " ".join([os.path.relpath(sys.argv[0])] + sys.argv[1:])
    lines = [
        f"### {ARGS.device.upper()} ({DTYPE})",
        "",
        f"Machine: {machine()}.  ",
        f"Command: `{cmd}`  ",
        f"Tolerance eps_abs = eps_rel = {ARGS.eps:g} for both solvers; linsys = {ARGS.linsys}; "
        f"block kernel = {ARGS.block_kernel}; "
        "OSQP 1.1.3 time = its C timer `solve_time` (one thread, no setup, no polishing), mean over "
        f"{ARGS.osqp_problems} problems; ours = wall time of the batched jitted solve incl. scaling and "
        f"factorisation, best of {ARGS.repeats}.",
        "",
        "| n | m | start | batch | QPs/s (ours) | mean iters | solved | OSQP QPs/s | OSQP iters | ratio |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(f"| {r['n']} | {r['m']} | {r['mode']} | {r['batch']} | {r['qps']:,.0f} | "
                     f"{r['it']:.0f} | {r['ok']:.3f} | {r['osqp_qps']:,.0f} | {r['osqp_it']:.0f} | "
                     f"{r['speedup']:.2f}× |")
    return "\n".join(lines) + "\n"


HEADER = "## QP solver"
INTRO = """{h}

`hlip_jax.core.qp.solve` (dense OSQP-style ADMM, jit + vmap) against OSQP 1.1.3 on random strongly
convex MPC-like QPs (box rows on every variable + general rows), generated by
`benchmarks/qp_bench.py`. "ratio" = our QPs/s ÷ OSQP's single-thread QPs/s.
"""


def write_section(table):
    path = os.path.abspath(ARGS.out)
    text = open(path).read() if os.path.exists(path) else "# Benchmarks\n"
    sub = table.splitlines()[0]
    start = text.find("\n" + HEADER + "\n")
    if start < 0:
        section = INTRO.format(h=HEADER) + "\n" + table
        text = text.rstrip("\n") + "\n\n" + section
    else:
        start += 1
        end = text.find("\n## ", start + 1)
        end = len(text) if end < 0 else end + 1
        section = text[start:end]
        # replace this device's subsection, keep the other one
        s0 = section.find(sub + "\n")
        if s0 >= 0:
            s1 = section.find("\n### ", s0 + 1)
            s1 = len(section) if s1 < 0 else s1 + 1
            section = section[:s0] + table + ("\n" if s1 < len(section) else "") + section[s1:]
        else:
            section = section.rstrip("\n") + "\n\n" + table
        text = text[:start] + section.rstrip("\n") + "\n" + ("\n" + text[end:] if end < len(text) else "")
    with open(path, "w") as f:
        f.write(text)
    print(f"wrote {path}")


if __name__ == "__main__":
    print(machine(), flush=True)
    main()
