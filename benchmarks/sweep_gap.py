"""Why a Cassie sweep runs slower than ``hlip-sweep bench``: the same compiled closed loop
(:func:`hlip_jax.simulation.execution.run`) timed on the benchmark's scenarios and on a shipped sweep's, at
one batch size and one simulated duration, in one process.

    python benchmarks/sweep_gap.py --batch 256 --duration 2.0 [--sweep sweeps/coverage_study.toml]
        [--cases sweep bench sweep-qp25] [--json OUT.json] [--per-step]

Cases:
  sweep       ``batch`` scenarios spread evenly over the sweep file's, duration overridden;
  bench       the benchmark's straight lines (``hlip_jax.sweepio.bench.configs``);
  sweep-qp25  the sweep's scenarios with the CLF-QP's ADMM budget cut to one convergence check
              (25 iterations): the time it saves is the ADMM iterations' cost in the sweep;
  sweep-realism  the sweep's scenarios with the non-ideal robot's stages compiled in
              (``Shapes.non_ideal``) but every value ideal: the cost of those stages alone
              (the sweep itself must be ideal).

Per case: compile + first call [s], second call [s], simulated robot-seconds per wall-second
(robots × steps × the H-LIP's T_SSP + T_DSP over the second call), the fraction of robots that
walked to the end.  Results print as each case finishes.  With ``--per-step`` each case runs
once, with the rollout's progress callback compiled in, and prints the wall time at which each
walking step of the batch finished (the first includes the compile): where a sweep's time goes.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time


def _cases(name, sweep_file, batch, duration):
    from hlip_jax.sweepio import bench
    from hlip_jax.sweepio.sweep import load_sweep

    if name == "bench":
        return bench.configs(batch, duration)
    every = list(load_sweep(sweep_file, duration=duration).scenarios)
    cfgs = [every[(i * len(every)) // batch % len(every)] for i in range(batch)]  # spread
    if name == "sweep-qp25":
        cfgs = [dataclasses.replace(c, cassie=dataclasses.replace(c.cassie, qp_max_iter=25))
                for c in cfgs]
    return cfgs


def run_case(name, sweep_file, batch, duration):
    import jax
    import numpy as np

    from hlip_jax.simulation import arrays
    from hlip_jax.sweepio import bench
    from hlip_jax.core import steplog

    cfgs = _cases(name, sweep_file, batch, duration)
    shapes = arrays.shapes_of(cfgs)
    if name == "sweep-realism":
        if shapes.non_ideal:
            raise SystemExit("sweep-realism: the sweep must be ideal (no [realism] departures)")
        shapes = shapes._replace(non_ideal=True)
    b, static = arrays.build(cfgs, shapes=shapes)
    t_first, t_run, out = bench.timed_run(b, static)
    sim = float(np.sum(np.asarray(b.t_ssp + b.t_dsp)) * static.n_steps)
    walked = float(np.mean(np.asarray(out["status"]) == steplog.STATUS_OK))
    return dict(case=name, batch=batch, duration=duration, steps=static.n_steps,
                ticks_per_step=int(b.plant.ticks.shape[-1]), compile_first_s=t_first,
                run_s=t_run, robot_s_per_s=sim / t_run, walked=walked,
                device=jax.devices()[0].device_kind)


def per_step(name, sweep_file, batch, duration):
    """One call with progress news: prints (step, wall time since the call began [s])."""
    import jax
    import numpy as np

    from hlip_jax.simulation import arrays, execution
    from hlip_jax.runtime import progress
    from hlip_jax.core import steplog

    b, static = arrays.build(_cases(name, sweep_file, batch, duration))
    t0 = time.perf_counter()
    last = [t0]

    def heard(k, n):
        now = time.perf_counter()
        print(f"{name}: step {k}/{n} at {now - t0:.1f} s (+{now - last[0]:.1f} s)", flush=True)
        last[0] = now

    with progress.listening(heard), jax.default_matmul_precision("highest"):
        out = jax.block_until_ready(execution.run(b, static._replace(progress=True)))
    status = np.asarray(out["status"])
    print(f"{name}: done at {time.perf_counter() - t0:.1f} s; walked "
          f"{np.mean(status == steplog.STATUS_OK):.3f}; fail steps "
          f"{np.bincount(np.maximum(np.asarray(out['fail_step']), 0))}", flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, default=256)
    ap.add_argument("--duration", type=float, default=2.0)
    ap.add_argument("--sweep", default="sweeps/coverage_study.toml")
    ap.add_argument("--cases", nargs="+", default=["sweep", "bench", "sweep-qp25"],
                    choices=["sweep", "bench", "sweep-qp25", "sweep-realism"])
    ap.add_argument("--json", default=None)
    ap.add_argument("--per-step", action="store_true")
    a = ap.parse_args(argv)
    rows = []
    for name in a.cases:
        if a.per_step:
            per_step(name, a.sweep, a.batch, a.duration)
            continue
        row = run_case(name, a.sweep, a.batch, a.duration)
        rows.append(row)
        print(json.dumps(row), flush=True)
        if a.json:
            with open(a.json, "w") as f:
                json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
