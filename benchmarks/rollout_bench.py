"""Closed-loop throughput on the H-LIP plant: one compiled call over a batch of mixed scenarios
(shapes, speeds, gains, disturbances, obstacles), scenario-steps per second and compile time.

    python benchmarks/rollout_bench.py --batch 4096 --duration 20 [--x64]
"""

from __future__ import annotations

import argparse
import itertools
import platform
import time


def mixed_configs(n: int, duration: float):
    from hlip_jax.simulation.config import (DisturbanceConfig, GainConfig, ObstacleConfig, PathConfig,
                                 PushConfig, ScenarioConfig)
    shapes = ["circle", "sinusoid", "square", "cardioid", "line", "figure_eight"]
    speeds = [0.3, 0.5, 0.8]
    gains = [GainConfig(), GainConfig(type="lqr", q_c=1.0, q_p=10.0, q_v=1.0, r=1.0),
             GainConfig(with_position=False)]
    dists = [DisturbanceConfig(), DisturbanceConfig(noise_p=0.005, noise_v=0.02),
             DisturbanceConfig(pushes=(PushConfig(time=5.0, duration=0.1, force=150.0),)),
             DisturbanceConfig(z0=0.85, noise_v=0.01)]
    obstacles = [(), (ObstacleConfig(x=2.0, y=0.0, radius=0.3),)]
    grid = itertools.cycle(itertools.product(shapes, speeds, gains, dists, obstacles))
    out = []
    for i in range(n):
        shape, v, g, d, o = next(grid)
        out.append(ScenarioConfig(seed=i, duration=duration, gain=g, disturbance=d, obstacles=o,
                                  path=PathConfig(shape=shape, params=dict(peak_speed=v))))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--batch", type=int, nargs="+", default=[4096])
    ap.add_argument("--duration", type=float, default=20.0, help="simulated seconds per scenario")
    ap.add_argument("--x64", action="store_true", help="float64 (default float32)")
    args = ap.parse_args(argv)
    import jax
    if args.x64:
        jax.config.update("jax_enable_x64", True)
    import numpy as np
    from hlip_jax.simulation import arrays
    from hlip_jax.core import steplog
    from hlip_jax.sweepio.bench import timed_run

    dev = jax.devices()[0]
    print(f"backend {jax.default_backend()} device {dev.device_kind} | {platform.processor() or platform.machine()}"
          f" | dtype {'float64' if args.x64 else 'float32'} | duration {args.duration} s")
    print("| batch | steps/scenario | build [s] | compile+first run [s] | run [s] | scenario-steps/s | ok |")
    print("|---|---|---|---|---|---|---|")
    for b in args.batch:
        cfgs = mixed_configs(b, args.duration)
        t0 = time.perf_counter()
        batch, static = arrays.build(cfgs)
        t_build = time.perf_counter() - t0
        t_first, t_run, out = timed_run(batch, static)
        steps = static.n_steps
        ok = float(np.mean(np.asarray(out["status"]) == steplog.STATUS_OK))
        print(f"| {b} | {steps} | {t_build:.1f} | {t_first:.1f} | {t_run:.2f} | "
              f"{b * steps / t_run:,.0f} | {ok:.3f} |", flush=True)


if __name__ == "__main__":
    main()
