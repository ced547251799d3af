"""The Cassie plant: MJX Cassie walking one step per call under the H-LIP stepping law and a
CLF-QP, behind the step-level interface of :mod:`hlip_jax.plants.base`.

One call of :func:`step` runs SSP⁻_k → SSP⁻_{k+1} as a ``lax.scan`` over 1 kHz control ticks
(2 MJX steps each):

* DSP (``cmd.t_dsp``): both feet on the ground (the foot that lands is added to the contact
  set when it touches, see below), outputs: pelvis orientation, COM height; both foot motors
  passive (the H-LIP's DSP has no horizontal COM force, p̈ = 0).
* SSP (``cmd.t_ssp``) on the new stance foot ``1 − cmd.stance``; the stance foot motor is
  passive (a free pivot in pitch; the flat foot still rests on toe and heel), the other foot
  swings to the step chosen every tick by the stepping law

      u_des(t) = u_H,k+1 + K (x_R(t) − x_H(t)),

  x_R(t) = [c, p, v] per plane of the robot now (p relative to the stance foot) and x_H(t) the
  H-LIP at the same SSP time (flow of ``cmd.x_hlip`` through its DSP and the step u_H,k); the
  error e(t) = x_R(t) − x_H(t) is carried to SSP⁻ by the LIP flow over the rest of the SSP
  (the same linear flow for both, so this is the pre-impact error the law's K is made for).
  Recovery (``gait.recovery_speed`` v_r > 0): with e_v⊥ the pre-impact velocity error across
  the heading, the step's component across the heading blends to the deadbeat law on [p, v],
  u⊥ = (1 − α) (K e)⊥ + α (K_db e)⊥, α = clip(|e_v⊥| / v_r − 1, 0, 1): a soft (LQR) gain
  spreads a push's velocity error over several steps while the LIP lets it grow.
  Outputs (:mod:`outputs`): pelvis roll/pitch 0 and yaw blended to the heading, COM height
  z0, swing foot x, y = (1 − c) x⁺ + c (stance + u_des − ℓ), swing height profile, sole flat
  and swing-foot yaw (1 − c) yaw⁺ + c θ_d.
  Landing lead ℓ (``gait.land_adapt`` = κ > 0; ℓ = 0 otherwise): the swing foot lands ahead of
  its target (it leads its own reference in late swing and touches down early), so the plant
  learns the miss m_k = u_robot,k − (u_des,k − ℓ_k) in the step's heading frame (along, and
  across signed outward for the swing side) and aims the next step at u_des − ℓ with
  ℓ_{k+1} = ℓ_k + κ (m_k − ℓ_k), each component clipped to ±``LEAD_MAX``.  A constant miss L
  gives ℓ → L geometrically (factor 1 − κ per step), so u_robot → u_des.
* Step noise (``disturbance.noise_v``, ``disturbance.step_error``; the PRNG key of the
  state, split once per step): a horizontal pelvis force F = M dv / (T_SSP + T_DSP) held over
  the step, dv uniform in ±noise_v per world axis (M the robot's mass: it changes the COM
  velocity by about dv over the step), and a landing-target offset uniform in ±step_error
  per world axis.  Replicates of a scenario (``seed``) then walk different steps.
* Touchdown is scheduled by time; a site of the landing foot joins the contact set only when
  it is on the ground (≤ 4 mm): an early touchdown in the last quarter of SSP turns that
  foot into a contact at once (its outputs are dropped), a late one keeps the foot reaching
  down (the height target keeps descending) into the DSP until it touches.

The number of ticks per step is static (``Params.ticks`` carries it as a shape); ticks past
T_SSP + T_DSP are idle (the state is held).  ``failed`` is set when the pelvis drops below
``FALL_HEIGHT``, tilts more than ``FALL_TILT`` or the state is not finite.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from hlip_jax import hlip
from hlip_jax.plants.base import StepCommand, StepResult, push_table
from hlip_jax.plants.cassie import clfqp, control, dynamics, model, outputs

FALL_HEIGHT = 0.55        # [m] pelvis height below which the robot has fallen
FALL_TILT = 0.7           # [rad] pelvis roll or pitch beyond which it has fallen
CONTACT_GAP = 0.004       # [m] sphere bottom this close to the floor counts as touching
COM_HEIGHT = (0.65, 0.9)  # [m] allowed COM height targets (z0 is clipped to it)
HURRY_FROM = 0.05         # [m] how far inward of the narrowest width the wanted step must be to hurry
HURRY_SPAN = 0.10         # [m] further inward excess over which the phase rate reaches gait.hurry
LEAD_MAX = 0.05           # [m] largest landing lead the swing target corrects (per component)
#: the gait's tunable parameters and their defaults live in :class:`hlip_jax.config.CassieConfig`
#: and reach the controller as per-scenario data (:class:`Gait`)

_CASSIE = None


def cassie() -> model.Cassie:
    """The plant's model (loaded once per process, leaf springs damped: see control.load)."""
    global _CASSIE
    if _CASSIE is None:
        _CASSIE = control.load()
    return _CASSIE


class Gait(NamedTuple):
    """Per-scenario gait parameters (scalars; see :class:`hlip_jax.config.CassieConfig` for
    meanings and units) and the CLF-QP gains they imply."""
    clearance: jax.Array
    strike: jax.Array
    reach: jax.Array
    freeze: jax.Array
    early_contact: jax.Array
    step_length_max: jax.Array
    step_width_min: jax.Array
    step_width_max: jax.Array
    foot_torque: jax.Array
    assist_ssp: jax.Array
    assist_dsp: jax.Array
    turn_max: jax.Array
    recovery_speed: jax.Array  # [m/s], 0 = off (see step_with_log)
    hurry: jax.Array           # largest swing-phase rate, 1 = off (see step_with_log)
    land_adapt: jax.Array      # landing-lead learning rate, 0 = off (see step_with_log)
    hold_unsolved: jax.Array   # 1.0: an unsolved CLF-QP keeps the previous torques, 0.0: last iterate
    gains: clfqp.Gains


_GAIT_CACHE: dict = {}


def make_gait(cfg=None) -> Gait:
    """:class:`Gait` (numpy) of a :class:`hlip_jax.config.CassieConfig` (defaults if None).

    Output frequencies per row of :mod:`outputs`: pelvis orientation (0..2) ``omega_pelvis``,
    COM height (3) ``omega_height``, COM x, y (4, 5) ``omega_com``, both feet's position and
    sole slope (6..13) ``omega_swing``, foot yaw (14, 15) ``omega_yaw``; QP weights 1 except
    the pelvis rows (``weight_pelvis``) and the COM x, y rows (``weight_com``)."""
    from hlip_jax.config import CassieConfig

    cfg = CassieConfig() if cfg is None else cfg
    if cfg in _GAIT_CACHE:
        return _GAIT_CACHE[cfg]
    omega = np.array([cfg.omega_pelvis] * 3 + [cfg.omega_height] + [cfg.omega_com] * 2
                     + [cfg.omega_swing] * 8 + [cfg.omega_yaw] * 2, float)
    weight = np.array([cfg.weight_pelvis] * 3 + [1.0] + [cfg.weight_com] * 2 + [1.0] * 10, float)
    f = np.float64
    g = Gait(clearance=f(cfg.clearance), strike=f(cfg.strike), reach=f(cfg.reach),
             freeze=f(cfg.freeze), early_contact=f(cfg.early_contact),
             step_length_max=f(cfg.step_length_max), step_width_min=f(cfg.step_width_min),
             step_width_max=f(cfg.step_width_max), foot_torque=f(cfg.foot_torque),
             assist_ssp=f(cfg.assist_ssp), assist_dsp=f(cfg.assist_dsp),
             turn_max=f(np.deg2rad(cfg.turn_max)), recovery_speed=f(cfg.recovery_speed),
             hurry=f(cfg.hurry), land_adapt=f(cfg.land_adapt),
             hold_unsolved=f(cfg.qp_fallback == "hold"), gains=clfqp.make_gains(omega, weight=weight))
    _GAIT_CACHE[cfg] = g
    return g


class Params(NamedTuple):
    push_start: jax.Array    # (P,) [s]
    push_end: jax.Array      # (P,) [s]
    push_force: jax.Array    # (P, 2) world x, y [N]
    ticks: jax.Array         # (n_ticks,) zeros: its length is the static tick budget per step
    gait: Gait
    noise_v: jax.Array       # half-width of the per-step COM velocity noise [m/s]
    step_error: jax.Array    # half-width of the landing-target error [m]


class State(NamedTuple):
    d: mjx.Data
    warm: tuple
    time: jax.Array          # plant clock at the current SSP⁻ [s]
    yaw: jax.Array           # pelvis heading target at the current SSP⁻ [rad]
    land_xy: jax.Array       # (2,) where the landing foot was aimed [m]
    lead: jax.Array          # (2,) landing lead estimate [along, outward] of the heading [m]
    key: jax.Array


def tick_budget(t_step: float) -> int:
    """Static 1 kHz ticks per step: T_SSP + T_DSP rounded up to 10 ms (ticks past the step's
    own T are idle, so a batch uses the longest step of the sweep)."""
    return int(10 * math.ceil(round(t_step / (10 * control.CONTROL_DT), 6)))


def make_params(cfg, n_push: int, t_step: float = 0.0) -> Params:
    """Per-scenario plant data from a :class:`hlip_jax.config.ScenarioConfig`; pushes act on
    the pelvis (force and direction of each :class:`hlip_jax.config.PushConfig`).  The tick
    budget covers ``max(t_step, T_SSP + T_DSP)`` (pass the sweep's longest step so that every
    chunk has one shape)."""
    start, end, force = push_table(cfg.disturbance.pushes, n_push)
    ticks = np.zeros(tick_budget(max(t_step, cfg.hlip.t_ssp + cfg.hlip.t_dsp)))
    return Params(push_start=start, push_end=end, push_force=force, ticks=ticks,
                  gait=make_gait(cfg.cassie), noise_v=np.float64(cfg.disturbance.noise_v),
                  step_error=np.float64(cfg.disturbance.step_error))


def _foot_xy(terms):
    return outputs.foot_centres(terms)[:, :2]


def init(params: Params, x0, u0, stance0, key, heading0=0.0) -> State:
    """Cassie at the "stand" keyframe, turned by ``heading0`` [rad] about the vertical through
    its COM and shifted so the COM is at x0's c (per plane).

    The robot starts facing along the path (``heading0`` is the path's heading at t = 0), so a
    path that leaves the origin at an angle does not begin with a turn.  Both feet are on the
    ground, so the first step's DSP starts from rest; u0 and stance0 are implied by the pose
    (left foot 0.26 m left of the right one)."""
    del u0, stance0
    c = cassie()
    m = c.mj_model
    dm = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, dm, c.index.stand_key)
    mujoco.mj_forward(m, dm)
    com = dm.subtree_com[c.index.pelvis_body].copy()
    d = mjx.put_data(m, dm, impl=c.mjx_model.impl)
    dt = x0.dtype
    d = jax.tree.map(lambda a: a.astype(dt) if jnp.issubdtype(a.dtype, jnp.floating) else a, d)
    # root pose: position rotated about the COM, orientation q ← q_z(θ0) ⊗ q (MuJoCo w, x, y, z)
    th = jnp.asarray(heading0, dt)
    ch, sh = jnp.cos(th), jnp.sin(th)
    r0 = c.index.root_qpos
    px, py, pz, w, qx, qy, qz = (d.qpos[r0 + i] for i in range(7))
    rx, ry = px - com[0], py - com[1]
    hw, hz = jnp.cos(th / 2), jnp.sin(th / 2)
    root = jnp.stack([x0[0, 0] + ch * rx - sh * ry, x0[1, 0] + sh * rx + ch * ry, pz,
                      hw * w - hz * qz, hw * qx - hz * qy, hw * qy + hz * qx, hw * qz + hz * w])
    d = control.canonical(c, d.replace(qpos=d.qpos.at[r0:r0 + 7].set(root)))
    feet = outputs.foot_centres(model.robot_terms(c, d))
    return State(d=d, warm=control.warm_zeros(c, dt), time=jnp.zeros((), dt),
                 yaw=outputs.wrap(th), land_xy=feet[0, :2], lead=jnp.zeros(2, dt), key=key)


def landing_lead(lead, miss, heading, outward, rate):
    """Next landing-lead estimate ℓ_{k+1} = clip(ℓ_k + κ (m_k − ℓ_k), ±LEAD_MAX) [m].

    ``miss`` (2,) is where the foot landed relative to where it was aimed (world x, y [m]);
    it is expressed in the step's heading frame (``heading`` [rad]) as [along, across ·
    ``outward``] (``outward`` = +1 for a left swing foot, −1 for a right one, so a foot that
    lands wide has a positive second component on either side); κ = ``rate``."""
    ch, sh = jnp.cos(heading), jnp.sin(heading)
    seen = jnp.stack([ch * miss[0] + sh * miss[1], outward * (-sh * miss[0] + ch * miss[1])])
    return jnp.clip(lead + rate * (seen - lead), -LEAD_MAX, LEAD_MAX)


def _hlip_at(cmd: StepCommand, t_in_ssp):
    """H-LIP [c, p, v] per plane (2, 3) at time t_in_ssp into the SSP of this step."""
    c, p, v = cmd.x_hlip[:, 0], cmd.x_hlip[:, 1], cmd.x_hlip[:, 2]
    p_d = p + v * cmd.t_dsp
    c_d = c + v * cmd.t_dsp
    p_plus = p_d - cmd.u_hlip
    ps, vs = hlip.ssp_trajectory(p_plus, v, t_in_ssp, cmd.z0)
    return jnp.stack([c_d + ps - p_plus, ps, vs], axis=-1)


def _hlip_dsp(cmd: StepCommand, tau):
    """H-LIP [c, p, v] (2, 3) at time tau into the DSP that starts at SSP⁻_k (p relative to
    the old stance foot, p̈ = 0)."""
    c, p, v = cmd.x_hlip[:, 0], cmd.x_hlip[:, 1], cmd.x_hlip[:, 2]
    return jnp.stack([c + v * tau, p + v * tau, v], axis=-1)


def _flow_to_impact(x, tau, z0):
    """[c, p, v] per plane (2, 3) flowed by the LIP for ``tau`` [s] (c moves with p)."""
    p, v = hlip.ssp_trajectory(x[:, 1], x[:, 2], tau, z0)
    return jnp.stack([x[:, 0] + p - x[:, 1], p, v], axis=-1)


def _robot_x(terms, stance):
    feet = _foot_xy(terms)
    st = jnp.where(stance == 0, feet[0], feet[1])
    c = terms.com[:2]
    return jnp.stack([c, c - st, terms.com_vel[:2]], axis=-1), st


def _fell(d):
    R = model.quat_to_mat(d.qpos[3:7] / jnp.linalg.norm(d.qpos[3:7]))
    tilt = jnp.arccos(jnp.clip(R[2, 2], -1.0, 1.0))
    finite = jnp.all(jnp.isfinite(d.qpos)) & jnp.all(jnp.isfinite(d.qvel))
    return (~finite) | (d.qpos[2] < FALL_HEIGHT) | (tilt > FALL_TILT)


class TickLog(NamedTuple):
    com: jax.Array       # (3,) COM [m]
    feet: jax.Array      # (2, 3) foot centres [m]
    tau: jax.Array       # (10,) motor torques [N m]
    V: jax.Array         # CLF value
    contact: jax.Array   # (4,) contact sites in the constraint set
    status: jax.Array    # CLF-QP status
    pelvis: jax.Array    # (7,) pelvis position [m] and quaternion
    rate: jax.Array      # swing phase rate dσ/dt (1 = unhurried)
    u_des: jax.Array     # (2,) step the swing target aims at (stance-relative, world) [m]


def step_with_log(params: Params, state: State, cmd: StepCommand,
                  settings=clfqp.DEFAULT_SETTINGS):
    """:func:`step` that also returns the per-tick log (for plots and tests)."""
    c = cassie()
    d0 = state.d
    dt = d0.qpos.dtype
    gait = jax.tree.map(lambda a: jnp.asarray(a, dt), params.gait)
    ctrl = cassie().ctrl_range
    lo_all = jnp.asarray(ctrl[:, 0], dt)
    hi_all = jnp.asarray(ctrl[:, 1], dt)
    foot_motor = np.array([c.index.actuators[0][4], c.index.actuators[1][4]])
    springs = dynamics.spring_dofs(c)
    t_ssp, t_dsp = cmd.t_ssp.astype(dt), cmd.t_dsp.astype(dt)
    t_end = t_ssp + t_dsp
    new_st = 1 - cmd.stance                      # stance foot of the coming SSP
    sw = cmd.stance                              # foot that swings in the coming SSP
    z0 = jnp.clip(cmd.z0, *COM_HEIGHT)
    terms0 = model.robot_terms(c, d0)
    feet0 = outputs.foot_centres(terms0)
    yaw_from = state.yaw
    # the heading target moves at most turn_max per step (a path that starts or turns faster
    # than the robot can follow is caught up over the next steps)
    dyaw = jnp.clip(outputs.wrap(cmd.heading - yaw_from), -gait.turn_max, gait.turn_max)
    heading = yaw_from + dyaw
    foot_yaw0 = terms0.foot_yaw
    # landing lead [along, outward] of the heading → world, outward by the swing side
    sgn_sw = jnp.where(sw == 0, 1.0, -1.0)
    ch0, sh0 = jnp.cos(heading), jnp.sin(heading)
    lead = state.lead.astype(dt)
    lead_w = lead[0] * jnp.stack([ch0, sh0]) + sgn_sw * lead[1] * jnp.stack([-sh0, ch0])
    kd = hlip.deadbeat_gain(cmd.z0, cmd.t_ssp, cmd.t_dsp).astype(dt)   # [p, v] deadbeat
    # step noise: a pelvis force held over the step that changes the COM velocity by dv,
    # and an offset of the landing target
    key, k_v, k_u = jax.random.split(state.key, 3)
    dv = jax.random.uniform(k_v, (2,), dt, -1.0, 1.0) * jnp.asarray(params.noise_v, dt)
    f_noise = jnp.asarray(c.total_mass, dt) * dv / t_end
    du_err = jax.random.uniform(k_u, (2,), dt, -1.0, 1.0) * jnp.asarray(params.step_error, dt)

    class Carry(NamedTuple):
        d: mjx.Data
        warm: tuple
        sw_start: jax.Array      # (3,) swing foot position at lift-off
        sw_yaw0: jax.Array
        u_last: jax.Array        # (2,) last swing target step
        fell: jax.Array
        t_saved: jax.Array       # σ − (time into SSP): time a hurried swing saved [s]
        rate: jax.Array          # dσ/dt of the last tick

    def tick(carry: Carry, i):
        d = carry.d
        tau_t = i.astype(dt) * control.CONTROL_DT          # time since SSP⁻_k
        in_dsp = tau_t < t_dsp
        ts = jnp.maximum(tau_t - t_dsp, 0.0)               # time into SSP
        sig = ts + carry.t_saved                           # swing phase time (= ts unhurried)
        # an unhurried step keeps the time-based end, so its tick count is exactly as before
        active = jnp.where(carry.t_saved > 0, in_dsp | (sig < t_ssp - 1e-9), tau_t < t_end - 1e-9)
        terms = model.robot_terms(c, d)
        meas = outputs.measure(terms, d.qvel, c.index.root_dof)
        feet = outputs.foot_centres(terms)
        site_z = terms.site_pos[:, 2] - model.FOOT_SPHERE_RADIUS
        touching = site_z < CONTACT_GAP
        side_of_site = jnp.array([0, 0, 1, 1])
        is_stance_site = side_of_site == new_st
        # landing foot in DSP, swing foot near the end of SSP: contact only when touching
        late_ssp = sig > gait.early_contact * t_ssp
        other_ok = jnp.where(in_dsp, touching, touching & late_ssp)
        contact = jnp.where(is_stance_site, True, other_ok).astype(dt)
        foot_contact = jnp.stack([contact[0] + contact[1] > 0, contact[2] + contact[3] > 0])
        # ---- stepping law (world planes)
        x_r, st_xy = _robot_x(terms, new_st)
        x_h = _hlip_at(cmd, ts)
        # the error at this phase, carried to SSP⁻ by the (linear) LIP flow of the rest of
        # the SSP: the step law's K is designed for pre-impact errors
        e_imp = _flow_to_impact(x_r - x_h, (t_ssp - jnp.minimum(sig, t_ssp)) / carry.rate, cmd.z0)
        u_fb = jnp.sum(cmd.gain * e_imp, axis=-1)
        # recovery: a large velocity error across the heading (a lateral push) takes the
        # deadbeat step on [p, v] across the heading, which removes the velocity error in
        # one step where a soft (LQR) gain spreads it over several while it grows
        ch, sh = jnp.cos(heading), jnp.sin(heading)
        across = jnp.stack([-sh, ch])
        u_db = kd[0] * e_imp[:, 1] + kd[1] * e_imp[:, 2]
        alpha = jnp.where(gait.recovery_speed > 0,
                          jnp.clip(jnp.abs(across @ e_imp[:, 2])
                                   / jnp.maximum(gait.recovery_speed, 1e-9) - 1.0, 0.0, 1.0), 0.0)
        u_des = cmd.u_hlip_next + u_fb + alpha * (across @ (u_db - u_fb)) * across
        # step limits in the heading frame (length along, width across the path heading)
        sgn = jnp.where(sw == 0, 1.0, -1.0)
        u_al = ch * u_des[0] + sh * u_des[1]
        u_ac = -sh * u_des[0] + ch * u_des[1]
        u_al = jnp.clip(u_al, -gait.step_length_max, gait.step_length_max)
        # hurry: a step that the law wants far inward of the narrowest width (past the
        # stance foot: the robot is pushed towards the stance side, and this swing foot
        # cannot catch it) is taken sooner: the swing phase runs up to ``hurry`` times
        # faster, so the other foot's outward step comes before the LIP lets the error grow
        w_des = sgn * u_ac
        excess = jnp.maximum(gait.step_width_min - w_des, 0.0)
        rate = 1.0 + (gait.hurry - 1.0) * jnp.clip((excess - HURRY_FROM) / HURRY_SPAN, 0.0, 1.0)
        rate = jnp.where(in_dsp, 1.0, rate)
        u_ac = sgn * jnp.clip(sgn * u_ac, gait.step_width_min, gait.step_width_max)
        u_des = jnp.stack([ch * u_al - sh * u_ac, sh * u_al + ch * u_ac])
        u_des = jnp.where(sig < gait.freeze * t_ssp, u_des, carry.u_last)
        # ---- desired outputs (swing trajectories on the phase time σ: d/dt = rate · d/dσ)
        cb, cdot, cddot = outputs.with_derivatives(lambda t: outputs.blend(t, t_ssp, gait.reach), sig)
        cdot, cddot = cdot * rate, cddot * rate ** 2
        yaw_d = yaw_from + cb * dyaw
        R_d = outputs.rot_z(yaw_d)
        y = jnp.zeros(outputs.N_OUT, dt).at[outputs.COM_Z].set(z0)
        yd = jnp.zeros(outputs.N_OUT, dt).at[2].set(cdot * dyaw)
        ydd = jnp.zeros(outputs.N_OUT, dt)
        # swing foot (in SSP): horizontal blend to stance + aim, height profile; the aim is
        # the law's step less the learned landing lead (the foot lands where the law asks)
        target_xy = st_xy + u_des - lead_w + du_err
        start_xy = carry.sw_start[:2]
        sxy = (1 - cb) * start_xy + cb * target_xy
        vxy = cdot * (target_xy - start_xy)
        axy = cddot * (target_xy - start_xy)
        hz, hzd, hzdd = outputs.with_derivatives(
            lambda t: outputs.swing_height(t, t_ssp, gait.clearance, gait.strike), sig)
        hzd, hzdd = hzd * rate, hzdd * rate ** 2
        # landing foot in DSP (late touchdown): hold xy, keep reaching down
        lz, lzd, lzdd = outputs.with_derivatives(
            lambda t: outputs.swing_height(t, t_ssp, gait.clearance, gait.strike), t_ssp + tau_t)
        fx = jnp.where(in_dsp, state.land_xy[0], sxy[0])
        fy = jnp.where(in_dsp, state.land_xy[1], sxy[1])
        fz = jnp.where(in_dsp, lz, hz)
        f_vel = jnp.where(in_dsp, jnp.array([0.0, 0.0, 1.0]) * lzd, jnp.stack([vxy[0], vxy[1], hzd]))
        f_acc = jnp.where(in_dsp, jnp.array([0.0, 0.0, 1.0]) * lzdd, jnp.stack([axy[0], axy[1], hzdd]))
        fyaw = jnp.where(in_dsp, yaw_from, (1 - cb) * carry.sw_yaw0 + cb * heading)
        fyaw_d = jnp.where(in_dsp, 0.0, cdot * outputs.wrap(heading - carry.sw_yaw0))
        # the moving foot: in DSP the landing foot (= new stance), in SSP the swing foot
        mv = jnp.where(in_dsp, new_st, sw)
        for s in (0, 1):
            sl = outputs.FOOT_POS[s]
            on = mv == s
            y = y.at[sl].set(jnp.where(on, jnp.stack([fx, fy, fz]), 0.0))
            yd = yd.at[sl].set(jnp.where(on, f_vel, 0.0))
            ydd = ydd.at[sl].set(jnp.where(on, f_acc, 0.0))
            y = y.at[outputs.FOOT_YAW[s]].set(jnp.where(on, fyaw, 0.0))
            yd = yd.at[outputs.FOOT_YAW[s]].set(jnp.where(on, fyaw_d, 0.0))
        # ankle assist: the COM follows the H-LIP's own trajectory (relative to the stance
        # foot) with a soft output, in both directions in DSP, along the heading in SSP (the
        # line foot has no authority across it); rows 4, 5 are expressed in the heading frame
        x_hd = _hlip_dsp(cmd, jnp.minimum(tau_t, t_dsp))
        p_h = jnp.where(in_dsp, x_hd[:, 1], x_h[:, 1])
        v_h = jnp.where(in_dsp, x_hd[:, 2], x_h[:, 2])
        a_h = jnp.where(in_dsp, 0.0, hlip.GRAVITY / cmd.z0 * x_h[:, 1])
        old_xy = jnp.where(cmd.stance == 0, feet0[0, :2], feet0[1, :2])
        ref_xy = jnp.where(in_dsp, old_xy, st_xy)
        Rh = R_d[:2, :2].T                                   # world → heading frame
        y = y.at[outputs.COM_XY].set(Rh @ (ref_xy + p_h))
        yd = yd.at[outputs.COM_XY].set(Rh @ v_h)
        ydd = ydd.at[outputs.COM_XY].set(Rh @ a_h)
        meas = meas._replace(y=meas.y.at[outputs.COM_XY].set(Rh @ meas.y[outputs.COM_XY]),
                             ydot=meas.ydot.at[outputs.COM_XY].set(Rh @ meas.ydot[outputs.COM_XY]),
                             J=meas.J.at[outputs.COM_XY].set(Rh @ meas.J[outputs.COM_XY]),
                             jdqd=meas.jdqd.at[outputs.COM_XY].set(Rh @ meas.jdqd[outputs.COM_XY]))
        mask = jnp.zeros(outputs.N_OUT, dt).at[:4].set(1.0)
        f_along = jnp.where(in_dsp, gait.assist_dsp, gait.assist_ssp)
        f_across = jnp.where(in_dsp, gait.assist_dsp, 0.0)
        mask = mask.at[4].set((f_along > 0).astype(dt)).at[5].set((f_across > 0).astype(dt))
        gains = gait.gains._replace(weight=gait.gains.weight.at[4].multiply(f_along)
                                    .at[5].multiply(f_across))
        for s in (0, 1):
            free = (mv == s) & ~foot_contact[s]
            rows = np.r_[np.arange(16)[outputs.FOOT_POS[s]], outputs.FOOT_SLOPE[s], outputs.FOOT_YAW[s]]
            mask = mask.at[rows].set(jnp.where(free, 1.0, 0.0))
        des = outputs.Desired(y=y, ydot=yd, yddot=ydd, R=R_d, mask=mask)
        # ---- torque limits: a foot motor is passive while its foot is on the ground
        lo, hi = lo_all, hi_all
        for s in (0, 1):
            lim = jnp.where(foot_contact[s], gait.foot_torque, 1.0)
            lo = lo.at[foot_motor[s]].multiply(lim)
            hi = hi.at[foot_motor[s]].multiply(lim)
        cond = dynamics.condense(terms, c.actuation, contact, springs)
        res = clfqp.solve(meas, des, cond, contact, lo, hi, gains, carry.warm, settings,
                          fallback=gait.hold_unsolved > 0.5)
        # ---- push and physics
        t_abs = state.time + tau_t
        on = (t_abs >= params.push_start) & (t_abs < params.push_end)
        f = jnp.sum(jnp.where(on[:, None], params.push_force, 0.0), axis=0) + f_noise
        d_new = control.physics(c, d, res.tau, jnp.concatenate([f, jnp.zeros(1, dt)]))
        keep = active & ~carry.fell
        d_next = jax.tree.map(lambda a, b: jnp.where(keep, a, b), d_new, d)
        warm = jax.tree.map(lambda a, b: jnp.where(keep, a, b), res.warm, carry.warm)
        # lift-off bookkeeping: at the first SSP tick record the swing foot pose
        first_ssp = (tau_t >= t_dsp) & (tau_t < t_dsp + control.CONTROL_DT)
        sw_pos = jnp.where(sw == 0, feet[0], feet[1])
        sw_yaw = jnp.where(sw == 0, terms.foot_yaw[0], terms.foot_yaw[1])
        sw_start = jnp.where(first_ssp, sw_pos, carry.sw_start)
        sw_yaw0 = jnp.where(first_ssp, sw_yaw, carry.sw_yaw0)
        # the target is frozen over the last part of the SSP (the foot is arriving)
        u_last = jnp.where(active & ~in_dsp & (sig < gait.freeze * t_ssp), u_des, carry.u_last)
        fell = carry.fell | (active & _fell(d_next))
        run = active & ~carry.fell
        t_saved = carry.t_saved + jnp.where(run & ~in_dsp, (rate - 1.0) * control.CONTROL_DT, 0.0)
        log = TickLog(com=terms.com, feet=feet, tau=res.tau, V=res.V, contact=contact,
                      status=res.status, pelvis=d.qpos[:7], rate=rate, u_des=u_des)
        return Carry(d_next, warm, sw_start, sw_yaw0, u_last, fell, t_saved,
                     jnp.where(run, rate, carry.rate)), log

    sw_pos0 = jnp.where(sw == 0, feet0[0], feet0[1])
    sw_yaw00 = jnp.where(sw == 0, foot_yaw0[0], foot_yaw0[1])
    zero = jnp.zeros((), dt)
    carry0 = Carry(d0, state.warm, sw_pos0, sw_yaw00, cmd.u_hlip_next.astype(dt),
                   jnp.bool_(False), zero, jnp.ones((), dt))
    n = params.ticks.shape[0]
    carry, log = jax.lax.scan(tick, carry0, jnp.arange(n))
    # ---- SSP⁻_{k+1}: robot state, executed step
    terms = model.robot_terms(c, carry.d)
    x_r, st_xy = _robot_x(terms, new_st)
    feet = outputs.foot_centres(terms)
    sw_xy = jnp.where(sw == 0, feet[0, :2], feet[1, :2])
    u_robot = sw_xy - st_xy
    failed = carry.fell | ~jnp.all(jnp.isfinite(x_r))
    aim = carry.u_last - lead_w + du_err
    lead_new = landing_lead(lead, u_robot - aim, heading, sgn_sw, gait.land_adapt)
    lead_new = jnp.where(failed | ~jnp.all(jnp.isfinite(lead_new)), lead, lead_new)
    # the step lasted T_SSP + T_DSP less what a hurried swing saved (to one tick)
    new = State(d=carry.d, warm=carry.warm, time=state.time + t_end - carry.t_saved,
                yaw=outputs.wrap(heading).astype(dt),
                land_xy=st_xy + aim, lead=lead_new, key=key)
    return new, StepResult(x_robot=x_r, u_robot=u_robot, failed=failed), log


def step(params: Params, state: State, cmd: StepCommand, settings=clfqp.DEFAULT_SETTINGS):
    """One walking step SSP⁻_k → SSP⁻_{k+1} (module doc); ``settings`` (static) are the
    CLF-QP's ADMM settings.  Returns (state, StepResult)."""
    new, res, _ = step_with_log(params, state, cmd, settings)
    return new, res


# ----------------------------------------------------------------------------- orbit driver


#: the walking tasks of the orbit-walking acceptance: name, forward [m/s], sideways [m/s],
#: yaw rate [deg/s] (in the heading frame)
WALK_TASKS = (
    ("in_place", 0.0, 0.0, 0.0),
    ("fwd_0.2", 0.2, 0.0, 0.0),
    ("fwd_0.5", 0.5, 0.0, 0.0),
    ("fwd_0.8", 0.8, 0.0, 0.0),
    ("side_0.3", 0.0, 0.3, 0.0),
    ("turn_30dps", 0.0, 0.0, 30.0),
)

#: the default orbit walk (gait search set #85, docs/cassie_gait.md): H-LIP T_SSP, T_DSP [s],
#: COM height z0 [m], nominal step width [m], and the weights of the 3-state LQR stepping gain
#: Q = diag(q_c, 1, q_v), R = r (see :func:`lqr_step_gain`)
WALK_DEFAULTS = dict(t_ssp=0.2726, t_dsp=0.02, z0=0.8413, width=0.15, q_c=0.07065, q_v=0.247,
                     r=2.673)


def lqr_step_gain(z0, t_ssp, t_dsp, q_c, q_v, r):
    """3-state LQR stepping gain K (3,) on [c, p, v] of one plane, Q = diag(q_c, 1, q_v),
    R = r (all traced: vmap over robots)."""
    A, B = hlip.s2s_matrices(z0, t_ssp, t_dsp)
    q_c, q_v = jnp.asarray(q_c, A.dtype), jnp.asarray(q_v, A.dtype)
    return hlip.lqr_gain(A, B, jnp.diag(jnp.stack([q_c, jnp.ones_like(q_c), q_v])), r)


class WalkLog(NamedTuple):
    """Per-step record of :func:`walk_orbits` (leading axes: robots, steps)."""
    x_robot: np.ndarray   # (B, K+1, 2, 3) robot [c, p, v] at SSP⁻_0..K
    u_robot: np.ndarray   # (B, K+1, 2) step placed at SSP⁻_0..K
    x_hlip: np.ndarray    # (B, K+1, 2, 3)
    u_hlip: np.ndarray    # (B, K+1, 2)
    failed: np.ndarray    # (B, K) bool
    heading: np.ndarray   # (B, K+1)
    w: np.ndarray         # (B, K-1, 2, 3) S2S residual x_{k+1} − A x_k − B u_k (from step 1 on)
    e: np.ndarray         # (B, K+1, 2, 3) x_robot − x_hlip
    pelvis_yaw: np.ndarray  # (B, K+1)
    time: np.ndarray      # (B, K+1) plant clock at SSP⁻_0..K [s] (a hurried step is shorter than T)


def orbit_step(z0, t_ssp, t_dsp, v_fwd, v_lat, width, heading, swing):
    """H-LIP orbit step in world planes: P1 along the heading (speed v_fwd), P2 across it
    (speed v_lat, step width ``width`` [m]); ``swing`` 0 = left foot steps (+width)."""
    p1 = hlip.p1_orbit(z0, t_ssp, t_dsp, v_fwd)
    p2 = hlip.p2_orbit(z0, t_ssp, t_dsp, v_lat, width + v_lat * (t_ssp + t_dsp))
    left = swing == 0
    u_lat = np.where(left, p2.u_left, p2.u_right)
    p_lat = np.where(left, p2.p_left, p2.p_right)
    v_l = np.where(left, p2.v_left, p2.v_right)
    c, s = np.cos(heading), np.sin(heading)
    rot = lambda a, b: np.array([c * a - s * b, s * a + c * b])
    return rot(p1.u, u_lat), rot(p1.p, p_lat), rot(p1.v, v_l)


def nominal_next(A, Bm, k_h, x_h, u_h, z0, t_ssp, t_dsp, v_fwd, v_lat, width, heading, swing):
    """One step of the orbit-following H-LIP nominal (numpy, batch B):
    x_H,k+1 = A x_H,k + B u_H,k per world plane, then u_H,k+1 = u* + K_H ([p, v]_H,k+1 − [p*, v*])
    with (u*, p*, v*) the P1/P2 orbit step of ``heading`` for the foot ``swing`` and K_H the
    2-state deadbeat gain (B, 2): the nominal converges to the orbit of the current heading
    (open-loop orbit steps diverge once the heading turns).  A (B, 3, 3), Bm (B, 3),
    x_h (B, 2, 3), u_h (2, B).  Returns (x_H,k+1 (B, 2, 3), u_H,k+1 (2, B))."""
    x_next = np.einsum("bij,bpj->bpi", A, x_h) + u_h.T[..., None] * Bm[:, None]
    u_o, p_o, v_o = orbit_step(z0, t_ssp, t_dsp, v_fwd, v_lat, width, heading, swing)
    u_next = u_o + (k_h[:, :1] * (x_next[:, :, 1] - p_o.T) + k_h[:, 1:] * (x_next[:, :, 2] - v_o.T)).T
    return x_next, u_next


def walk_orbits(v_fwd, v_lat, yaw_rate, n_steps: int, *, z0=0.8, t_ssp=0.3, t_dsp=0.1,
                width=0.25, gain=None, gait=None, pushes=None, batch_step=None,
                return_ticks=False, noise_v=0.0, step_error=0.0):
    """Closed loop without MPC: the H-LIP nominal follows P1 (sagittal) / P2 (lateral) orbit
    steps in the heading frame, x_H,k+1 = A x_H,k + B u_H,k, heading θ_k = yaw_rate · k T;
    the robot steps by the stepping law (deadbeat K by default).  One robot per entry of
    ``v_fwd``, ``v_lat``, ``yaw_rate`` (arrays of equal length B, vmapped); ``z0``, ``t_ssp``,
    ``t_dsp``, ``width`` are scalars or per-robot arrays, ``gain`` is (2, 3) or (B, 2, 3),
    ``gait`` a :class:`hlip_jax.config.CassieConfig` or a sequence of B of them; ``noise_v``
    [m/s] and ``step_error`` [m] (scalars or per robot) the step noise of the module doc, drawn
    from robot i's key PRNGKey(i).
    Returns (WalkLog, per-step tick logs if ``return_ticks``)."""
    v_fwd, v_lat, yaw_rate = (np.atleast_1d(np.asarray(a, float)) for a in (v_fwd, v_lat, yaw_rate))
    B = v_fwd.size
    z0, t_ssp, t_dsp, width = (np.broadcast_to(np.asarray(a, float), (B,)).copy()
                               for a in (z0, t_ssp, t_dsp, width))
    T = t_ssp + t_dsp
    A, Bm = (np.asarray(a) for a in jax.vmap(hlip.s2s_matrices)(z0, t_ssp, t_dsp))  # (B,3,3),(B,3)
    if gain is None:
        k = np.asarray(jax.vmap(hlip.deadbeat_gain)(z0, t_ssp, t_dsp))              # (B, 2)
        gain = np.repeat(np.concatenate([np.zeros((B, 1)), k], 1)[:, None], 2, axis=1)
    gain = np.broadcast_to(np.asarray(gain, float), (B, 2, 3))
    if gait is None or not isinstance(gait, (list, tuple)):
        gaits = [make_gait(gait)] * B
    else:
        if len(gait) != B:
            raise ValueError(f"gait: expected one CassieConfig per robot ({B}), got {len(gait)}")
        gaits = [make_gait(g) for g in gait]
    n_push = 1 if pushes is None else len(pushes)
    params = Params(push_start=np.full((B, n_push), -1.0), push_end=np.full((B, n_push), -1.0),
                    push_force=np.zeros((B, n_push, 2)),
                    ticks=np.zeros((B, tick_budget(float(T.max())))),
                    gait=jax.tree.map(lambda *a: np.stack(a), *gaits),
                    noise_v=np.broadcast_to(np.asarray(noise_v, float), (B,)).copy(),
                    step_error=np.broadcast_to(np.asarray(step_error, float), (B,)).copy())
    if pushes is not None:
        for i, (t0, t1, fx, fy) in enumerate(pushes):
            params.push_start[:, i], params.push_end[:, i] = t0, t1
            params.push_force[:, i] = np.stack(np.broadcast_arrays(fx, fy), -1)
    params = jax.tree.map(jnp.asarray, params)
    x0 = jnp.zeros((2, 3))
    one = init(None, x0, None, None, jax.random.PRNGKey(0))       # every robot starts alike
    state = jax.tree.map(lambda a: jnp.broadcast_to(a, (B,) + a.shape), one)
    state = state._replace(key=jax.vmap(jax.random.PRNGKey)(jnp.arange(B)))
    if batch_step is None:
        batch_step = jax.jit(jax.vmap(step_with_log))
    k_h = np.asarray(jax.vmap(hlip.deadbeat_gain)(z0, t_ssp, t_dsp))             # (B, 2)
    # nominal at SSP⁻_0: right stance ended, the left foot lands with u_H,0
    stance = 1
    heading = np.zeros(B)
    u_h, p_h, v_h = orbit_step(z0, t_ssp, t_dsp, v_fwd, v_lat, width, heading, 1 - stance)
    x_h = np.stack([np.stack([np.zeros(B), p_h[0], v_h[0]], -1),
                    np.stack([np.zeros(B), p_h[1], v_h[1]], -1)], 1)          # (B, 2, 3)
    terms = jax.vmap(lambda d: model.robot_terms(cassie(), d))(state.d)
    x_r0 = np.asarray(jax.vmap(_robot_x, in_axes=(0, None))(terms, stance)[0])
    feet = np.asarray(jax.vmap(outputs.foot_centres)(terms))
    u_r0 = feet[:, 0, :2] - feet[:, 1, :2]
    log = dict(x_robot=[x_r0], u_robot=[u_r0], x_hlip=[x_h], u_hlip=[u_h.T], failed=[],
               heading=[heading.copy()], pelvis_yaw=[np.zeros(B)], time=[np.asarray(state.time)])
    ticks = []
    for k in range(n_steps):
        heading_next = yaw_rate * (k + 1) * T
        x_h_next, u_h_next = nominal_next(A, Bm, k_h, x_h, u_h, z0, t_ssp, t_dsp, v_fwd, v_lat,
                                          width, heading_next, stance)
        cmd = StepCommand(t=jnp.asarray(k * T), stance=jnp.full(B, stance, jnp.int32),
                          x_hlip=jnp.asarray(x_h), u_hlip=jnp.asarray(u_h.T),
                          x_hlip_next=jnp.asarray(x_h_next), u_hlip_next=jnp.asarray(u_h_next.T),
                          gain=jnp.asarray(gain), heading=jnp.asarray(heading_next),
                          t_ssp=jnp.asarray(t_ssp), t_dsp=jnp.asarray(t_dsp), z0=jnp.asarray(z0))
        state, res, tlog = batch_step(params, state, cmd)
        if return_ticks:
            ticks.append(jax.tree.map(np.asarray, tlog))
        x_h, u_h, stance, heading = x_h_next, u_h_next, 1 - stance, heading_next
        log["x_robot"].append(np.asarray(res.x_robot))
        log["u_robot"].append(np.asarray(res.u_robot))
        log["x_hlip"].append(x_h)
        log["u_hlip"].append(u_h.T)
        log["failed"].append(np.asarray(res.failed))
        log["heading"].append(heading.copy())
        R = jax.vmap(lambda q: model.quat_to_mat(q / jnp.linalg.norm(q)))(state.d.qpos[:, 3:7])
        log["pelvis_yaw"].append(np.arctan2(np.asarray(R[:, 1, 0]), np.asarray(R[:, 0, 0])))
        log["time"].append(np.asarray(state.time))
    out = {k: np.stack(v, axis=1) for k, v in log.items()}
    xr, ur = out["x_robot"], out["u_robot"]
    w = (xr[:, 2:] - np.einsum("bij,bkpj->bkpi", A, xr[:, 1:-1])
         - ur[:, 1:-1, :, None] * Bm[:, None, None])
    out["w"] = w
    out["e"] = xr - out["x_hlip"]
    out["failed"] = np.cumsum(out["failed"], axis=1) > 0
    return WalkLog(**out), ticks


def walk_speeds(log: WalkLog, i: int, lo: int, hi: int, T: float):
    """Average motion of robot ``i`` from SSP⁻_lo to SSP⁻_hi of a :func:`walk_orbits` log:
    (forward, sideways) COM speed in the heading frame of each step [m/s] and the pelvis yaw
    rate [deg/s]; ``T`` is the step duration [s]."""
    c = log.x_robot[i, lo:hi + 1, :, 0]
    h = log.heading[i, lo:hi]                                    # heading over each interval
    dc = np.diff(c, axis=0)
    dur = (hi - lo) * T
    fwd = float(np.cos(h) @ dc[:, 0] + np.sin(h) @ dc[:, 1]) / dur
    side = float(-np.sin(h) @ dc[:, 0] + np.cos(h) @ dc[:, 1]) / dur
    yaw = np.unwrap(log.pelvis_yaw[i, lo:hi + 1])
    return fwd, side, float(np.rad2deg(yaw[-1] - yaw[0])) / dur
