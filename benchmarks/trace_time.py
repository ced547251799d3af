"""Where the time before a sweep's first simulated step goes: tracing, lowering and compiling
the closed loop's segment program (:func:`hlip_jax.simulation.rollout.segment_batch`), each timed on
its own, for a sweep file's first ``--batch`` scenarios.

    python benchmarks/trace_time.py [--sweep sweeps/paper.toml] [--batch 6] [--duration 3]
        [--repeats 2] [--no-compile] [--unrolled-substeps]

Tracing runs the Python of the whole closed loop (MPC, stepping law, CLF-QP, MJX steps) once to
build its jaxpr; JAX does it on every process start, warm compilation cache or not, so it bounds
how fast a rerun can start.  Lowering turns the jaxpr into StableHLO; compiling is XLA's (what
the persistent cache saves).  Each repeat traces afresh (the jit's cache is cleared between
repeats); the figures print as they finish.  "start" is the start program's trace, compile and
first call together, once per process.  XLA settings come from ``XLA_FLAGS`` as given (the CLI's
own additions, :mod:`hlip_jax.runtime.xla_flags`, are not made here).  ``--unrolled-substeps`` measures the tick as it
was before its two MJX substeps became a loop (the same MJX step written out twice), for a
before/after comparison in one process.
"""

from __future__ import annotations

import argparse
import time


def _timed(label, f):
    t = time.perf_counter()
    out = f()
    print(f"{label:>10s}: {time.perf_counter() - t:7.2f} s", flush=True)
    return out


def _unroll_substeps():
    """Replace :func:`control.physics` (MJX-JAX path) by the substeps written out in Python."""
    import jax.numpy as jnp

    from hlip_jax.plants.cassie import control
    from hlip_jax.plants.cassie.mjx_import import mjx

    def physics(cassie, d, ctrl, force, mx=None, backend="jax", robots=1):
        mx = cassie.mjx_model if mx is None else mx
        xfrc = jnp.zeros_like(d.xfrc_applied).at[cassie.index.pelvis_body, :3].set(force)
        d = d.replace(ctrl=ctrl, xfrc_applied=xfrc)
        for _ in range(control.SUBSTEPS):
            d = mjx.step(mx, d)
        return d

    control.physics = physics


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sweep", default="sweeps/paper.toml")
    ap.add_argument("--batch", type=int, default=6)
    ap.add_argument("--duration", type=float, default=3.0)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--no-compile", action="store_true", help="trace and lower only")
    ap.add_argument("--unrolled-substeps", action="store_true",
                    help="the MJX substeps written out, as before they became a loop")
    args = ap.parse_args(argv)
    if args.unrolled_substeps:
        _unroll_substeps()

    import jax
    import jax.numpy as jnp

    from hlip_jax.simulation import arrays, rollout
    from hlip_jax.sweepio.sweep import load_sweep

    cfgs = list(load_sweep(args.sweep, duration=args.duration).scenarios)[:args.batch]
    batch, static = arrays.build(cfgs)
    static = static._replace(progress=True)
    print(f"{args.sweep}: {len(cfgs)} scenarios, {static.n_steps} steps, "
          f"plant {static.plant}, {jax.default_backend()}, "
          f"substeps {'unrolled' if args.unrolled_substeps else 'loop'}", flush=True)
    with jax.default_matmul_precision("highest"):
        carry, _ = _timed("start", lambda: jax.block_until_ready(
            rollout.start_batch(batch, static)))
        ks = jnp.arange(rollout.segment_length(static.n_steps))
        for r in range(args.repeats):
            print(f"repeat {r + 1}", flush=True)
            rollout.segment_batch.clear_cache()
            traced = _timed("trace", lambda: rollout.segment_batch.trace(batch, carry, ks, static))
            lowered = _timed("lower", traced.lower)
            if not args.no_compile:
                _timed("compile", lowered.compile)


if __name__ == "__main__":
    main()
