"""Physics-only throughput of the Cassie model: MJX (vmapped ``mjx.step``) and C MuJoCo.

Every robot starts at the ``stand`` keyframe with small random joint velocities and zero motor
torque; one call runs ``--steps`` physics steps as a ``lax.scan`` inside ``jit(vmap(...))``.
Reported: robot-steps per second (batch × steps / wall time of one call, best of
``--repeats`` after a warm-up call), compile time, and the largest closed-chain violation at
the end as a sanity check of the solver settings.

    python benchmarks/cassie_physics_bench.py                       # CPU: batches 8 32
    python benchmarks/cassie_physics_bench.py --device gpu --batch 1024 4096 16384 32768

On CPU, batches above 48 are refused unless ``--force``: a vmapped MJX step has hung at
batch ≥ 64 on a 2-core machine with jax 0.10.2.
"""

from __future__ import annotations

import argparse
import os
import sys
import time


def _parse(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", choices=("cpu", "gpu"), default="cpu")
    p.add_argument("--batch", type=int, nargs="+", default=None,
                   help="batch sizes (default: 8 32 on cpu, 1024 4096 16384 32768 on gpu)")
    p.add_argument("--steps", type=int, default=None,
                   help="physics steps per timed call (default 20 on cpu, 200 on gpu)")
    p.add_argument("--repeats", type=int, default=3, help="timed calls per batch size (best is kept)")
    p.add_argument("--iterations", type=int, default=None, help="override solver iterations")
    p.add_argument("--ls-iterations", type=int, default=None, help="override line-search iterations")
    p.add_argument("--no-eulerdamp", action="store_true",
                   help="disable implicit joint damping in the Euler step (saves one factorization)")
    p.add_argument("--c-steps", type=int, default=4000, help="C MuJoCo reference steps (0: skip)")
    p.add_argument("--float64", action="store_true", help="run MJX in float64")
    p.add_argument("--matmul-precision", choices=("default", "high", "highest"), default="highest",
                   help="jax default matmul precision (default highest: no TF32 in the solver)")
    p.add_argument("--force", action="store_true", help="allow CPU batches above 48")
    p.add_argument("--cache-dir", default=None, help="persistent XLA compilation cache directory")
    a = p.parse_args(argv)
    if a.batch is None:
        a.batch = [8, 32] if a.device == "cpu" else [1024, 4096, 16384, 32768]
    if a.steps is None:
        a.steps = 20 if a.device == "cpu" else 200
    for b in a.batch:
        if b < 1:
            p.error(f"--batch: sizes must be ≥ 1, got {b}")
        if a.device == "cpu" and b > 48 and not a.force:
            p.error(f"--batch: {b} > 48 on cpu (vmapped MJX steps have hung at ≥ 64); pass --force")
    if a.steps < 1 or a.repeats < 1 or a.c_steps < 0:
        p.error("--steps and --repeats must be ≥ 1, --c-steps ≥ 0")
    if a.iterations is not None and a.iterations < 1:
        p.error(f"--iterations: must be ≥ 1, got {a.iterations}")
    return a


def _setup_env(a):
    # must happen before jax is imported
    os.environ["JAX_PLATFORMS"] = "cpu" if a.device == "cpu" else "cuda"
    if a.device == "gpu":
        os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
        flags = os.environ.get("XLA_FLAGS", "")
        if "triton_gemm_any" not in flags:
            os.environ["XLA_FLAGS"] = (flags + " --xla_gpu_triton_gemm_any=true").strip()


def c_mujoco_steps_per_s(m, key_id, n):
    """Single-thread C MuJoCo ``mj_step`` rate from the stand keyframe."""
    import mujoco
    import numpy as np

    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, key_id)
    d.qvel[:] = np.random.default_rng(0).uniform(-0.1, 0.1, m.nv)
    mujoco.mj_step(m, d)
    t = time.perf_counter()
    for _ in range(n):
        mujoco.mj_step(m, d)
    return n / (time.perf_counter() - t)


def main(argv=None):
    a = _parse(argv)
    _setup_env(a)
    import jax

    if a.float64:
        jax.config.update("jax_enable_x64", True)
    jax.config.update("jax_default_matmul_precision", a.matmul_precision)
    if a.cache_dir:
        jax.config.update("jax_compilation_cache_dir", a.cache_dir)
    import jax.numpy as jnp
    import mujoco
    import numpy as np
    from mujoco import mjx

    from hlip_jax.plants.cassie import model as cm

    cassie = cm.load()
    m = cassie.mj_model
    if a.iterations is not None:
        m.opt.iterations = a.iterations
    if a.ls_iterations is not None:
        m.opt.ls_iterations = a.ls_iterations
    if a.no_eulerdamp:
        m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP)
    mx = mjx.put_model(m, impl="jax")
    nsteps = a.steps

    def rollout(d):
        def body(d, _):
            return mjx.step(mx, d), None
        d, _ = jax.lax.scan(body, d, None, length=nsteps)
        return d

    def chain_violation(d):
        d = mjx.kinematics(mx, d)
        return jnp.abs(cm.loop_residual(cassie, d)).max()

    run = jax.jit(jax.vmap(rollout))
    viol = jax.jit(jax.vmap(chain_violation))

    rows = []
    dev = jax.devices()[0]
    for b in a.batch:
        data = cm.make_batch(cassie, b, jax.random.PRNGKey(0), qvel_noise=0.1, forward=False)
        t0 = time.perf_counter()
        out = run(data)
        out.qpos.block_until_ready()
        t_compile = time.perf_counter() - t0
        best = float("inf")
        for _ in range(a.repeats):
            t0 = time.perf_counter()
            out = run(out)
            out.qpos.block_until_ready()
            best = min(best, time.perf_counter() - t0)
        finite = bool(np.all(np.isfinite(np.asarray(out.qpos))))
        v = float(np.max(np.asarray(viol(out))))
        sps = b * nsteps / best
        rows.append((b, t_compile, best, sps, sps * m.opt.timestep, v, finite))
        print(f"batch {b}: {sps:,.0f} steps/s (compile {t_compile:.1f} s)", file=sys.stderr, flush=True)

    c_sps = c_mujoco_steps_per_s(m, cassie.index.stand_key, a.c_steps) if a.c_steps else None

    print(f"\nCassie physics only — {dev.platform} ({dev.device_kind}), dtype "
          f"{'float64' if a.float64 else 'float32'}, matmul precision {a.matmul_precision}, timestep {m.opt.timestep} s, "
          f"solver Newton iterations={m.opt.iterations} ls_iterations={m.opt.ls_iterations}, "
          f"eulerdamp {'off' if a.no_eulerdamp else 'on'}, "
          f"{nsteps} steps per call, best of {a.repeats}\n")
    print("| engine | batch | compile [s] | s / call | robot-steps/s | × real time | max chain gap [m] | finite |")
    print("|---|---:|---:|---:|---:|---:|---:|---|")
    for b, tc, t, sps, rt, v, fin in rows:
        print(f"| MJX (jax) | {b} | {tc:.1f} | {t:.4f} | {sps:,.0f} | {rt:,.1f} | {v:.2e} | {fin} |")
    if c_sps is not None:
        print(f"| C MuJoCo, 1 thread | 1 | – | – | {c_sps:,.0f} | {c_sps * m.opt.timestep:,.1f} | – | – |")


if __name__ == "__main__":
    main()
