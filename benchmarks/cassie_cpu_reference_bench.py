"""CPU baseline of the standing CLF-QP: C MuJoCo + numpy + OSQP per tick, one robot per process.

Runs ``tests/support/cassie_cpu_reference.py`` (the same controller as the MJX/JAX one: model
terms → condensed dynamics → CLF-QP by OSQP → 2 × ``mj_step`` of 0.5 ms) in ``--procs``
processes (default: one per core), each standing one robot from the keyframe for ``--seconds``
of simulated time (COM target 2 cm below the start, as the standing tests).  The processes are
started with ``spawn``, set up their model, data and OSQP object, run a short warm-up on a
throw-away robot, and then start the timed run together (a barrier).

Reports:

* aggregate control ticks/s = Σ ticks / (last end − first start) over all processes, and
  physics steps/s = 2 × that (1 kHz control, 2 kHz physics);
* each process's own ticks/s and its real-time factor (simulated s per wall s);
* the per-tick time split of process 0 (model terms, outputs, condensation, QP build, OSQP
  update + solve, physics, and the remainder: loop, logging, timers) [µs/tick];
* the compiled-code floor of process 0: the same tick's C MuJoCo, LAPACK and OSQP calls timed
  alone (what a C/C++ implementation could not go below; the rest is Python/numpy glue);
* whether the robots stood (final COM height error, upright) and the OSQP status / iterations;
* ``jax_backend_initialised``: the workers import the project's JAX modules for constants only
  (MJCF path, index map, gains, QP settings); this records that no JAX backend was ever
  initialised in them, i.e. no JAX computation ran.

BLAS threads are pinned to 1 per process (``OPENBLAS_NUM_THREADS`` etc.), ``--pin`` also pins
process i to core i mod cpu_count.

    python benchmarks/cassie_cpu_reference_bench.py --procs 2 --seconds 2 --out cpu_ref.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

# the repository root: tests.support.cassie_cpu_reference
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS",
                "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS")
WARMUP_TICKS = 20
FLOOR_REPS = 300


def _compiled_floor(cr, robot, target) -> dict:
    """µs per tick spent in compiled code only, timed call group by call group at the robot's
    final state (each group repeated ``FLOOR_REPS`` times, cache-warm, so slightly optimistic):
    the C MuJoCo model-term calls, ``mj_solveM``, LAPACK ``eigh`` of G, OSQP update + warm start
    + solve, and the 2 ``mj_step``.  Their sum is what a compiled (C/C++) implementation of the
    same tick could not go below; the rest of the measured tick is Python/numpy glue."""
    import mujoco
    import numpy as np

    s, d, m = robot.s, robot.d, robot.s.m
    qpos, qvel, ctrl = d.qpos.copy(), d.qvel.copy(), d.ctrl.copy()
    des = cr.stand_desired(target[2], target[:2], target[3])
    terms = cr.robot_terms(s, d)
    meas = cr.measure(terms, d.qvel, s.idx.root_dof)
    J, jd, active, H = cr.constraint_stack(terms, robot.contact, s.springs)
    Yt = np.concatenate([s.B.T, (terms.passive - terms.bias)[None], J])
    X = robot.solve_M(Yt)
    G = J @ X[m.nu + 1:].T
    G[np.diag_indices_from(G)] += 1.0 - active
    cond = cr.condense(terms, s.B, robot.contact, s.springs, robot.solve_M)
    prob = cr.build(meas, des, cond, robot.contact, s.tau_min, s.tau_max, robot.gains)
    site_J, J3 = np.empty((3, m.nv)), np.empty((3, m.nv))
    M = np.empty((m.nv, m.nv))
    p1 = d.xpos[s.loop_b1].copy()
    p2 = d.xpos[s.loop_b2].copy()

    def terms_c():
        cr.smooth(m, d)
        mujoco.mj_fullM(m, d, M)
        for site in s.sites:
            mujoco.mj_jacSite(m, d, site_J, None, site)
        for k in range(4):
            mujoco.mj_jac(m, d, J3, None, p1[k], int(s.loop_b1[k]))
            mujoco.mj_jac(m, d, J3, None, p2[k], int(s.loop_b2[k]))
        mujoco.mj_jacSubtreeCom(m, d, J3, s.idx.pelvis_body)

    def solve_m():
        mujoco.mj_solveM(m, d, X, Yt)

    def eigh():
        np.linalg.eigh(G)

    def osqp_():
        robot.qp.solve(prob.P, prob.q, prob.A, prob.l, prob.u, robot.warm)

    def physics():
        d.qpos[:], d.qvel[:] = qpos, qvel
        for _ in range(cr.SUBSTEPS):
            mujoco.mj_step(m, d)

    out = {}
    for name, f in (("model terms (C MuJoCo calls)", terms_c), ("mj_solveM", solve_m),
                    ("eigh of G (LAPACK)", eigh), ("OSQP update + solve", osqp_),
                    ("physics (2 × mj_step)", physics)):
        f()
        t0 = time.perf_counter()
        for _ in range(FLOOR_REPS):
            f()
        out[name] = (time.perf_counter() - t0) / FLOOR_REPS * 1e6
    d.qpos[:], d.qvel[:], d.ctrl[:] = qpos, qvel, ctrl
    out["total"] = sum(out.values())
    return out


def _worker(rank: int, seconds: float, pin: bool, profile: bool, barrier, queue) -> None:
    """One process: set up one robot, wait for the others, stand it for ``seconds``."""
    try:
        if pin and hasattr(os, "sched_setaffinity"):
            os.sched_setaffinity(0, {rank % os.cpu_count()})
        import numpy as np

        from tests.support import cassie_cpu_reference as cr

        s = cr.static(cr.load_model())
        warm = cr.Robot(s)                                   # warm-up: caches, lazy inits
        cr.stand(WARMUP_TICKS * cr.CONTROL_DT, cr.default_target(warm), robot=warm)
        robot = cr.Robot(s)
        target = cr.default_target(robot)
        prof = np.zeros(len(cr.STAGES)) if profile else None
        barrier.wait()
        t0 = time.time()
        log = cr.stand(seconds, target, robot=robot, prof=prof)
        t1 = time.time()
        floor = _compiled_floor(cr, robot, target) if profile else None
        n = len(log.V)
        jax_mod = sys.modules.get("jax")
        backends = {}
        if jax_mod is not None:
            from jax._src import xla_bridge
            backends = dict(getattr(xla_bridge, "_backends", {}) or {})
        err = np.abs(log.com[:, 2] - target[2])
        tail = max(1, n // 4)
        status, counts = np.unique(log.status, return_counts=True)
        queue.put(dict(
            rank=rank, pid=os.getpid(),
            cpus=sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
            ticks=n, t_start=t0, t_end=t1, wall_s=t1 - t0, ticks_per_s=n / (t1 - t0),
            realtime_factor=n * cr.CONTROL_DT / (t1 - t0),
            prof_s=None if prof is None else prof.tolist(), compiled_floor_us=floor,
            com_z_err_final_m=float(err[-1]), com_z_err_max_last_quarter_m=float(err[-tail:].max()),
            upright=bool(np.all(log.pelvis_z > 0.8) and np.all(np.abs(log.rpy[:, :2]) < 0.2)),
            osqp_status={int(k): int(v) for k, v in zip(status, counts)},
            osqp_iterations_mean=float(log.iterations.mean()),
            osqp_iterations_max=int(log.iterations.max()),
            jax_imported=jax_mod is not None, jax_backend_initialised=bool(backends)))
    except BaseException as exc:  # report instead of hanging the parent on the queue
        try:
            barrier.abort()
        except Exception:
            pass
        queue.put(dict(rank=rank, error=f"{type(exc).__name__}: {exc}"))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--procs", type=int, default=os.cpu_count(),
                    help="processes, one robot each (default: os.cpu_count())")
    ap.add_argument("--seconds", type=float, default=2.0, help="simulated seconds per robot")
    ap.add_argument("--pin", action="store_true", help="pin process i to core i mod cpu_count")
    ap.add_argument("--out", default="cassie_cpu_reference_bench.json")
    args = ap.parse_args(argv)
    if args.procs < 1:
        ap.error("--procs must be ≥ 1")
    if not args.seconds > 0:
        ap.error("--seconds must be > 0")
    for v in _THREAD_VARS:                      # inherited by the spawned workers
        os.environ[v] = "1"
    os.environ.setdefault("JAX_PLATFORMS", "cpu")

    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    barrier = ctx.Barrier(args.procs)
    queue = ctx.Queue()
    load_before = os.getloadavg() if hasattr(os, "getloadavg") else None
    procs = [ctx.Process(target=_worker, args=(r, args.seconds, args.pin, r == 0, barrier, queue))
             for r in range(args.procs)]
    for p in procs:
        p.start()
    rows = [queue.get() for _ in procs]
    for p in procs:
        p.join()
    errors = [r for r in rows if "error" in r]
    if errors:
        for r in errors:
            print(f"worker {r['rank']}: {r['error']}", file=sys.stderr)
        return 1
    rows.sort(key=lambda r: r["rank"])
    load_after = os.getloadavg() if hasattr(os, "getloadavg") else None

    import mujoco
    import numpy as np
    import osqp

    from tests.support import cassie_cpu_reference as cr
    from hlip_jax.plants.cassie import control

    ticks = sum(r["ticks"] for r in rows)
    wall = max(r["t_end"] for r in rows) - min(r["t_start"] for r in rows)
    agg = ticks / wall
    r0 = rows[0]
    per_tick = np.asarray(r0["prof_s"]) / r0["ticks"] * 1e6
    tick_us = r0["wall_s"] / r0["ticks"] * 1e6
    split = {name: float(v) for name, v in zip(cr.STAGES, per_tick)}
    split["other (loop, logging, timers)"] = float(tick_us - per_tick.sum())
    summary = dict(
        benchmark="cassie_cpu_reference", procs=args.procs, seconds=args.seconds,
        substeps=control.SUBSTEPS, control_dt_s=control.CONTROL_DT, pinned=args.pin,
        cpu_count=os.cpu_count(), platform=platform.platform(), python=platform.python_version(),
        numpy=np.__version__, mujoco=mujoco.__version__, osqp=osqp.__version__,
        loadavg_before=load_before, loadavg_after=load_after,
        aggregate_ticks_per_s=agg, aggregate_physics_steps_per_s=control.SUBSTEPS * agg,
        aggregate_realtime_factor=agg * control.CONTROL_DT,
        per_process_ticks_per_s=[r["ticks_per_s"] for r in rows],
        tick_us_process0=tick_us, tick_split_us_process0=split,
        compiled_floor_us_process0=r0["compiled_floor_us"],
        all_upright=all(r["upright"] for r in rows),
        jax_backend_initialised_in_any_worker=any(r["jax_backend_initialised"] for r in rows),
        workers=rows)
    with open(args.out, "w") as fh:
        json.dump(summary, fh, indent=1)

    print(f"{args.procs} process(es) × 1 robot × {args.seconds} s standing "
          f"(C MuJoCo {mujoco.__version__} + OSQP {osqp.__version__}, {os.cpu_count()} cores; "
          f"load average before {load_before[0] if load_before else float('nan'):.2f})")
    print(f"aggregate: {agg:,.0f} control ticks/s, {control.SUBSTEPS * agg:,.0f} physics steps/s "
          f"({agg * control.CONTROL_DT:.2f} robot-s per s)")
    for r in rows:
        print(f"  process {r['rank']}: {r['ticks_per_s']:,.0f} ticks/s, COM z error at end "
              f"{r['com_z_err_final_m'] * 1e3:.2f} mm, upright {r['upright']}, OSQP iterations "
              f"mean {r['osqp_iterations_mean']:.1f} max {r['osqp_iterations_max']}, "
              f"status {r['osqp_status']}")
    print(f"per-tick split (process 0, {tick_us:.0f} µs/tick):")
    print("| stage | µs/tick | share |")
    print("|---|---:|---:|")
    for name, v in split.items():
        print(f"| {name} | {v:.1f} | {100 * v / tick_us:.1f} % |")
    fl = r0["compiled_floor_us"]
    print(f"compiled code only (process 0, call groups timed in isolation): {fl['total']:.0f} µs/tick "
          f"→ {1e6 / fl['total']:,.0f} ticks/s per core for a compiled implementation at best; "
          + ", ".join(f"{k} {v:.1f}" for k, v in fl.items() if k != "total"))
    print(f"JAX backend initialised in a worker: {summary['jax_backend_initialised_in_any_worker']}"
          f"; wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
