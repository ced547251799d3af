"""Random search over Cassie's gait parameters on the orbit-walking tasks (device-sized).

Every parameter set (one :class:`hlip_jax.config.CassieConfig` plus the H-LIP timing, COM
height, nominal step width and the weights of the 3-state LQR stepping gain) is run on the walking tasks of
issue #8 — in place, 0.2 / 0.5 / 0.8 m/s forward, 0.3 m/s sideways, turning in place at
30 °/s — all sets × tasks as one vmapped batch (one compile: every parameter is data).  Set 0
is the current default.  Per robot: steps walked before a fall, average speed over the second
half of the run against the command, the S2S residual w.  Per set: the mean fraction of steps
walked over the tasks and the worst relative speed error.  Writes everything to a JSON file
and prints the best sets.

    python benchmarks/cassie_gait_search.py --sets 256 --steps 16 --out search.json   (GPU)
    python benchmarks/cassie_gait_search.py --sets 1 --steps 2 --device cpu            (smoke)

``--around FILE`` samples new sets near the best sets of an earlier result file (each
parameter perturbed by ±``--spread`` of its range) instead of over the whole ranges.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time

# name: (lo, hi, log-scale) — CassieConfig fields and the walk's own parameters
RANGES = {
    "t_ssp": (0.25, 0.4, False), "t_dsp": (0.02, 0.1, False), "z0": (0.75, 0.9, False),
    "width": (0.15, 0.35, False), "q_c": (0.01, 3.0, True), "q_v": (0.1, 10.0, True),
    "r": (0.1, 10.0, True),
    "clearance": (0.05, 0.15, False), "strike": (0.0, 0.04, False), "reach": (0.5, 0.95, False),
    "freeze": (0.6, 1.0, False), "early_contact": (0.5, 0.95, False),
    "foot_torque": (0.0, 1.0, False), "assist_ssp": (0.0, 3.0, False),
    "assist_dsp": (0.0, 5.0, False), "omega_pelvis": (4.0, 20.0, True),
    "omega_height": (4.0, 20.0, True), "omega_com": (1.0, 10.0, True),
    "omega_swing": (8.0, 40.0, True), "omega_yaw": (5.0, 20.0, True),
    "weight_com": (0.05, 3.0, True), "weight_pelvis": (0.3, 5.0, True),
}


def sample(rng, n, around=None, spread=0.15):
    """n parameter dicts: uniform (log-uniform) over RANGES, or near the dicts in ``around``."""
    import numpy as np

    out = []
    for i in range(n):
        base = around[i % len(around)] if around else None
        d = {}
        for k, (lo, hi, log) in RANGES.items():
            a, b = (np.log(lo), np.log(hi)) if log else (lo, hi)
            if base is None or k not in base:
                x = rng.uniform(a, b)
            else:
                x0 = np.log(base[k]) if log else base[k]
                x = np.clip(x0 + spread * (b - a) * rng.uniform(-1, 1), a, b)
            d[k] = float(np.exp(x) if log else x)
        out.append(d)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", choices=("cpu", "gpu"), default="gpu")
    ap.add_argument("--sets", type=int, default=256, help="parameter sets (set 0 = defaults)")
    ap.add_argument("--steps", type=int, default=16, help="walking steps per robot (≥ 2)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--around", help="result JSON of an earlier search: sample near its best")
    ap.add_argument("--top", type=int, default=8, help="best sets of --around to sample near")
    ap.add_argument("--spread", type=float, default=0.15)
    ap.add_argument("--out", default="cassie_gait_search.json")
    args = ap.parse_args(argv)
    if args.steps < 2 or args.sets < 1:
        ap.error("--steps must be ≥ 2 and --sets ≥ 1")
    if args.device == "cpu":
        os.environ.setdefault("JAX_PLATFORMS", "cpu")
    import jax

    jax.config.update("jax_enable_x64", args.device == "cpu")
    import numpy as np

    from hlip_jax.config import CassieConfig
    from hlip_jax.plants.cassie import plant

    rng = np.random.default_rng(args.seed)
    defaults = {**plant.WALK_DEFAULTS, **{f.name: getattr(CassieConfig(), f.name)
                                   for f in dataclasses.fields(CassieConfig)}}
    around = None
    if args.around:
        with open(args.around) as fh:
            prev = json.load(fh)
        around = [s["params"] for s in prev["sets"][: args.top]]
    sets = [{k: defaults[k] for k in RANGES}] + sample(rng, args.sets - 1, around, args.spread)
    TASKS = plant.WALK_TASKS
    n_task = len(TASKS)
    rows = [(s, t) for s in sets for t in TASKS]
    B = len(rows)
    col = lambda k: np.array([s[k] for s, _ in rows])                     # noqa: E731
    z0, ts, td = col("z0"), col("t_ssp"), col("t_dsp")
    # stepping gain: 3-state LQR on [c, p, v] per plane, Q = diag(q_c, 1, q_v), R = r
    k = np.asarray(jax.vmap(plant.lqr_step_gain)(z0, ts, td, col("q_c"), col("q_v"), col("r")))
    gain = np.repeat(k.reshape(B, 1, 3), 2, axis=1)
    gaits = [CassieConfig(**{f.name: s[f.name] for f in dataclasses.fields(CassieConfig)
                             if f.name in s}) for s, _ in rows]
    vf = np.array([t[1] for _, t in rows])
    vl = np.array([t[2] for _, t in rows])
    yr = np.deg2rad([t[3] for _, t in rows])
    print(f"{len(sets)} sets × {n_task} tasks = {B} robots, {args.steps} steps, "
          f"backend {jax.default_backend()}", flush=True)
    step_fn = jax.jit(jax.vmap(plant.step_with_log))
    kw = dict(z0=z0, t_ssp=ts, t_dsp=td, width=col("width"), gain=gain, gait=gaits,
              batch_step=step_fn)
    t0 = time.time()
    plant.walk_orbits(vf, vl, yr, 1, **kw)
    t_compile = time.time() - t0
    print(f"compile + 1 step: {t_compile:.1f} s", flush=True)
    t0 = time.time()
    log, _ = plant.walk_orbits(vf, vl, yr, args.steps, **kw)
    t_run = time.time() - t0
    T = ts + td
    print(f"run: {t_run:.1f} s ({B * args.steps * T.mean() / t_run:.1f} robot-s per s)",
          flush=True)

    K = args.steps
    per_robot = []
    for i in range(B):
        f = log.failed[i]
        n_ok = int(np.argmax(f)) if f.any() else K
        r = dict(steps=n_ok)
        lo = max(1, K // 2)
        if n_ok == K:
            r["fwd"], r["side"], r["yaw_rate_deg"] = plant.walk_speeds(log, i, lo, K, T[i])
            w = log.w[i, lo - 1:]
            r["w_max"] = np.abs(w[..., 1:]).max(0).tolist()     # (plane, [p, v])
        per_robot.append(r)

    def speed_err(r, t):
        """Relative error of the commanded motion (absolute in m/s for in place, scaled)."""
        _, f, s, y = t
        if "fwd" not in r:
            return float("inf")
        if y:
            return abs(r["yaw_rate_deg"] - y) / y
        if f:
            return abs(r["fwd"] - f) / f
        if s:
            return abs(r["side"] - s) / s
        return (abs(r["fwd"]) + abs(r["side"])) / 0.1        # in place: drift vs 0.1 m/s

    out_sets = []
    for j, s in enumerate(sets):
        rs = per_robot[j * n_task:(j + 1) * n_task]
        errs = [speed_err(r, t) for r, t in zip(rs, TASKS)]
        walked = float(np.mean([r["steps"] / K for r in rs]))
        out_sets.append(dict(index=j, params=s, walked=walked,
                             tasks_full=int(sum(r["steps"] == K for r in rs)),
                             worst_speed_err=float(max(errs)),
                             tasks={t[0]: dict(r, speed_err=e) for t, r, e in zip(TASKS, rs, errs)}))
    order = sorted(out_sets, key=lambda d: (-d["walked"], d["worst_speed_err"]))
    summary = dict(backend=jax.default_backend(), devices=str(jax.devices()), sets_n=len(sets),
                   tasks=[t[0] for t in TASKS], steps=K, robots=B, compile_s=t_compile,
                   run_s=t_run, default_set=out_sets[0], sets=order)
    with open(args.out, "w") as fh:
        json.dump(summary, fh, indent=1)
    d0 = out_sets[0]
    print(f"defaults: walked {d0['walked']:.2f}, full tasks {d0['tasks_full']}/{n_task}")
    for d in order[:10]:
        print(f"set {d['index']:4d} walked {d['walked']:.2f} full {d['tasks_full']}/{n_task} "
              f"worst speed err {d['worst_speed_err']:.2f} "
              + " ".join(f"{k}={v:.3g}" for k, v in d["params"].items()), flush=True)
    hist = np.bincount([d["tasks_full"] for d in out_sets], minlength=n_task + 1)
    print("sets by tasks fully walked:", hist.tolist())
    return 0


if __name__ == "__main__":
    sys.exit(main())
