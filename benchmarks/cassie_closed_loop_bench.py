"""Closed-loop Cassie throughput: the MPC on the H-LIP driving the MJX Cassie plant through the
stepping law, one compiled, vmapped call over a batch of scenarios (straight paths at several
speeds), against physics-only MJX on the same model in the same run.

Reported: simulated robot-seconds per wall-second, physics steps per second (2 per 1 kHz
control tick), the physics-only figure and their ratio, compile time, and how many robots were
still walking at the end.

    python benchmarks/cassie_closed_loop_bench.py --batch 2 --duration 0.7      # CPU
    python benchmarks/cassie_closed_loop_bench.py --batch 1024 4096 --duration 2  # GPU
"""

from __future__ import annotations

import argparse
import os
import time


def configs(n: int, duration: float):
    from hlip_jax.config import GainConfig, HLIPConfig, PathConfig, ScenarioConfig
    speeds = [0.0, 0.2, 0.4, 0.6]
    return [ScenarioConfig(plant="cassie", seed=i, duration=duration,
                           hlip=HLIPConfig(z0=0.85, t_ssp=0.25, t_dsp=0.1),
                           gain=GainConfig(type="lqr", with_position=False, q_p=1.0, q_v=1.0, r=2.0),
                           path=PathConfig(shape="line", params=dict(
                               peak_speed=max(speeds[i % 4], 0.01), length=5.0)))
            for i in range(n)]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--batch", type=int, nargs="+", default=[2])
    ap.add_argument("--duration", type=float, default=0.7, help="simulated seconds per robot")
    args = ap.parse_args(argv)
    os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
    import jax
    import jax.numpy as jnp
    import numpy as np

    from hlip_jax import rollout
    from hlip_jax.plants.cassie import control, model
    from hlip_jax.plants.cassie import plant as cassie_plant

    dev = jax.devices()[0]
    print(f"backend {jax.default_backend()} device {dev.device_kind}; {args.duration} s per robot, float32")
    print("| batch | steps | compile+first [s] | run [s] | robot-s/s | physics steps/s (closed loop) | "
          "physics only [steps/s] | ratio | walking at end |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    cassie = cassie_plant.cassie()
    for B in args.batch:
        cfgs = configs(B, args.duration)
        batch, static = rollout.build(cfgs)
        t0 = time.perf_counter()
        with jax.default_matmul_precision("highest"):
            out = rollout.run(batch, static)
            jax.block_until_ready(out)
            t1 = time.perf_counter()
            out = rollout.run(batch, static)
            jax.block_until_ready(out)
        t2 = time.perf_counter()
        # ticks that simulate (the per-step scan has a static budget; ticks past T are idle)
        T = float(np.asarray(batch.t_ssp[0] + batch.t_dsp[0]))
        ticks = static.n_steps * int(round(T / control.CONTROL_DT))
        steps = ticks * control.SUBSTEPS
        sim_s = B * static.n_steps * T

        d = model.make_batch(cassie, B, jax.random.PRNGKey(0))

        physics_only = jax.jit(jax.vmap(lambda d: control.zero_torque_rollout(cassie, d, ticks)))

        jax.block_until_ready(physics_only(d))
        t3 = time.perf_counter()
        jax.block_until_ready(physics_only(d))
        t4 = time.perf_counter()
        rate = B * steps / (t2 - t1)
        prate = B * steps / (t4 - t3)
        ok = np.asarray(out["status"]) == rollout.STATUS_OK
        print(f"| {B} | {static.n_steps} | {t1 - t0:.1f} | {t2 - t1:.2f} | {sim_s / (t2 - t1):,.1f} | "
              f"{rate:,.0f} | {prate:,.0f} | {rate / prate:.2f} | {ok.mean():.3f} |", flush=True)


if __name__ == "__main__":
    main()
