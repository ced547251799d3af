"""Cassie walking benchmark: H-LIP orbit references (no MPC) on MJX with the CLF-QP.

One robot per case, all cases in one vmapped batch (one compile):

    in place, 0.2 / 0.5 / 0.8 m/s forward, 0.3 m/s sideways, turning in place at 30 °/s.

Reports per case: steps walked before a fall, average COM speed over the steps walked
(command in brackets), the S2S residual w = x_{k+1} − A x_k − B u_k per plane (max |·| and std
of p and v over the steps walked) and the error e_k = x_robot − x_HLIP; and the throughput in
robot-steps per second (compile excluded).  Writes a JSON file.

Run:  python benchmarks/cassie_walk_bench.py --device cpu --steps 8
      python benchmarks/cassie_walk_bench.py --device gpu --steps 40   (unchanged on a GPU)
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", choices=("cpu", "gpu"), default="cpu")
    ap.add_argument("--steps", type=int, default=8, help="walking steps per robot (≥ 2)")
    ap.add_argument("--t-ssp", type=float, default=0.26)
    ap.add_argument("--t-dsp", type=float, default=0.02)
    ap.add_argument("--z0", type=float, default=0.85)
    ap.add_argument("--width", type=float, default=0.15, help="nominal step width [m]")
    ap.add_argument("--gain", choices=("lqr", "deadbeat"), default="lqr",
                    help="3-state gain on [c, p, v]: LQR Q = diag(0.05, 1, 0.25), R = 4, or deadbeat")
    ap.add_argument("--tasks", default="all",
                    help="comma-separated subset of plant.WALK_TASKS (default all)")
    ap.add_argument("--out", default="cassie_walk_bench.json")
    args = ap.parse_args(argv)
    if args.steps < 2:
        ap.error("--steps must be ≥ 2")
    if args.device == "cpu":
        os.environ.setdefault("JAX_PLATFORMS", "cpu")
    else:
        os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
    import jax

    jax.config.update("jax_enable_x64", args.device == "cpu")
    import jax.numpy as jnp
    import numpy as np

    from hlip_jax import hlip
    from hlip_jax.plants.cassie import plant

    z0, ts, td = args.z0, args.t_ssp, args.t_dsp
    if args.gain == "lqr":
        A3, B3 = hlip.s2s_matrices(z0, ts, td)
        k = np.asarray(hlip.lqr_gain(A3, B3, jnp.diag(jnp.array([0.05, 1.0, 0.25])), jnp.array(4.0)))
    else:
        k = np.asarray(hlip.deadbeat_gain(z0, ts, td, with_position=True))
    gain = np.tile(k, (2, 1))
    CASES = plant.WALK_TASKS
    cases = [c for c in CASES if args.tasks == "all" or c[0] in args.tasks.split(",")]
    if not cases:
        ap.error(f"--tasks: none of {args.tasks!r} is one of {[c[0] for c in CASES]}")
    vf = np.array([c[1] for c in cases])
    vl = np.array([c[2] for c in cases])
    yr = np.deg2rad([c[3] for c in cases])
    step_fn = jax.jit(jax.vmap(plant.step_with_log))
    # compile (and warm up) on a 1-step run, then time the real one
    t0 = time.time()
    plant.walk_orbits(vf, vl, yr, 1, z0=z0, t_ssp=ts, t_dsp=td, width=args.width, gain=gain,
                      batch_step=step_fn)
    t_compile = time.time() - t0
    t0 = time.time()
    log, _ = plant.walk_orbits(vf, vl, yr, args.steps, z0=z0, t_ssp=ts, t_dsp=td,
                               width=args.width, gain=gain, batch_step=step_fn)
    t_run = time.time() - t0
    print(f"compile {t_compile:.1f} s, run {t_run:.1f} s", flush=True)
    np.savez(os.path.splitext(args.out)[0] + "_log.npz", **log._asdict())
    T = ts + td
    results = []
    for i, (name, f, s, y) in enumerate(cases):
        failed = log.failed[i]
        n_ok = int(np.argmax(failed)) if failed.any() else args.steps
        row = dict(case=name, cmd_forward=f, cmd_sideways=s, cmd_yaw_rate_deg=y, steps_walked=n_ok)
        if n_ok >= 2:
            c = log.x_robot[i, :n_ok + 1, :, 0]
            hd = log.heading[i, :n_ok + 1]
            # average over the last 10 s walked (all but the start-up step if shorter)
            lo = max(1, n_ok - int(round(10.0 / T)))
            d = c[-1] - c[lo]
            dur = (n_ok - lo) * T
            h = hd[lo:-1]                                 # heading over each interval
            fwd = np.cos(h) @ np.diff(c[lo:, 0]) + np.sin(h) @ np.diff(c[lo:, 1])
            side = -np.sin(h) @ np.diff(c[lo:, 0]) + np.cos(h) @ np.diff(c[lo:, 1])
            w = log.w[i, :n_ok - 1]
            e = log.e[i, :n_ok + 1]
            row.update(window_s=dur, speed_forward=float(fwd / dur), speed_sideways=float(side / dur),
                       displacement=d.tolist(),
                       yaw_rate_deg=float(np.rad2deg(np.unwrap(log.pelvis_yaw[i, :n_ok + 1])[-1]
                                                     - np.unwrap(log.pelvis_yaw[i, :n_ok + 1])[lo]) / dur),
                       w_max_abs={pl: np.abs(w[:, j, 1:]).max(0).tolist() for j, pl in enumerate("xy")},
                       w_std={pl: w[:, j, 1:].std(0).tolist() for j, pl in enumerate("xy")},
                       e_max_abs={pl: np.abs(e[:, j, 1:]).max(0).tolist() for j, pl in enumerate("xy")})
        results.append(row)
        print(json.dumps(row))
    summary = dict(device=args.device, backend=jax.default_backend(), steps=args.steps,
                   robots=len(cases), t_ssp=ts, t_dsp=td, z0=z0, gain=args.gain,
                   gain_cpv=k.tolist(), compile_s=t_compile, run_s=t_run,
                   robot_steps_per_s=len(cases) * args.steps / t_run,
                   sim_seconds_per_wall_second=len(cases) * args.steps * T / t_run,
                   cases=results)
    print(json.dumps({k: v for k, v in summary.items() if k != "cases"}))
    with open(args.out, "w") as fh:
        json.dump(summary, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
