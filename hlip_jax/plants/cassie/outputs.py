"""Controlled outputs y(q) of Cassie and their desired trajectories (standing and walking).

One fixed stack of ``N_OUT = 16`` outputs is measured at every tick; a 0/1 ``mask`` selects the
rows a mode controls (shapes stay static under jit / vmap):

    row  0..2   pelvis orientation error, world rotation vector of R R_dᵀ [rad]
    row  3      COM height z [m] (flat ground at z = 0: the stance "leg length" of the H-LIP)
    row  4..5   COM x, y [m]                                 (standing only)
    row  6..8   left foot centre x, y, z [m] (mid-point of toe and heel sphere centres,
                z measured to the sphere bottoms, so 0 = on the ground)
    row  9..11  right foot centre x, y, z [m]
    row 12, 13  left / right sole slope: toe z − heel z [m]  (0 = flat)
    row 14, 15  left / right foot yaw, heading of heel → toe [rad]

For each row ``ẏ = J q̇`` and ``ÿ = J q̈ + J̇q̇`` (world frame; for the orientation rows ẏ is the
pelvis angular velocity ω and ÿ = R ω̇_body).  Walking trajectories are functions of the phase
time (see :func:`swing_profile`), with analytic time derivatives by forward-mode autodiff.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from hlip_jax.plants.cassie import model

N_OUT = 16
ROT, COM_Z, COM_XY = slice(0, 3), 3, slice(4, 6)
FOOT_POS = (slice(6, 9), slice(9, 12))
FOOT_SLOPE = (12, 13)
FOOT_YAW = (14, 15)
#: output groups of the CLF (:mod:`clfqp`): pelvis orientation, COM (height; x, y standing),
#: foot position and sole slope, foot yaw — each with its own Lyapunov function and rate
GROUPS = (slice(0, 3), slice(3, 6), slice(6, 14), slice(14, 16))


class Measured(NamedTuple):
    """Outputs at the current state (rows as in the module doc)."""
    y: jax.Array        # (16,) rows 0..2 are unused (orientation is kept as R)
    ydot: jax.Array     # (16,)
    J: jax.Array        # (16, nv)
    jdqd: jax.Array     # (16,)
    R: jax.Array        # (3, 3) pelvis rotation


class Desired(NamedTuple):
    """Desired outputs: y_d, ẏ_d, ÿ_d (16,) each, R_d (3, 3) for the pelvis, mask (16,)."""
    y: jax.Array
    ydot: jax.Array
    yddot: jax.Array
    R: jax.Array
    mask: jax.Array


def foot_centres(terms: model.RobotTerms) -> jax.Array:
    """(2, 3) left / right foot centre [m]: toe/heel mid-point, z at the sphere bottom."""
    sp = terms.site_pos.reshape(2, 2, 3).mean(axis=1)
    return sp.at[:, 2].add(-model.FOOT_SPHERE_RADIUS)


def measure(terms: model.RobotTerms, qvel: jax.Array, root_dof: int = 0) -> Measured:
    """All 16 outputs with velocities ẏ = J q̇ for the given ``qvel`` (nv,)."""
    nv = terms.M.shape[0]
    dt = terms.M.dtype
    R = terms.pelvis_R
    J_rot = jnp.zeros((3, nv), dt).at[:, root_dof + 3: root_dof + 6].set(R)
    Jsite = terms.site_J.reshape(2, 2, 3, nv)
    Asite = terms.site_jdqd.reshape(2, 2, 3)
    J_foot = Jsite.mean(axis=1)
    a_foot = Asite.mean(axis=1)
    sp = terms.site_pos.reshape(2, 2, 3)
    d = sp[:, 0] - sp[:, 1]
    Jd = Jsite[:, 0] - Jsite[:, 1]
    ad = Asite[:, 0] - Asite[:, 1]
    dd = Jd @ qvel                                          # (2, 3) d-dot
    r2 = d[:, 0] ** 2 + d[:, 1] ** 2
    yaw = jnp.arctan2(d[:, 1], d[:, 0])
    J_yaw = (d[:, 0, None] * Jd[:, 1] - d[:, 1, None] * Jd[:, 0]) / r2[:, None]
    yaw_dot = (d[:, 0] * dd[:, 1] - d[:, 1] * dd[:, 0]) / r2
    a_yaw = ((d[:, 0] * ad[:, 1] - d[:, 1] * ad[:, 0]) / r2
             - 2.0 * yaw_dot * (d[:, 0] * dd[:, 0] + d[:, 1] * dd[:, 1]) / r2)
    feet = foot_centres(terms)
    zero3 = jnp.zeros(3, dt)
    y = jnp.concatenate([zero3, terms.com[2:3], terms.com[:2], feet[0], feet[1],
                         d[:, 2], yaw])
    J = jnp.concatenate([J_rot, terms.com_J[2:3], terms.com_J[:2], J_foot[0], J_foot[1],
                         Jd[:, 2], J_yaw], axis=0)
    jdqd = jnp.concatenate([zero3, terms.com_jdqd[2:3], terms.com_jdqd[:2], a_foot[0],
                            a_foot[1], ad[:, 2], a_yaw])
    ydot = J @ qvel
    return Measured(y=y, ydot=ydot, J=J, jdqd=jdqd, R=R)


def rotation_error(R: jax.Array, R_d: jax.Array) -> jax.Array:
    """World rotation vector e with R = exp([e]×) R_d (small-angle accurate; [rad])."""
    E = R @ R_d.T
    s = 0.5 * jnp.stack([E[2, 1] - E[1, 2], E[0, 2] - E[2, 0], E[1, 0] - E[0, 1]])
    c = 0.5 * (jnp.trace(E) - 1.0)
    ang = jnp.arctan2(jnp.linalg.norm(s), c)
    n = jnp.linalg.norm(s)
    return jnp.where(n > 1e-9, s * ang / jnp.maximum(n, 1e-12), s)


def wrap(a):
    """Angle wrapped to (−π, π]."""
    return jnp.arctan2(jnp.sin(a), jnp.cos(a))


def errors(meas: Measured, des: Desired):
    """(e, ė) (16,) each: output minus desired (orientation: rotation vector; yaw rows wrapped)."""
    e = meas.y - des.y
    e = e.at[ROT].set(rotation_error(meas.R, des.R))
    e = e.at[jnp.array(FOOT_YAW)].set(wrap(e[jnp.array(FOOT_YAW)]))
    edot = meas.ydot - des.ydot
    return e * des.mask, edot * des.mask


def rot_z(yaw):
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    o, z = jnp.ones_like(c), jnp.zeros_like(c)
    return jnp.stack([jnp.stack([c, -s, z]), jnp.stack([s, c, z]), jnp.stack([z, z, o])])


# ----------------------------------------------------------------------------- standing


STAND_MASK = np.array([1, 1, 1, 1, 1, 1] + [0] * 10, dtype=float)


def stand_desired(com_height, com_xy, yaw, dtype=jnp.float64) -> Desired:
    """Standing: pelvis level with heading ``yaw`` [rad], COM at (com_xy, com_height) [m]."""
    y = jnp.zeros(N_OUT, dtype).at[COM_Z].set(com_height).at[COM_XY].set(com_xy)
    z = jnp.zeros(N_OUT, dtype)
    return Desired(y=y, ydot=z, yddot=z, R=rot_z(jnp.asarray(yaw, dtype)),
                   mask=jnp.asarray(STAND_MASK, dtype))


# ----------------------------------------------------------------------------- walking


def smoothstep5(x):
    """Quintic 0 → 1 on x ∈ [0, 1] with zero slope and curvature at both ends; clipped."""
    x = jnp.clip(x, 0.0, 1.0)
    return x ** 3 * (10.0 - 15.0 * x + 6.0 * x ** 2)


def blend(t, t_ssp, reach: float = 0.8):
    """c(t): smooth 0 → 1 over [0, reach·T_SSP], 1 afterwards (t from the start of SSP)."""
    return smoothstep5(t / (reach * t_ssp))


def swing_height(t, t_ssp, clearance, strike):
    """Swing-foot height [m] over SSP: lifts from 0 with zero velocity, peaks at ``clearance``
    at mid-SSP, reaches −``strike`` (slightly below the ground) at T_SSP and keeps descending
    at the final slope after that (a late touchdown keeps reaching for the ground)."""
    s = t / t_ssp
    sc = jnp.clip(s, 0.0, 1.0)
    bump = 64.0 * sc ** 3 * (1.0 - sc) ** 3
    down = sc ** 2 * (3.0 - 2.0 * sc)                        # smoothstep, slope 0 at both ends
    late = jnp.maximum(s - 1.0, 0.0)
    return clearance * bump - strike * (down + late)


def landing_fraction(clearance, strike, iters: int = 40):
    """Fraction s* of SSP at which :func:`swing_height` comes back to the ground: the root of
    clearance · 64 s³(1 − s)³ = strike · s²(3 − 2s) on s ∈ [½, 1] (the difference is
    clearance − strike/2 > 0 at ½ and −strike ≤ 0 at 1, one crossing after the apex), by
    ``iters`` bisection steps (interval 2⁻⁴¹).  It depends only on strike / clearance; s* = 1
    when strike = 0.  With strike > 0 the swing foot is expected to touch down at s* T_SSP,
    before the H-LIP's T_SSP."""
    h = lambda s: swing_height(s, 1.0, clearance, strike)

    def halve(_, ab):
        a, b = ab
        m = 0.5 * (a + b)
        above = h(m) > 0.0
        return jnp.where(above, m, a), jnp.where(above, b, m)

    one = jnp.ones_like(jnp.asarray(clearance))
    a, b = jax.lax.fori_loop(0, iters, halve, (0.5 * one, one))
    return 0.5 * (a + b)


def with_derivatives(f, t):
    """(f(t), f'(t), f''(t)) of a scalar function of time by nested forward-mode AD."""
    df = lambda s: jax.jvp(f, (s,), (jnp.ones_like(s),))[1]
    v, d1 = jax.jvp(f, (t,), (jnp.ones_like(t),))
    d2 = jax.jvp(df, (t,), (jnp.ones_like(t),))[1]
    return v, d1, d2
