"""One 1 kHz control tick of the walking Cassie, written as a chain of named stages.

The controller is the underactuated design of Xiong, Reher & Ames: in single support (SSP) the
stance-foot motor is passive (zero torque, an equality of the CLF-QP) and the other nine motors
track nine outputs — pelvis roll, pitch and yaw (the yaw follows the path heading), COM height,
swing-foot x, y, z, swing-foot sole slope (pitch) and swing-foot yaw.  Nothing acts on the
horizontal COM: it is the zero dynamics that only the choice of the next step controls.  In
double support (DSP) both feet rest on the ground with passive foot motors and the outputs are
the pelvis orientation and the COM height (the H-LIP's DSP has p̈ = 0).

A tick is

    gap   = proximity(s)                          feet and leg clearances of the true robot
    dm, s = sense(ctx, s)                         the state as the controller measures it
    terms = measure(ctx, dm)                      whole-body terms at the measured state
    s     = estimate(ctx, s, terms)               the stepping law's COM velocity estimate
    s     = lift_off(ctx, s, terms)               first SSP tick: record the swing foot pose
    cts   = contacts(ctx, s, dm, terms)           contact set and touchdown detection
    u_des = stepping_target(ctx, s, terms)        H-LIP stepping law, step limits
    des   = desired_outputs(ctx, s, terms, cts, u_des)
    res   = clf_qp(ctx, s, dm, terms, cts, des)   torques (passive feet on the ground)
    tau, s = actuate(ctx, s, res.tau)             control rate, latency, motor lag and curve
    d     = physics(ctx, s, tau)                  pushes, step noise, two MJX steps
    s     = advance(ctx, s, cts, u_des, res, d)   phase clock, touchdown → end of step

each a pure function of pytrees (:class:`Context` is constant over one walking step,
:class:`TickState` is the scan carry).  ``sense``, ``estimate`` and ``actuate`` model a
non-ideal robot (:mod:`hlip_jax.plants.cassie.realism`: noise, filters, motors; the physics'
model errors and slope live in ``Context.mx_plant``).  A batch built for the ideal plant has
no realism data (``Context.real`` is None, a static property of the batch's pytree): those
stages are then the identity and are not compiled at all, so the ideal program is the
plain controller.  Phases: DSP for ``T_DSP``; SSP until the swing foot's
touchdown is *detected* — one of its contact spheres within ``CONTACT_GAP`` of the ground for
``TOUCHDOWN_TICKS`` consecutive ticks, no earlier than ``early_contact · T_SSP`` (early
touchdown) — or until ``LATE_SSP`` times the swing profile's duration (a late foot keeps
reaching down; it joins the contact set in the next DSP when it touches); then the step is
done and the remaining ticks of the static budget are idle.  The swing profile is stretched
(:func:`swing_duration`) so that the foot comes back to the ground at T_SSP: the robot steps
with the H-LIP's period.

Stepping law (every SSP tick): with x_R = [c, p, v] per world plane, p the COM relative to the
stance foot's **ankle pivot** (the passive foot's centre of pressure sits under its joint) and
x_H(t) the H-LIP at the same SSP time, the error is carried to SSP⁻ by the LIP flow of the rest
of the SSP and

    u_des = u_H,k+1 + K · flow(x_R − x_H, T_SSP − t),

clipped to the gait's step length and width (in the heading frame) and held from
``freeze · T_SSP`` on.  The swing foot's centre is steered from its lift-off position to the
stance ankle + u_des + (its own centre − ankle offset), so its ankle lands on the step.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from hlip_jax.plants.cassie.mjx_import import mjx
from hlip_jax.core import hlip
from hlip_jax.plants.base import StepCommand, clip_step
from hlip_jax.plants.cassie import clfqp, collisions, control, dynamics, model, outputs, realism

CONTACT_GAP = 0.004       # [m] sphere bottom this close to the floor counts as touching
TOUCHDOWN_TICKS = 3       # consecutive touching ticks that detect a touchdown (bounce filter)
LATE_SSP = 1.2            # longest SSP waiting for touchdown, in units of the swing duration
DSP, SSP, DONE = 0, 1, 2  # phases of one walking step
COM_HEIGHT = (0.65, 0.9)  # [m] allowed COM height targets (z0 is clipped to it)
FALL_HEIGHT = 0.55        # [m] pelvis height below which the robot has fallen
FALL_TILT = 0.7           # [rad] pelvis roll or pitch beyond which it has fallen
_SIDE_OF_SITE = np.array([0, 0, 1, 1])


class Context(NamedTuple):
    """What stays fixed over one walking step SSP⁻_k → SSP⁻_{k+1}."""
    cmd: StepCommand         # the closed loop's command (float fields in the state's dtype)
    gait: object             # plant.Gait of the scenario
    mx: mjx.Model            # the controller's MJX model (the scenario's leaf-spring damping)
    mx_plant: mjx.Model      # the physics' model (mx with the scenario's model errors, slope)
    mx_physics: mjx.Model    # mx_plant in the implementation that steps the physics (MJX-JAX,
                             # or its Warp twin: :mod:`warp_physics`)
    real: realism.Realism | None  # the scenario's departures from the ideal plant (None: an
                                  # ideal batch, nothing compiled)
    terrain: object               # terrain.Terrain of the scenario's ground step (None: a batch
                                  # on flat ground)
    new_st: jax.Array        # stance foot of the coming SSP (0 left, 1 right)
    sw: jax.Array            # foot that swings in the coming SSP
    yaw_from: jax.Array      # pelvis heading target at SSP⁻_k [rad]
    dyaw: jax.Array          # heading change over the step [rad]
    land_xy: jax.Array       # (2,) where the landing foot's centre was aimed [m]
    f_noise: jax.Array       # (2,) step-noise force on the pelvis [N]
    du_err: jax.Array        # (2,) landing-target error [m]
    t0: jax.Array            # plant clock at SSP⁻_k [s]
    push_start: jax.Array    # (P,) [s]
    push_end: jax.Array      # (P,) [s]
    push_force: jax.Array    # (P, 2) [N]
    tau_lo: jax.Array        # (nu,) motor torque limits [N m]
    tau_hi: jax.Array


class Settings(NamedTuple):
    """Static settings of the tick (hashable; a change recompiles): the CLF-QP's ADMM
    settings, whether the robots' QPs are solved with straggler compaction across the vmapped
    batch (:func:`hlip_jax.core.qp.solve`'s ``compact``), the implementation that steps the
    physics, "jax" (MJX-JAX) or "warp" (MJX's Warp implementation, :mod:`warp_physics`), and
    the number of robots stepped together in one vmapped batch (Warp sizes its contact buffer
    for all of them at once), how the condensation solves for the constraint forces
    (:data:`dynamics.SOLVES`, ``impl.condense``) and how the whole-body terms are computed
    (:data:`model.TERMS`, ``impl.terms``)."""
    qp: object = clfqp.DEFAULT_SETTINGS
    qp_compact: bool = False
    physics: str = "jax"
    robots: int = 1
    condense: str = "eigen"
    terms: str = "mjx"


class TickState(NamedTuple):
    """The scan carry of one walking step."""
    d: mjx.Data
    warm: tuple              # CLF-QP warm start (x, y)
    phase: jax.Array         # DSP, SSP or DONE
    t_phase: jax.Array       # time since the phase began [s]
    t_step: jax.Array        # time since SSP⁻_k [s]
    sw_start: jax.Array      # (3,) swing-foot centre at lift-off [m]
    sw_yaw0: jax.Array       # swing-foot yaw at lift-off [rad]
    sw_offset: jax.Array     # (2,) swing-foot centre minus its ankle at lift-off [m]
    u_last: jax.Array        # (2,) last step target (stance-relative, world) [m]
    touch: jax.Array         # consecutive ticks the swing foot has touched
    fell: jax.Array          # bool
    gap: jax.Array           # (2,) smallest feet and lower-leg clearances so far this step
                             # (:mod:`collisions`; the true robot) [m]
    real: realism.RealState | None  # torque queue, motor lag, velocity estimate, noise key


class Contacts(NamedTuple):
    sites: jax.Array         # (4,) 1.0 = site in the constraint set (CONTACT_SITES order)
    foot: jax.Array          # (2,) bool: the foot has a site in the set (its motor is passive)
    touching: jax.Array      # (4,) bool: sphere within CONTACT_GAP of the ground
    count: jax.Array         # consecutive SSP ticks (this one included) the swing foot touched
    touchdown: jax.Array     # bool: swing-foot touchdown detected this tick


class TickLog(NamedTuple):
    """Per-tick record (leading axis: ticks of the step).  ``com``, ``feet``, ``y_err``,
    ``grf``, ``ydot`` and ``ydd_model`` are what the controller computes from its measurement
    (the truth on an ideal robot); ``pelvis``, ``spring`` and ``tau`` are the simulated
    robot's."""
    com: jax.Array           # (3,) COM [m]
    feet: jax.Array          # (2, 3) foot centres [m]
    tau: jax.Array           # (10,) torques the motors apply [N m, motor side]
    V: jax.Array             # CLF value, summed over the output groups
    contact: jax.Array       # (4,) sites in the constraint set
    status: jax.Array        # CLF-QP status (hlip_jax.core.qp codes)
    iterations: jax.Array    # CLF-QP ADMM iterations of the tick
    pelvis: jax.Array        # (7,) pelvis position [m] and quaternion
    phase: jax.Array         # DSP 0, SSP 1, done 2
    u_des: jax.Array         # (2,) step the swing target aims at (stance-relative, world) [m]
    y_err: jax.Array         # (16,) output errors of the active rows (outputs module order)
    grf: jax.Array           # (4, 3) contact forces at the sites, world frame [N] (QP model)
    spring: jax.Array        # (4,) leaf-spring deflections, shin L, heel L, shin R, heel R [rad]
    gap: jax.Array           # (2,) feet and lower-leg clearances of this tick [m] (collisions)
    ydot: jax.Array          # (16,) output velocities ẏ = J q̇ at the tick's measured state
                             # [m/s, rad/s] (outputs module order; orientation rows: ω)
    ydd_model: jax.Array     # (16,) output accelerations ÿ = J (q̈_τ τ + q̈₀) + J̇q̇ that the
                             # CLF-QP's model (rigid leaf springs, the contact set) predicts for
                             # the applied torques [m/s², rad/s²]; against the measured ÿ
                             # (the time derivative of ``ydot``) it shows the model's mismatch
    qpos: jax.Array          # (nq,) the simulated robot's generalised positions at the tick's
                             # start (MuJoCo qpos: pelvis free joint [m, quaternion], then the
                             # legs' joints [rad]; hlip_jax.presentation.render draws the robot from them)


def robot_state(terms: model.RobotTerms, stance):
    """H-LIP state [c, p, v] per world plane (2, 3) of the robot and the stance ankle (2,):
    p is measured from the stance foot's ankle pivot."""
    st = jnp.where(stance == 0, terms.ankle[0, :2], terms.ankle[1, :2])
    c = terms.com[:2]
    return jnp.stack([c, c - st, terms.com_vel[:2]], axis=-1), st


def hlip_at(cmd: StepCommand, t_in_ssp):
    """H-LIP [c, p, v] per plane (2, 3) at time ``t_in_ssp`` into this step's SSP."""
    c, p, v = cmd.x_hlip[:, 0], cmd.x_hlip[:, 1], cmd.x_hlip[:, 2]
    p_plus = p + v * cmd.t_dsp - cmd.u_hlip
    ps, vs = hlip.ssp_trajectory(p_plus, v, t_in_ssp, cmd.z0)
    return jnp.stack([c + v * cmd.t_dsp + ps - p_plus, ps, vs], axis=-1)


def flow_to_impact(x, tau, z0):
    """[c, p, v] per plane (2, 3) flowed by the LIP for ``tau`` [s] (c moves with p)."""
    p, v = hlip.ssp_trajectory(x[:, 1], x[:, 2], tau, z0)
    return jnp.stack([x[:, 0] + p - x[:, 1], p, v], axis=-1)


def heading_clip(u, heading, sw, gait):
    """Step ``u`` (2,) [m] with its length along ``heading`` clipped to ±step_length_max and its
    width across it to [step_width_min, step_width_max] on the swing side (left: +)."""
    return clip_step(u, heading, sw, gait.step_length_max, gait.step_width_min,
                     gait.step_width_max)


# ----------------------------------------------------------------------------- stages


def sense(ctx: Context, s: TickState):
    """(the data the controller measures, state with the next noise key; an idle tick keeps
    the key)."""
    if ctx.real is None:
        return s.d, s
    dm, real = realism.sense(cassie(), ctx.real, s.real, s.d)
    return dm, s._replace(real=_if_running(s, real, s.real))


def measure(ctx: Context, dm: mjx.Data, terms: str = "mjx") -> model.RobotTerms:
    """Whole-body terms at the measured state (``terms``: :class:`Settings`)."""
    return model.robot_terms(cassie(), dm, ctx.mx, terms)


def estimate(ctx: Context, s: TickState, terms) -> TickState:
    """The stepping law's COM velocity estimate after this tick's measurement."""
    if ctx.real is None:
        return s
    real = realism.estimate_velocity(ctx.real, s.real, terms.com_vel, control.CONTROL_DT)
    return s._replace(real=_if_running(s, real, s.real))


def _if_running(s: TickState, new, old):
    return jax.tree.map(lambda a, b: jnp.where(running(s), a, b), new, old)


def lift_off(ctx: Context, s: TickState, terms) -> TickState:
    """At the first SSP tick record the swing foot's centre, yaw and centre − ankle offset."""
    first = (s.phase == SSP) & (s.t_phase < 0.5 * control.CONTROL_DT)
    feet = outputs.foot_centres(terms)
    i = ctx.sw
    pos = jnp.where(i == 0, feet[0], feet[1])
    yaw = jnp.where(i == 0, terms.foot_yaw[0], terms.foot_yaw[1])
    off = pos[:2] - jnp.where(i == 0, terms.ankle[0, :2], terms.ankle[1, :2])
    return s._replace(sw_start=jnp.where(first, pos, s.sw_start),
                      sw_yaw0=jnp.where(first, yaw, s.sw_yaw0),
                      sw_offset=jnp.where(first, off, s.sw_offset))


def contacts(ctx: Context, s: TickState, dm: mjx.Data, terms) -> Contacts:
    """DSP: every touching site (the new stance foot joins when it touches); SSP: the stance
    foot's sites.  Touchdown: the swing foot has touched for ``TOUCHDOWN_TICKS`` ticks in a
    row (this one included), no earlier than ``early_contact · T_SSP``.  Touching: a sphere
    within ``CONTACT_GAP`` of the ground, or the scenario's spring detector
    (:func:`realism.touching`); with the springs the contact set follows the gait, the way
    hardware controllers use them: both feet in DSP (the landing one was just detected), the
    stance foot in SSP, and the springs decide only the touchdown that ends the SSP."""
    if ctx.real is None:
        touching = terms.site_pos[:, 2] - model.FOOT_SPHERE_RADIUS < CONTACT_GAP
        dsp_set = touching
    else:
        touching = realism.touching(cassie(), ctx.real, s.d, dm, terms.site_pos, CONTACT_GAP,
                                    ctx.terrain)
        dsp_set = touching | (ctx.real.touchdown == realism.TOUCHDOWN.index("spring"))
    in_dsp = s.phase == DSP
    stance_site = _SIDE_OF_SITE == ctx.new_st
    on = jnp.where(in_dsp, dsp_set, stance_site)
    foot = jnp.stack([on[0] | on[1], on[2] | on[3]])
    sw_touch = jnp.any(touching & ~stance_site)
    count = jnp.where(sw_touch, s.touch + 1, 0)
    late_enough = s.t_phase >= ctx.gait.early_contact * ctx.cmd.t_ssp
    touchdown = (s.phase == SSP) & (count >= TOUCHDOWN_TICKS) & late_enough
    return Contacts(sites=on.astype(terms.site_pos.dtype), foot=foot, touching=touching,
                    count=jnp.where(s.phase == SSP, count, 0), touchdown=touchdown)


def stepping_target(ctx: Context, s: TickState, terms) -> jax.Array:
    """The stepping law's step (stance-relative, world) [m] (module doc); held outside the
    SSP's adjustable part."""
    cmd = ctx.cmd
    x_r, _ = robot_state(terms, ctx.new_st)
    if ctx.real is not None:
        x_r = x_r.at[:, 2].set(s.real.v_est[:2])
    ts = jnp.clip(s.t_phase, 0.0, cmd.t_ssp)
    e_imp = flow_to_impact(x_r - hlip_at(cmd, ts), cmd.t_ssp - ts, cmd.z0)
    u = cmd.u_hlip_next + jnp.sum(cmd.gain * e_imp, axis=-1)
    u = heading_clip(u, ctx.yaw_from + ctx.dyaw, ctx.sw, ctx.gait)
    live = (s.phase == SSP) & (s.t_phase < ctx.gait.freeze * cmd.t_ssp)
    return jnp.where(live, u, s.u_last)


def swing_duration(t_ssp, gait):
    """Duration [s] of the swing profile (:func:`outputs.swing_height`, :func:`outputs.blend`)
    that brings the foot back to the ground exactly at the H-LIP's T_SSP: T_SSP / s*, s* the
    profile's landing fraction (:func:`outputs.landing_fraction`; the profile ends ``strike``
    below the ground, so it crosses the ground before its end).  The robot's single support
    then lasts T_SSP, as the H-LIP's does, and the stepping law's SSP⁻ is the real impact."""
    return t_ssp / outputs.landing_fraction(gait.clearance, gait.strike)


def height_reference(ctx: Context, terms) -> jax.Array:
    """Height [m] the COM-height target and the swing profile are measured from: the sole of
    the coming SSP's stance foot (the foot that has just landed, in DSP; ``cassie.
    height_reference = "stance_foot"``, the default) or 0 (the flat ground, "ground")."""
    sole = outputs.foot_centres(terms)[:, 2]
    st = jnp.where(ctx.new_st == 0, sole[0], sole[1])
    return jnp.where(ctx.gait.from_stance > 0.5, st, jnp.zeros_like(st))


def _foot_rows(ctx: Context, s: TickState, terms, u_des, base):
    """Desired (position (3,), velocity (3,), acceleration (3,), yaw, yaw rate) of the moving
    foot: the swing foot in SSP, the landing foot in DSP (it reaches down until it touches);
    heights above ``base`` [m] (:func:`height_reference`)."""
    g = ctx.gait
    t_ssp = swing_duration(ctx.cmd.t_ssp, g)            # the profile's own duration
    in_dsp = s.phase == DSP
    ts = jnp.where(in_dsp, 0.0, s.t_phase)
    cb, cd, cdd = outputs.with_derivatives(lambda t: outputs.blend(t, t_ssp, g.reach), ts)
    st = jnp.where(ctx.new_st == 0, terms.ankle[0, :2], terms.ankle[1, :2])
    target = st + u_des + s.sw_offset + ctx.du_err
    start = s.sw_start[:2]
    h = lambda t: base + outputs.swing_height(t, t_ssp, g.clearance, g.strike)
    hz, hzd, hzdd = outputs.with_derivatives(h, ts)
    lz, lzd, lzdd = outputs.with_derivatives(h, LATE_SSP * t_ssp + s.t_phase)
    swing_p = jnp.concatenate([(1 - cb) * start + cb * target, hz[None]])
    swing_v = jnp.concatenate([cd * (target - start), hzd[None]])
    swing_a = jnp.concatenate([cdd * (target - start), hzdd[None]])
    ez = jnp.array([0.0, 0.0, 1.0], swing_p.dtype)
    pos = jnp.where(in_dsp, jnp.concatenate([ctx.land_xy, lz[None]]), swing_p)
    vel = jnp.where(in_dsp, ez * lzd, swing_v)
    acc = jnp.where(in_dsp, ez * lzdd, swing_a)
    heading = ctx.yaw_from + ctx.dyaw
    yaw = jnp.where(in_dsp, ctx.yaw_from, (1 - cb) * s.sw_yaw0 + cb * heading)
    yaw_d = jnp.where(in_dsp, 0.0, cd * outputs.wrap(heading - s.sw_yaw0))
    return pos, vel, acc, yaw, yaw_d, cb, cd


def desired_outputs(ctx: Context, s: TickState, terms, cts: Contacts, u_des) -> outputs.Desired:
    """Pelvis level with its yaw blended to the heading, COM height z0, and the moving foot's
    position, sole slope 0 and yaw (its rows only while it is off the contact set)."""
    dt = s.d.qpos.dtype
    base = height_reference(ctx, terms)
    pos, vel, acc, yaw, yaw_d, cb, cd = _foot_rows(ctx, s, terms, u_des, base)
    in_ssp = s.phase != DSP
    z0 = jnp.clip(ctx.cmd.z0, *COM_HEIGHT) + base
    y = jnp.zeros(outputs.N_OUT, dt).at[outputs.COM_Z].set(z0)
    yd = jnp.zeros(outputs.N_OUT, dt).at[2].set(jnp.where(in_ssp, cd * ctx.dyaw, 0.0))
    ydd = jnp.zeros(outputs.N_OUT, dt)
    mask = jnp.zeros(outputs.N_OUT, dt).at[:4].set(1.0)
    mover = jnp.where(in_ssp, ctx.sw, ctx.new_st)
    for f in (0, 1):
        on = mover == f
        sl = outputs.FOOT_POS[f]
        y = y.at[sl].set(jnp.where(on, pos, 0.0))
        yd = yd.at[sl].set(jnp.where(on, vel, 0.0))
        ydd = ydd.at[sl].set(jnp.where(on, acc, 0.0))
        y = y.at[outputs.FOOT_YAW[f]].set(jnp.where(on, yaw, 0.0))
        yd = yd.at[outputs.FOOT_YAW[f]].set(jnp.where(on, yaw_d, 0.0))
        rows = np.r_[np.arange(outputs.N_OUT)[sl], outputs.FOOT_SLOPE[f], outputs.FOOT_YAW[f]]
        mask = mask.at[rows].set(jnp.where(on & ~cts.foot[f], 1.0, 0.0))
    yaw_p = ctx.yaw_from + jnp.where(in_ssp, cb, 0.0) * ctx.dyaw
    return outputs.Desired(y=y, ydot=yd, yddot=ydd, R=outputs.rot_z(yaw_p), mask=mask)


def clf_qp(ctx: Context, s: TickState, dm: mjx.Data, terms, cts: Contacts,
           des: outputs.Desired, settings: clfqp.qp.Settings, compact: bool = False,
           condense: str = "eigen"):
    """CLF-QP torques; the foot motor of a foot in the contact set is passive (τ = 0);
    ``compact``: the batch's QPs with straggler compaction, ``condense``: the condensation's
    solve (:class:`Settings`).
    Returns (clfqp.Result, outputs.Measured, dynamics.Condensed)."""
    c = cassie()
    lo, hi = ctx.tau_lo, ctx.tau_hi
    for f in (0, 1):
        motor = c.index.actuators[f][4]
        lo = lo.at[motor].set(jnp.where(cts.foot[f], 0.0, lo[motor]))
        hi = hi.at[motor].set(jnp.where(cts.foot[f], 0.0, hi[motor]))
    meas = outputs.measure(terms, dm.qvel, c.index.root_dof)
    cond = dynamics.condense(terms, c.actuation, cts.sites, dynamics.spring_dofs(c),
                             solve=condense)
    return clfqp.solve(meas, des, cond, cts.sites, lo, hi, ctx.gait.gains, s.warm, settings,
                       fallback=ctx.gait.hold_unsolved > 0.5, active=running(s),
                       compact=compact, rho_previous=ctx.gait.rho_previous > 0.5), meas, cond


def proximity(s: TickState) -> jax.Array:
    """(feet, lower legs) clearances [m] of the true robot (:func:`collisions.gaps`), from the
    physics' last kinematics (the configuration at the start of the previous tick's MJX step,
    one tick old): the simulated legs do not collide, so a clearance below zero is reported,
    not resolved."""
    return collisions.gaps(leg_capsules(), s.d.geom_xpos, s.d.geom_xmat)


def running(s: TickState) -> jax.Array:
    """Whether this tick acts: the step has not ended and the robot has not fallen (the other
    ticks of the static budget leave the state as it is)."""
    return (s.phase != DONE) & ~s.fell


def actuate(ctx: Context, s: TickState, tau):
    """(torques the motors apply (nu,) [N m], state): the CLF-QP's ``tau`` through the
    scenario's control rate, latency, motor lag and torque–speed curve."""
    if ctx.real is None:
        return tau, s
    out, real = realism.actuate(cassie(), ctx.real, s.real, tau, s.d.qvel, running(s),
                                control.CONTROL_DT)
    return out, s._replace(real=real)


def physics(ctx: Context, s: TickState, tau, backend: str = "jax", robots: int = 1) -> mjx.Data:
    """Two MJX steps (``backend``, ``robots``: :class:`Settings` ``physics``, ``robots``) with
    ``tau`` and the pelvis force of the active pushes and step noise."""
    t = ctx.t0 + s.t_step
    on = (t >= ctx.push_start) & (t < ctx.push_end)
    f = jnp.sum(jnp.where(on[:, None], ctx.push_force, 0.0), axis=0) + ctx.f_noise
    return control.physics(cassie(), s.d, tau, jnp.concatenate([f, jnp.zeros(1, f.dtype)]),
                           mx=ctx.mx_physics, backend=backend, robots=robots)


def advance(ctx: Context, s: TickState, cts: Contacts, u_des, res, d_new) -> TickState:
    """Keep the new state while the step runs; DSP → SSP after T_DSP; SSP → done at the
    detected touchdown or at LATE_SSP times the swing duration."""
    dt_c = control.CONTROL_DT
    run = running(s)
    keep = lambda a, b: jnp.where(run, a, b)
    d = jax.tree.map(keep, d_new, s.d)
    warm = jax.tree.map(keep, res.warm, s.warm)
    t_phase = s.t_phase + dt_c
    eps = 0.5 * dt_c
    to_ssp = (s.phase == DSP) & (t_phase >= ctx.cmd.t_dsp - eps)
    late = LATE_SSP * swing_duration(ctx.cmd.t_ssp, ctx.gait)
    to_done = (s.phase == SSP) & (cts.touchdown | (t_phase >= late - eps))
    phase = jnp.where(to_ssp, SSP, jnp.where(to_done, DONE, s.phase))
    return s._replace(
        d=d, warm=warm, phase=jnp.where(run, phase, s.phase).astype(s.phase.dtype),
        t_phase=jnp.where(run, jnp.where(to_ssp, 0.0, t_phase), s.t_phase),
        t_step=jnp.where(run, s.t_step + dt_c, s.t_step),
        u_last=u_des, touch=cts.count,
        fell=s.fell | (run & fell(d)))


def fell(d: mjx.Data) -> jax.Array:
    """Pelvis below ``FALL_HEIGHT``, tilted beyond ``FALL_TILT`` or a non-finite state."""
    R = model.quat_to_mat(d.qpos[3:7] / jnp.linalg.norm(d.qpos[3:7]))
    tilt = jnp.arccos(jnp.clip(R[2, 2], -1.0, 1.0))
    finite = jnp.all(jnp.isfinite(d.qpos)) & jnp.all(jnp.isfinite(d.qvel))
    return (~finite) | (d.qpos[2] < FALL_HEIGHT) | (tilt > FALL_TILT)


def tick(ctx: Context, s: TickState, settings: Settings):
    """One control tick: the stages of the module doc.  Returns (TickState, TickLog)."""
    gap = proximity(s)
    dm, s = sense(ctx, s)
    terms = measure(ctx, dm, settings.terms)
    s = estimate(ctx, s, terms)
    s = lift_off(ctx, s, terms)
    cts = contacts(ctx, s, dm, terms)
    u_des = stepping_target(ctx, s, terms)
    des = desired_outputs(ctx, s, terms, cts, u_des)
    res, meas, cond = clf_qp(ctx, s, dm, terms, cts, des, settings.qp, settings.qp_compact,
                             settings.condense)
    tau, s = actuate(ctx, s, res.tau)
    d_new = physics(ctx, s, tau, settings.physics, settings.robots)
    e, _ = outputs.errors(meas, des)
    c0 = dynamics.N_LOOP_ROWS
    grf = (cond.lam_tau @ res.tau + cond.lam0)[c0:c0 + dynamics.N_CONTACT_ROWS].reshape(4, 3)
    ydd_model = meas.J @ (cond.qdd_tau @ tau + cond.qdd0) + meas.jdqd
    log = TickLog(com=terms.com, feet=outputs.foot_centres(terms), tau=tau, V=jnp.sum(res.V),
                  contact=cts.sites, status=res.status, iterations=res.iterations,
                  pelvis=s.d.qpos[:7], phase=s.phase,
                  u_des=u_des, y_err=e, grf=grf, spring=s.d.qpos[realism.layout(cassie()).spring_qpos],
                  gap=gap, ydot=meas.ydot, ydd_model=ydd_model, qpos=s.d.qpos)
    s = s._replace(gap=jnp.where(running(s), jnp.minimum(s.gap, gap), s.gap))
    return advance(ctx, s, cts, u_des, res, d_new), log


_MODEL = None
_CAPSULES = None


def leg_capsules() -> collisions.Capsules:
    """The lower-leg capsules of the walking robot's model (:func:`collisions.capsules`)."""
    global _CAPSULES
    if _CAPSULES is None:
        _CAPSULES = collisions.capsules(cassie().mj_model)
    return _CAPSULES


def cassie() -> model.Cassie:
    """The walking robot's model, loaded once per process with the MJCF's own leaf-spring
    damping (each scenario sets its own: :class:`Context` ``mx``)."""
    global _MODEL
    if _MODEL is None:
        # the first call may come while a closed loop is being traced: build the MJX model's
        # arrays eagerly, so the cached model holds concrete arrays, not that trace's tracers
        with jax.ensure_compile_time_eval():
            _MODEL = model.load()
    return _MODEL


def scenario_model(damping, base: mjx.Model | None = None) -> mjx.Model:
    """The MJX model (``base``, default the walking robot's MJX-JAX model; its Warp twin for
    the Warp physics) with leaf-spring damping ``damping`` (4,) [N m s/rad] (left shin, left
    heel, right shin, right heel); traced values are fine (one compile per sweep)."""
    c = cassie()
    mx = c.mjx_model if base is None else base
    springs = jnp.array(dynamics.spring_dofs(c))
    return mx.replace(dof_damping=mx.dof_damping.at[springs].set(damping))
