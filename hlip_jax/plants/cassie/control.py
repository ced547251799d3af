"""One control tick of Cassie on MJX: measure → condense → CLF-QP → physics substeps.

Control runs at 1 kHz on 2 kHz physics (``SUBSTEPS = 2`` MJX steps per tick, the model's
timestep 0.5 ms).  Also the standing controller and a batched standing simulation
(:func:`stand_rollout`), used by the tests and as the settle phase of the walking plant.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from hlip_jax.plants.cassie.mjx_import import mjx
from hlip_jax.plants.cassie import clfqp, dynamics, model, outputs

SUBSTEPS = 2
CONTROL_DT = 0.001  # [s]
#: viscous damping [N m s/rad] given to the four leaf-spring dofs of the simulated robot.
#: The MJCF's heel springs have none and the shin springs 0.1: undamped, their ≈ 10 Hz mode
#: (excited by every touchdown) is never dissipated, the rigid-spring controller keeps
#: feeding it and the feet skitter across the floor within a second of standing.
SPRING_DAMPING = 10.0


def load(spring_damping: float = SPRING_DAMPING) -> model.Cassie:
    """The Cassie model of :func:`model.load` with ``spring_damping`` on the leaf springs."""
    if not spring_damping >= 0:
        raise ValueError(f"spring_damping must be ≥ 0 N m s/rad, got {spring_damping}")
    c = model.load()
    m = c.mj_model
    for j in dynamics.spring_dofs(c):
        m.dof_damping[j] = spring_damping
    return dataclasses.replace(c, mj_model=m, mjx_model=model.put(m, c.mjx_model.impl))

# standing: orientation ω = 8 rad/s, COM height 8, COM xy 4 (well below the ≈ 24 rad/s
# spring-mass mode of the legs, which the rigid-spring controller model does not see)
STAND_OMEGA = np.array([8.0, 8.0, 8.0, 8.0, 4.0, 4.0] + [10.0] * 10)
STAND_GAINS = clfqp.make_gains(STAND_OMEGA)


def canonical(cassie: model.Cassie, d: mjx.Data, mx=None) -> mjx.Data:
    """``mjx.forward`` once (on ``mx``, default the robot's own model), so every field has the
    dtype ``mjx.step`` produces (under x64 ``put_data`` leaves some contact index fields int32
    while ``step`` returns int64)."""
    return mjx.forward(cassie.mjx_model if mx is None else mx, d)


def control(cassie: model.Cassie, d: mjx.Data, des: outputs.Desired, contact, tau_min, tau_max,
            gains: clfqp.Gains, warm, settings=clfqp.DEFAULT_SETTINGS, terms: str = "mjx",
            solve: str = "eigen"):
    """CLF-QP torques at the state of ``d`` (its qpos, qvel); ``terms`` (static) as in
    :func:`model.robot_terms`, ``solve`` (static) the condensation's (:func:`dynamics.condense`).
    Returns (clfqp.Result, outputs.Measured, model.RobotTerms)."""
    terms = model.robot_terms(cassie, d, terms=terms)
    meas = outputs.measure(terms, d.qvel, cassie.index.root_dof)
    cond = dynamics.condense(terms, cassie.actuation, contact, dynamics.spring_dofs(cassie),
                             solve=solve)
    res = clfqp.solve(meas, des, cond, contact, tau_min, tau_max, gains, warm, settings)
    return res, meas, terms


def physics(cassie: model.Cassie, d: mjx.Data, ctrl, force, mx=None, backend: str = "jax",
            robots: int = 1) -> mjx.Data:
    """``SUBSTEPS`` MJX steps with motor torques ``ctrl`` (nu,) and a world force ``force``
    (3,) [N] on the pelvis COM (``xfrc_applied``); ``mx`` replaces ``cassie.mjx_model``.
    ``backend`` (static): "jax" steps MJX-JAX; "warp" steps MJX's Warp implementation with
    ``mx`` a Warp model (:mod:`hlip_jax.plants.cassie.warp_physics`), ``d`` staying MJX-JAX
    data, for ``robots`` robots stepped together (static: the vmapped batch size)."""
    mx = cassie.mjx_model if mx is None else mx
    xfrc = jnp.zeros_like(d.xfrc_applied).at[cassie.index.pelvis_body, :3].set(force)
    d = d.replace(ctrl=ctrl, xfrc_applied=xfrc)
    if backend == "warp":
        from hlip_jax.plants.cassie import warp_physics
        return warp_physics.step(cassie.mj_model, mx, d, SUBSTEPS, robots)
    # traced once and unrolled when lowered: tracing the MJX step SUBSTEPS times made up a
    # third of the closed loop's tracing (which every run pays, compilation cache or not),
    # while a rolled loop would cost the GPU a loop trip per substep (docs/benchmarks/compile.md)
    return jax.lax.fori_loop(0, SUBSTEPS, lambda _, d: mjx.step(mx, d), d, unroll=True)


def zero_torque_rollout(cassie: model.Cassie, d: mjx.Data, n_ticks: int, mx=None,
                        backend: str = "jax", robots: int = 1) -> mjx.Data:
    """``n_ticks`` control ticks of physics alone (zero motor torque, no push): the
    physics-only reference the benchmarks compare the controlled loops against, stepped by
    ``backend`` ("jax" or "warp" with ``mx`` the Warp model and ``robots`` the vmapped batch
    size, as in :func:`physics`)."""
    ctrl = jnp.zeros(cassie.index.nu, d.qpos.dtype)
    force = jnp.zeros(3, d.qpos.dtype)

    def tick(d, _):
        return physics(cassie, d, ctrl, force, mx, backend, robots), None

    return jax.lax.scan(tick, d, None, length=n_ticks)[0]


def warm_zeros(cassie: model.Cassie, dtype):
    nu = cassie.index.nu
    return (jnp.zeros(clfqp.n_vars(nu), dtype), jnp.zeros(clfqp.n_rows(nu), dtype),
            jnp.asarray(clfqp.DEFAULT_SETTINGS.rho, dtype))


class StandLog(NamedTuple):
    com: jax.Array          # (T, 3)
    pelvis_z: jax.Array     # (T,)
    rpy: jax.Array          # (T, 3)
    tau: jax.Array          # (T, nu)
    V: jax.Array
    status: jax.Array


def stand_rollout(cassie: model.Cassie, d0: mjx.Data, target, n_ticks: int,
                  push=None, warm=None, t0=0.0, gains: clfqp.Gains = STAND_GAINS,
                  settings=clfqp.DEFAULT_SETTINGS):
    """Simulate one standing robot for ``n_ticks`` control ticks (vmap over a batch).

    Args:
      d0: data (from :func:`canonical`).
      target: (4,) desired COM x, y, z [m] and heading [rad].
      push: optional (5,) [start s, end s, Fx, Fy, Fz N] pelvis force (times on the clock
        that starts at ``t0``).
      warm: QP warm start (x, y) from a previous call (zeros if None); t0: clock at tick 0 [s].
    Returns (final data, final warm start, StandLog sampled every tick); chain calls to
    simulate long horizons with one compile.
    """
    dt = d0.qpos.dtype
    target = jnp.asarray(target, dt)
    push = jnp.zeros(5, dt) if push is None else jnp.asarray(push, dt)
    des = outputs.stand_desired(target[2], target[:2], target[3], dt)
    contact = jnp.ones(4, dt)
    lo = jnp.asarray(cassie.ctrl_range[:, 0], dt)
    hi = jnp.asarray(cassie.ctrl_range[:, 1], dt)

    def tick(carry, k):
        d, warm = carry
        res, meas, terms = control(cassie, d, des, contact, lo, hi, gains, warm, settings)
        t = t0 + k.astype(dt) * CONTROL_DT
        on = (t >= push[0]) & (t < push[1])
        d = physics(cassie, d, res.tau, jnp.where(on, push[2:], 0.0))
        log = StandLog(com=terms.com, pelvis_z=d.qpos[2],
                       rpy=model.rpy_from_mat(terms.pelvis_R), tau=res.tau, V=jnp.sum(res.V),
                       status=res.status)
        return (d, res.warm), log

    warm = warm_zeros(cassie, dt) if warm is None else warm
    t0 = jnp.asarray(t0, dt)
    (d, warm), log = jax.lax.scan(tick, (d0, warm), jnp.arange(n_ticks))
    return d, warm, log
