"""Where a Cassie control tick's time goes: each stage of the tick timed alone, vmapped over a
batch of standing robots, on whatever device JAX uses.

Stages (the CLF-QP tick of :mod:`hlip_jax.plants.cassie.control`, the walking tick's core):

    terms      model.robot_terms: smooth (kinematics, COM, composite inertias), mass matrix,
               bias and passive forces, COM / site / loop / angular Jacobians and J̇q̇
    condense   dynamics.condense: the constrained dynamics' affine maps τ ↦ (q̈, λ)
    qp_build   clfqp.build: outputs, CLF rows, friction rows, the QP's matrices
    admm       qp.solve of that QP (the standing controller's ADMM settings), warm-started
               from the previous tick's solution and cold, with the linear system solved by
               the Cholesky factor in every iteration or by its inverse formed once per
               factorisation (``qp.Settings.linsys``, ``impl.qp_linsys``)
    physics    control.physics: the two MJX steps of a tick (MJX-JAX)
    physics (warp)  the same two steps on MJX's Warp implementation (where warp-lang is installed)
    tick       all of the above in one program (terms → condense → build → solve → physics);
               "tick (inverse)" with the inverse linear solve, "tick (inverse, warp)" with it
               and the Warp physics

``--terms`` and ``--condense`` choose how every stage computes the whole-body terms
(``impl.terms``: mjx, dense) and the constraint forces (``impl.condense``: eigen, deflated).

Each stage is one jitted, vmapped program over ``B`` robots at the same state (the stand
keyframe after 0.2 s of standing, all four contact sites closed), timed as the best of
``--repeats`` runs of ``--ticks`` calls in a ``lax.scan`` (so per-call dispatch is not
counted; each call's input depends on the previous call's output, so nothing is hoisted out
of the loop), after a compile.  The stage times do not sum exactly to the tick: XLA fuses across
stage boundaries inside one program.

    python benchmarks/tick_profile.py --batch 6 32 --ticks 50
"""

from __future__ import annotations

import argparse
import sys
import time

import jax
import jax.numpy as jnp

from hlip_jax.core import qp
from hlip_jax.plants.cassie import clfqp, control, dynamics, model, outputs, warp_physics


def _state(c, B: int):
    """(data batch (B,), warm start batch, desired outputs) after 0.2 s of standing."""
    d0 = jax.tree.map(lambda a: a[0], model.make_batch(c, 1, jax.random.PRNGKey(0)))
    d0 = control.canonical(c, d0)
    com = model.com_position(c, model.smooth(c, d0))
    target = jnp.concatenate([com, jnp.zeros(1, com.dtype)])
    d, warm, _ = jax.jit(lambda d: control.stand_rollout(c, d, target, 200))(d0)
    des = outputs.stand_desired(target[2], target[:2], target[3], com.dtype)
    tile = lambda t: jax.tree.map(lambda a: jnp.broadcast_to(a, (B,) + jnp.shape(a)), t)
    return tile(d), tile(warm), des


def _stages(c, des, robots: int, terms: str = "mjx", solve: str = "eigen"):
    """name → per-robot function of (d, warm) returning arrays (the stage's output), with the
    whole-body terms ``terms`` and the condensation's solve ``solve``."""
    dt = jnp.float32 if not jax.config.jax_enable_x64 else jnp.float64
    contact = jnp.ones(4, dt)
    lo, hi = (jnp.asarray(c.ctrl_range[:, i], dt) for i in (0, 1))
    gains, st = control.STAND_GAINS, clfqp.DEFAULT_SETTINGS
    springs = dynamics.spring_dofs(c)

    def parts(d):
        rt = model.robot_terms(c, d, terms=terms)
        meas = outputs.measure(rt, d.qvel, c.index.root_dof)
        cond = dynamics.condense(rt, c.actuation, contact, springs, solve=solve)
        return rt, meas, cond

    def prob(d):
        _, meas, cond = parts(d)
        return clfqp.build(meas, des, cond, contact, lo, hi, gains)

    def admm(d, warm, cold, linsys="cholesky"):
        p = prob(d)
        w = jax.tree.map(jnp.zeros_like, warm) if cold else warm
        return qp.solve(p.P, p.q, p.A, p.l, p.u, settings=st._replace(linsys=linsys),
                        warm_start=w[:2]).x

    def tick(d, warm, linsys="cholesky", backend="jax"):
        res, _, _ = control.control(c, d, des, contact, lo, hi, gains, warm,
                                    st._replace(linsys=linsys), terms, solve)
        mx = warp_physics.base_model(c.mj_model) if backend == "warp" else None
        return control.physics(c, d, res.tau, jnp.zeros(3, dt), mx=mx, backend=backend,
                               robots=robots).qpos

    zero = jnp.zeros(c.index.nu, dt)
    return {
        "terms": lambda d, w: model.robot_terms(c, d, terms=terms).M,
        "condense": lambda d, w: parts(d)[2].qdd_tau,
        "qp_build": lambda d, w: prob(d).P,
        "admm (warm)": lambda d, w: admm(d, w, False),
        "admm (cold)": lambda d, w: admm(d, w, True),
        "admm (warm, inverse)": lambda d, w: admm(d, w, False, "inverse"),
        "admm (cold, inverse)": lambda d, w: admm(d, w, True, "inverse"),
        "physics": lambda d, w: control.physics(c, d, zero, jnp.zeros(3, dt)).qpos,
        "physics (warp)": lambda d, w: control.physics(
            c, d, zero, jnp.zeros(3, dt), mx=warp_physics.base_model(c.mj_model), backend="warp",
            robots=robots).qpos,
        "tick": tick,
        "tick (inverse)": lambda d, w: tick(d, w, "inverse"),
        "tick (inverse, warp)": lambda d, w: tick(d, w, "inverse", "warp"),
    }


def _time(fn, d, warm, ticks: int, repeats: int) -> tuple[float, float]:
    """(compile + first run [s], best per-call time [s]) of ``ticks`` calls of the vmapped
    ``fn`` in one scan; each call sees the same state up to a 1e-9 change of the positions and velocities
    that depends on the previous call's output."""
    batched = jax.vmap(fn)

    def run(d, warm):
        def body(acc, _):
            # the state depends on the previous call's output, so XLA cannot hoist the stage
            # out of the loop (a loop-invariant body would be computed once)
            eps = 1e-9 * jnp.tanh(acc)
            dk = d.replace(qpos=d.qpos + eps, qvel=d.qvel + eps)
            return acc + jnp.sum(batched(dk, warm)), None
        return jax.lax.scan(body, jnp.zeros((), d.qpos.dtype), None, length=ticks)[0]

    f = jax.jit(run)
    t0 = time.perf_counter()
    jax.block_until_ready(f(d, warm))
    first = time.perf_counter() - t0
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(f(d, warm))
        best = min(best, time.perf_counter() - t0)
    return first, best / ticks


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, nargs="+", default=[6])
    ap.add_argument("--ticks", type=int, default=50, help="calls per timed run")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--stages", nargs="+", default=None, help="only these stages")
    ap.add_argument("--terms", default="mjx", choices=model.TERMS,
                    help="whole-body terms of every stage (impl.terms)")
    ap.add_argument("--condense", default="eigen", choices=dynamics.SOLVES,
                    help="the condensation's solve in every stage (impl.condense)")
    args = ap.parse_args(argv)
    c = control.load()
    dev = jax.devices()[0]
    print(f"backend {jax.default_backend()}, device {dev.device_kind}, jax {jax.__version__}, "
          f"{'float64' if jax.config.jax_enable_x64 else 'float32'}, terms {args.terms}, "
          f"condensation {args.condense}")
    print("| batch | stage | compile + first [s] | per call [ms] | share of the tick |")
    print("|---:|---|---:|---:|---:|")
    for B in args.batch:
        d, warm, des = _state(c, B)
        stages = _stages(c, des, B, args.terms, args.condense)
        names = args.stages or list(stages)
        if not warp_physics.available() and any("warp" in n for n in names):
            print("skipping the Warp stages: warp-lang is not installed", file=sys.stderr)
            names = [n for n in names if "warp" not in n]
        unknown = sorted(set(names) - set(stages))
        if unknown:
            ap.error(f"--stages: unknown {unknown}; allowed: {list(stages)}")
        # the first whole tick named is timed first: the other rows' share is of it, and each
        # row prints as soon as it is timed
        whole = None
        for n in sorted(names, key=lambda n: not n.startswith("tick")):
            first, per = _time(stages[n], d, warm, args.ticks, args.repeats)
            whole = per if whole is None and n.startswith("tick") else whole
            share = "–" if whole is None else f"{per / whole:.2f}"
            print(f"| {B} | {n} | {first:.1f} | {per * 1e3:.3f} | {share} |", flush=True)


if __name__ == "__main__":
    main()
