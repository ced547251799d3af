"""Cassie standing under the CLF-QP at scale: physics-only vs physics + CLF-QP throughput, and
how many of a batch of randomly perturbed robots stand.

Every robot starts at the ``stand`` keyframe with ±``--noise`` rad on every hinge, made
consistent by ``model.stance_projection`` (chains closed, soles flat on the floor; ``--raw``
skips it and starts from the open chains, as the first measurements did); one control
tick is one condensed-dynamics CLF-QP (``hlip_jax.core.qp``, warm-started) and 2 MJX physics steps
(1 kHz control, 2 kHz physics).  The physics-only run steps the same batch with zero torque for
the same number of ticks.  A robot is *upright* when, at the end, its pelvis is above 0.85 m and
its roll and pitch are under 0.1 rad; the last column also asks its COM height to be within
2 cm of the target.  With ``--push F`` the same batch is run a second time (same compiled
program) with a pelvis force of F newtons for 0.2 s at ``--push-at`` seconds, in a uniformly
random horizontal direction per robot, and the upright count is reported per direction sector.

    python benchmarks/cassie_stand_bench.py                                  # CPU: batch 8
    python benchmarks/cassie_stand_bench.py --batch 1024 4096 --seconds 2    # GPU
    python benchmarks/cassie_stand_bench.py --batch 4096 --seconds 2 --push 50
"""

from __future__ import annotations

import argparse
import os
import time


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--batch", type=int, nargs="+", default=[8])
    ap.add_argument("--seconds", type=float, default=1.0, help="simulated seconds per robot")
    ap.add_argument("--chunk", type=int, default=250, help="control ticks per compiled call")
    ap.add_argument("--noise", type=float, default=0.03, help="hinge offsets [rad]")
    ap.add_argument("--x64", action="store_true", help="float64 (default float32)")
    ap.add_argument("--raw", action="store_true",
                    help="keep the offset configurations as drawn (chains open, feet off the floor)")
    ap.add_argument("--push", type=float, default=0.0, metavar="F",
                    help="also run with an F-newton pelvis push for 0.2 s in a random direction")
    ap.add_argument("--push-at", type=float, default=0.5, metavar="S", help="push start [s]")
    args = ap.parse_args(argv)
    os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
    import jax
    if args.x64:
        jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import numpy as np

    from hlip_jax.plants.cassie import control, model

    cassie = control.load()
    dev = jax.devices()[0]
    print(f"backend {jax.default_backend()} device {dev.device_kind}; {args.seconds} s per robot, "
          f"{args.chunk} ticks per call, {'float64' if args.x64 else 'float32'}")
    print("| batch | compile [s] | CLF-QP + physics [robot-s/s] | physics steps/s (with CLF-QP) | "
          "physics only [steps/s] | ratio | upright | COM z within 2 cm |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|")
    n_calls = max(1, int(round(args.seconds / (args.chunk * control.CONTROL_DT))))
    for B in args.batch:
        d = model.make_batch(cassie, B, jax.random.PRNGKey(B), qpos_noise=args.noise,
                             consistent=not args.raw)
        d = jax.jit(jax.vmap(lambda x: control.canonical(cassie, x)))(d)
        com = jax.jit(jax.vmap(lambda x: model.robot_terms(cassie, x).com))(d)
        target = jnp.concatenate([com[:, :2], com[:, 2:3] - 0.02, jnp.zeros((B, 1), com.dtype)], 1)
        warm = jax.vmap(lambda _: control.warm_zeros(cassie, com.dtype))(jnp.arange(B))

        @jax.jit
        def chunk(d, warm, t0, target, push):
            def one(d, w, t, tg, p):
                return control.stand_rollout(cassie, d, tg, args.chunk, push=p, warm=w, t0=t)
            return jax.vmap(one)(d, warm, t0, target, push)

        no_push = jnp.zeros((B, 5), com.dtype).at[:, :2].set(-1.0)

        physics_only = jax.jit(jax.vmap(lambda d: control.zero_torque_rollout(cassie, d, args.chunk)))

        t0 = time.perf_counter()
        out = chunk(d, warm, jnp.zeros(B, com.dtype), target, no_push)
        jax.block_until_ready(out)
        compile_s = time.perf_counter() - t0
        # the data a chunk returns can differ in weak types from the initial data: one more
        # call on its own output so the timed loop below reuses a single compiled program
        jax.block_until_ready(chunk(out[0], out[1], jnp.zeros(B, com.dtype), target, no_push))

        def run(push):
            dd, ww = d, warm
            t0 = time.perf_counter()
            for i in range(n_calls):
                dd, ww, log = chunk(dd, ww, jnp.full(B, i * args.chunk * control.CONTROL_DT,
                                                     com.dtype), target, push)
            jax.block_until_ready(log)
            return log, time.perf_counter() - t0

        log, run_s = run(no_push)
        jax.block_until_ready(physics_only(d))
        t0 = time.perf_counter()
        dp = d
        for _ in range(n_calls):
            dp = physics_only(dp)
        jax.block_until_ready(dp)
        phys_s = time.perf_counter() - t0
        ticks = n_calls * args.chunk
        steps = ticks * control.SUBSTEPS
        z = np.asarray(log.pelvis_z[:, -1])
        rpy = np.asarray(log.rpy[:, -1])
        comz = np.asarray(log.com[:, -1, 2])
        stood = (z > 0.85) & (np.abs(rpy[:, :2]).max(1) < 0.1) & np.isfinite(z)
        within = stood & (np.abs(comz - np.asarray(target[:, 2])) < 0.02)
        rate = B * steps / run_s
        prate = B * steps / phys_s
        print(f"| {B} | {compile_s:.1f} | {B * ticks * control.CONTROL_DT / run_s:,.1f} | {rate:,.0f} | "
              f"{prate:,.0f} | {rate / prate:.2f} | {stood.mean():.3f} ({stood.sum()}/{B}) | "
              f"{within.mean():.3f} |", flush=True)
        if args.push > 0:
            ang = np.asarray(jax.random.uniform(jax.random.PRNGKey(B + 1), (B,), minval=-np.pi,
                                                maxval=np.pi))
            push = np.zeros((B, 5))
            push[:, 0], push[:, 1] = args.push_at, args.push_at + 0.2
            push[:, 2], push[:, 3] = args.push * np.cos(ang), args.push * np.sin(ang)
            plog, _ = run(jnp.asarray(push, com.dtype))
            z = np.asarray(plog.pelvis_z[:, -1])
            rpy = np.asarray(plog.rpy[:, -1])
            ok = (z > 0.85) & (np.abs(rpy[:, :2]).max(1) < 0.1) & np.isfinite(z)
            print(f"{args.push:g} N for 0.2 s at {args.push_at:g} s, random direction: upright "
                  f"{ok.sum()}/{B} ({ok.mean():.3f}); by direction of the force:")
            for name, lo, hi in (("forward (|angle| < 45°)", -45, 45), ("left", 45, 135),
                                 ("backward", 135, 225), ("right", -135, -45)):
                a = np.rad2deg(ang) % 360
                lo_, hi_ = lo % 360, hi % 360
                sel = (a >= lo_) & (a < hi_) if lo_ < hi_ else (a >= lo_) | (a < hi_)
                print(f"  {name}: {ok[sel].sum()}/{sel.sum()}")


if __name__ == "__main__":
    main()
