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
    ap.add_argument("--t-ssp", type=float, help="default: orbits.WALK_DEFAULTS")
    ap.add_argument("--t-dsp", type=float, help="default: orbits.WALK_DEFAULTS")
    ap.add_argument("--z0", type=float, help="default: orbits.WALK_DEFAULTS")
    ap.add_argument("--width", type=float, help="nominal step width [m]; default: orbits.WALK_DEFAULTS")
    ap.add_argument("--gain", choices=("lqr", "deadbeat"), default="lqr",
                    help="3-state gain on [c, p, v]: the LQR of orbits.WALK_DEFAULTS, or deadbeat")
    ap.add_argument("--tasks", default="all",
                    help="comma-separated subset of orbits.WALK_TASKS (default all)")
    ap.add_argument("--out", default="cassie_walk_bench.json")
    ap.add_argument("--figures", metavar="DIR",
                    help="also plot each case's COM and footprints, foot heights and the "
                         "lateral S2S state against the H-LIP (PNG files in DIR)")
    args = ap.parse_args(argv)
    if args.steps < 2:
        ap.error("--steps must be ≥ 2")
    if args.device == "cpu":
        os.environ.setdefault("JAX_PLATFORMS", "cpu")
    else:
        os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
    import jax

    jax.config.update("jax_enable_x64", args.device == "cpu")
    import numpy as np

    from hlip_jax.core import hlip
    from hlip_jax.plants.cassie import plant

    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))  # the root
    from tests.support import cassie_orbits as orbits
    dflt = orbits.WALK_DEFAULTS
    pick = lambda v, k: dflt[k] if v is None else v                     # noqa: E731
    z0, ts, td = pick(args.z0, "z0"), pick(args.t_ssp, "t_ssp"), pick(args.t_dsp, "t_dsp")
    width = pick(args.width, "width")
    if args.gain == "lqr":
        k = np.asarray(orbits.lqr_step_gain(z0, ts, td, dflt["q_c"], dflt["q_v"], dflt["r"]))
    else:
        k = np.asarray(hlip.deadbeat_gain(z0, ts, td, with_position=True))
    gain = np.tile(k, (2, 1))
    CASES = orbits.WALK_TASKS
    cases = [c for c in CASES if args.tasks == "all" or c[0] in args.tasks.split(",")]
    if not cases:
        ap.error(f"--tasks: none of {args.tasks!r} is one of {[c[0] for c in CASES]}")
    vf = np.array([c[1] for c in cases])
    vl = np.array([c[2] for c in cases])
    yr = np.deg2rad([c[3] for c in cases])
    step_fn = jax.jit(jax.vmap(plant.step_with_log))
    # compile (and warm up) on a 1-step run, then time the real one
    t0 = time.time()
    orbits.walk_orbits(vf, vl, yr, 1, z0=z0, t_ssp=ts, t_dsp=td, width=width, gain=gain,
                      batch_step=step_fn)
    t_compile = time.time() - t0
    t0 = time.time()
    log, ticks = orbits.walk_orbits(vf, vl, yr, args.steps, z0=z0, t_ssp=ts, t_dsp=td,
                                   width=width, gain=gain, batch_step=step_fn,
                                   return_ticks=bool(args.figures))
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
            # average over the last 10 s walked (all but the start-up step if shorter)
            lo = max(1, n_ok - int(round(10.0 / T)))
            fwd, side, yaw_rate = orbits.walk_speeds(log, i, lo, n_ok, T)
            d = log.x_robot[i, n_ok, :, 0] - log.x_robot[i, lo, :, 0]
            w = log.w[i, :n_ok - 1]
            e = log.e[i, :n_ok + 1]
            row.update(window_s=(n_ok - lo) * T, speed_forward=fwd, speed_sideways=side,
                       displacement=d.tolist(), yaw_rate_deg=yaw_rate,
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
    if args.figures:
        plot(args.figures, cases, log, ticks, T)
    return 0


def plot(out_dir, cases, log, ticks, T):
    """Per case: (a) COM path and footprints (x-y), (b) both feet's height and the COM height
    over the first 4 s, (c) lateral pre-impact (p, v) of the robot and the H-LIP per step."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    os.makedirs(out_dir, exist_ok=True)
    n_tick = int(round(T * 1000))
    for i, (name, *_cmd) in enumerate(cases):
        com = np.concatenate([t.com[i, :n_tick] for t in ticks])            # (n, 3)
        feet = np.concatenate([t.feet[i, :n_tick] for t in ticks])          # (n, 2, 3)
        time_s = np.arange(com.shape[0]) * 1e-3
        fig, ax = plt.subplots(1, 3, figsize=(15, 4.2))
        ax[0].plot(com[:, 0], com[:, 1], "g-", lw=1, label="COM")
        for s, c in ((0, "tab:blue"), (1, "tab:red")):
            down = feet[:, s, 2] < 0.01
            ax[0].plot(feet[down, s, 0], feet[down, s, 1], ".", ms=2, color=c,
                       label="left foot on ground" if s == 0 else "right foot on ground")
        ax[0].set_aspect("equal", "datalim")
        ax[0].set(xlabel="x [m]", ylabel="y [m]", title=f"{name}: COM and footprints")
        ax[0].legend(fontsize=7)
        k = min(len(time_s), 4000)
        ax[1].plot(time_s[:k], feet[:k, 0, 2], color="tab:blue", label="left foot z")
        ax[1].plot(time_s[:k], feet[:k, 1, 2], color="tab:red", label="right foot z")
        ax[1].plot(time_s[:k], com[:k, 2] - 0.75, "g-", lw=0.8, label="COM z − 0.75 m")
        ax[1].set(xlabel="t [s]", ylabel="[m]", title="foot heights (first 4 s)")
        ax[1].legend(fontsize=7)
        xr, xh = log.x_robot[i], log.x_hlip[i]
        ax[2].plot(xr[1:, 1, 1], xr[1:, 1, 2], "o-", ms=3, lw=0.6, color="g", label="robot")
        ax[2].plot(xh[1:, 1, 1], xh[1:, 1, 2], "s", ms=4, mfc="none", color="b", label="H-LIP")
        ax[2].set(xlabel="lateral p [m]", ylabel="lateral v [m/s]",
                  title="pre-impact lateral state per step")
        ax[2].legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(os.path.join(out_dir, f"cassie_walk_{name}.png"), dpi=80)
        plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
