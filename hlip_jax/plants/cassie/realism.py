"""How the simulated Cassie departs from the ideal plant: motors, latency, sensing, touchdown
detection, model errors and ground slope — each a per-scenario number, so a sweep over any of
them shares one compiled program, and the defaults (those of
:class:`hlip_jax.simulation.config.RealismConfig`) leave today's ideal plant exactly as it was: a batch of
ideal robots carries no realism data and compiles none of this
(:mod:`hlip_jax.plants.cassie.tick`), and in a batch that does, an ideal robot's stages select
their ideal branch (no arithmetic touches its torques or measurements).

Per 1 kHz control tick i (the stages the tick of :mod:`hlip_jax.plants.cassie.tick` calls):

**Sensing** (:func:`sense`).  The controller sees ``qpos``, ``qvel`` with zero-mean Gaussian
noise: σ_q on every hinge joint (encoders; Agility's Cassie model gives 2e-4 rad on the shin
and tarsus encoders), σ_q̇ on their rates, σ_R on the pelvis orientation (a small rotation
δ = b + n in the pelvis frame, b the constant roll/pitch bias, n ~ N(0, σ_R²) per axis) and σ_ω
on the gyro (the pelvis angular velocity; the model gives 5e-4 rad/s).  The pelvis position and
linear velocity stay exact (the H-LIP state is measured relative to the stance foot).  The
stepping law's COM velocity is a first-order low-pass of the measured one,

    v̂_i = v̂_{i−1} + a (v_i − v̂_{i−1}),    a = Δt / (τ_v + Δt),

(τ_v = 0: v̂ = v).  The step log and the analysis keep the true state.

**Touchdown detection** (:func:`touching`).  Either the oracle — a contact sphere within the
tick's ``CONTACT_GAP`` of the ground, read from the true state (under sensing noise from the
physics' last kinematics, half a physics step old) — or the leaf springs: a foot touches when
its heel spring, measured, is compressed beyond a threshold, the way the hardware controllers
detect contact (walking at 0.5 m/s in the ideal simulation the loaded heel spring sits at −2.2°
(median; 5 % of stance ticks beyond −3.9°, 95 % beyond −0.5°) and a swinging one within ±1°
99 % of the time: the default 1.5° separates them) — or the measured leg kinematics: a foot
touches when its lower sphere is within the gap of the lowest of the four spheres, all from
the measured state (encoders and IMU, their noise and bias included).  The kinematic detector
needs no ground height: the stance foot stands for the ground, as on hardware that reads
contact from leg kinematics; on a slope it fires late uphill and early downhill.

**Actuation** (:func:`actuate`).  A control update every n ticks (torques held in between,
zero-order hold), a latency of L ticks between measurement and torque, a first-order motor lag

    τ_m,i = τ_m,i−1 + b (τ_c,i−L − τ_m,i−1),    b = Δt / (τ_lag + Δt),

and the motor's torque–speed curve: with ω the motor speed (gear × joint rate), ω_0 its no-load
speed and c the corner fraction, torque that drives the motor along ω is limited to

    τ_max · clip((ω_0 − |ω|) / ((1 − c) ω_0), 0, 1)

(full torque up to c ω_0, none beyond ω_0: the joints' speed limit); braking torque keeps τ_max.
No-load speeds 2900, 2900, 1300, 1300, 5500 rpm (hip roll, yaw, pitch, knee, foot), the figures
of Agility Robotics' Cassie model as published in MuJoCo Menagerie.

**Model errors and slope** (:func:`plant_model`, the physics' model only; the controller keeps
the nominal one): every link's mass and inertia × s_m, the pelvis COM shifted by (Δx, Δy) in the
pelvis frame, the leaf-spring stiffness × s_k, the friction coefficient μ of the feet and the
floor, and gravity tilted so the ground is a plane rising by α_x along world x and α_y along y
(the controller does not know the slope: its frame stays the ground's).  A step in the ground
or rough ground (``step_height``, ``step_x``, ``rough_height``) is geometry, not a model edit:
:mod:`terrain`.  The constraint solver's body weights are those of the nominal model.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from hlip_jax.plants.cassie import dynamics, model, terrain

#: longest latency the per-scenario queue holds [ticks]; the config's range stops here
MAX_LATENCY = 10
#: touchdown detectors, in the order of :attr:`Realism.touchdown` (``realism.touchdown`` values)
TOUCHDOWN = ("contact", "spring", "kinematic")
#: no-load motor speeds [rpm] per motor of a leg (hip roll, yaw, pitch, knee, foot): Agility's
#: Cassie model (actuator ``user`` values in MuJoCo Menagerie's ``agility_cassie``)
NO_LOAD_RPM = (2900.0, 2900.0, 1300.0, 1300.0, 5500.0)


class Realism(NamedTuple):
    """Per-scenario departures from the ideal plant (arrays; :func:`make` builds them)."""
    motor_curve: jax.Array      # bool: limit torques by the torque–speed curve
    motor_corner: jax.Array     # c: fraction of the no-load speed with full torque
    motor_lag: jax.Array        # τ_lag [s], 0 = instant
    latency: jax.Array          # L [ticks] (int32)
    period: jax.Array           # n: control update every n ticks (int32)
    noisy: jax.Array            # bool: any sensing noise or bias
    joint_noise: jax.Array      # σ_q [rad]
    joint_rate_noise: jax.Array  # σ_q̇ [rad/s]
    imu_noise: jax.Array        # σ_R [rad]
    imu_rate_noise: jax.Array   # σ_ω [rad/s]
    imu_bias: jax.Array         # (2,) roll, pitch bias b [rad]
    velocity_filter: jax.Array  # τ_v [s], 0 = no filter
    touchdown: jax.Array        # touchdown detector, index into TOUCHDOWN (int32)
    spring_threshold: jax.Array  # heel-spring compression that counts as contact [rad]
    mass_scale: jax.Array       # s_m
    pelvis_com: jax.Array       # (2,) Δx, Δy of the pelvis COM in the pelvis frame [m]
    stiffness_scale: jax.Array  # s_k
    friction: jax.Array         # μ
    slope: jax.Array            # (2,) α_x, α_y [rad]


class RealState(NamedTuple):
    """What the non-ideal stages remember from tick to tick (and step to step)."""
    queue: jax.Array            # (MAX_LATENCY, nu) past commands, newest first [N m]
    held: jax.Array             # (nu,) command of the last control update [N m]
    motor: jax.Array            # (nu,) torque the motors produce (lag state) [N m]
    v_est: jax.Array            # (3,) the stepping law's COM velocity estimate [m/s]
    tick: jax.Array             # control ticks since the start (int32)
    key: jax.Array              # PRNG key of the sensing noise


def make(cfg) -> Realism:
    """:class:`Realism` (numpy) of a :class:`hlip_jax.simulation.config.RealismConfig` (angles there in
    degrees)."""
    f, rad = np.float64, np.deg2rad
    noise = (cfg.joint_noise, cfg.joint_rate_noise, cfg.imu_noise, cfg.imu_rate_noise,
             cfg.imu_bias_roll, cfg.imu_bias_pitch)
    return Realism(
        motor_curve=np.bool_(cfg.motor_curve), motor_corner=f(cfg.motor_corner),
        motor_lag=f(cfg.motor_lag), latency=np.int32(cfg.latency), period=np.int32(cfg.control_period),
        noisy=np.bool_(any(v != 0 for v in noise)), joint_noise=f(rad(cfg.joint_noise)),
        joint_rate_noise=f(rad(cfg.joint_rate_noise)), imu_noise=f(rad(cfg.imu_noise)),
        imu_rate_noise=f(rad(cfg.imu_rate_noise)),
        imu_bias=rad(np.array([cfg.imu_bias_roll, cfg.imu_bias_pitch], float)),
        velocity_filter=f(cfg.velocity_filter),
        touchdown=np.int32(TOUCHDOWN.index(cfg.touchdown)),
        spring_threshold=f(rad(cfg.spring_threshold)), mass_scale=f(cfg.mass_scale),
        pelvis_com=np.array([cfg.pelvis_com_x, cfg.pelvis_com_y], float),
        stiffness_scale=f(cfg.spring_stiffness_scale), friction=f(cfg.friction),
        slope=rad(np.array([cfg.slope_x, cfg.slope_y], float)))


def init_state(nu: int, com_vel, key, dtype) -> RealState:
    z = jnp.zeros(nu, dtype)
    return RealState(queue=jnp.zeros((MAX_LATENCY, nu), dtype), held=z, motor=z,
                     v_est=jnp.asarray(com_vel, dtype), tick=jnp.zeros((), jnp.int32), key=key)


# ----------------------------------------------------------------------------- constants


class Layout(NamedTuple):
    """Model addresses the stages need (numpy, from the C model)."""
    hinge_qpos: np.ndarray      # qpos addresses of the hinge joints
    hinge_dof: np.ndarray       # their dof addresses
    motor_dof: np.ndarray       # (nu,) dof of each actuator
    gear: np.ndarray            # (nu,) motor-to-joint ratio
    no_load: np.ndarray         # (nu,) ω_0 [rad/s] at the motor
    heel_qpos: np.ndarray       # (2,) heel-spring qpos addresses, left, right
    spring_jnt: np.ndarray      # (4,) joint ids of the leaf springs (shin L, heel L, shin R, heel R)
    spring_qpos: np.ndarray     # (4,) their qpos addresses
    contact_geoms: np.ndarray   # geoms that collide (feet, floor)


_LAYOUT: dict = {}


def layout(c: model.Cassie) -> Layout:
    key = id(c)
    if key not in _LAYOUT:
        m = c.mj_model
        hinge = np.flatnonzero(m.jnt_type == mujoco.mjtJoint.mjJNT_HINGE)
        motor_jnt = m.actuator_trnid[:, 0]
        spring_jnt = m.dof_jntid[np.array(dynamics.spring_dofs(c))]
        spring_qpos = m.jnt_qposadr[spring_jnt]
        _LAYOUT[key] = Layout(
            hinge_qpos=m.jnt_qposadr[hinge].copy(), hinge_dof=m.jnt_dofadr[hinge].copy(),
            motor_dof=m.jnt_dofadr[motor_jnt].copy(), gear=m.actuator_gear[:, 0].copy(),
            no_load=np.tile(NO_LOAD_RPM, 2) * 2 * np.pi / 60,
            heel_qpos=spring_qpos[[1, 3]].copy(), spring_jnt=spring_jnt.copy(),
            spring_qpos=spring_qpos.copy(),
            contact_geoms=np.flatnonzero((m.geom_contype != 0) | (m.geom_conaffinity != 0)))
    return _LAYOUT[key]


# ----------------------------------------------------------------------------- stages


def _small_rotation(q, delta):
    """Quaternion ``q`` (w, x, y, z) turned by the rotation vector ``delta`` (3,) [rad] in its
    own frame: q ⊗ [cos(θ/2), sin(θ/2) δ/θ], θ = |δ| (sinc form: exact at δ = 0)."""
    th = jnp.linalg.norm(delta)
    e = jnp.concatenate([jnp.cos(0.5 * th)[None], 0.5 * jnp.sinc(th / (2 * jnp.pi)) * delta])
    w1, x1, y1, z1 = q
    w2, x2, y2, z2 = e
    return jnp.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                      w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def sense(c: model.Cassie, real: Realism, rs: RealState, d):
    """(the data the controller measures, next state): ``d`` with its ``qpos``/``qvel`` noised
    and biased as the module doc says (``d`` itself where the scenario has no sensing noise)."""
    lay = layout(c)
    dt = d.qpos.dtype
    key, kq, kv, kr, kw = jax.random.split(rs.key, 5)
    nh = lay.hinge_qpos.shape[0]
    r0, v0 = c.index.root_qpos, c.index.root_dof
    qpos = d.qpos.at[lay.hinge_qpos].add(real.joint_noise * jax.random.normal(kq, (nh,), dt))
    delta = jnp.concatenate([real.imu_bias, jnp.zeros(1, dt)]) \
        + real.imu_noise * jax.random.normal(kr, (3,), dt)
    qpos = qpos.at[r0 + 3:r0 + 7].set(_small_rotation(d.qpos[r0 + 3:r0 + 7], delta))
    qvel = d.qvel.at[lay.hinge_dof].add(real.joint_rate_noise * jax.random.normal(kv, (nh,), dt))
    qvel = qvel.at[v0 + 3:v0 + 6].add(real.imu_rate_noise * jax.random.normal(kw, (3,), dt))
    meas = d.replace(qpos=jnp.where(real.noisy, qpos, d.qpos), qvel=jnp.where(real.noisy, qvel, d.qvel))
    return meas, rs._replace(key=key)


def estimate_velocity(real: Realism, rs: RealState, com_vel, dt_c: float) -> RealState:
    """The stepping law's COM velocity after this tick's measurement ``com_vel`` (3,)."""
    a = dt_c / (real.velocity_filter + dt_c)
    filtered = rs.v_est + a * (com_vel - rs.v_est)
    return rs._replace(v_est=jnp.where(real.velocity_filter > 0, filtered, com_vel))


def touching(c: model.Cassie, real: Realism, d_true, d_meas, site_pos, gap: float, ground=None):
    """(4,) bool per contact site (:data:`model.CONTACT_SITES`): the oracle (sphere within
    ``gap`` [m] of the ground — z = 0, or the step of ``ground``, a :class:`terrain.Terrain`;
    ``site_pos`` where the measurement is exact, else the true sites of ``d_true``'s last
    kinematics), the heel springs of ``d_meas`` (both sites of a
    foot whose spring deflects beyond the threshold), or the measured kinematics: both sites
    of a foot whose lower sphere is within ``gap`` of the lowest sphere in the measured
    ``site_pos`` (the stance foot stands for the ground, so the robot needs no ground height,
    and sensing errors and slopes move the detection; per foot, because a 3° pitch error
    already puts a flat foot's toe and heel 6 mm apart in the measurement)."""
    sites = jnp.where(real.noisy, d_true.site_xpos[np.asarray(c.index.contact_sites)], site_pos)
    floor = 0.0 if ground is None else terrain.height(ground, sites[:, :2])
    oracle = sites[:, 2] - model.FOOT_SPHERE_RADIUS - floor < gap
    heel = -d_meas.qpos[layout(c).heel_qpos] > real.spring_threshold    # compressed by the load
    foot_low = jnp.min(site_pos[:, 2].reshape(2, 2), axis=1)                # (2,) per foot
    kinematic = jnp.repeat(foot_low - jnp.min(foot_low) < gap, 2)
    return jnp.stack([oracle, jnp.repeat(heel, 2), kinematic])[real.touchdown]


def motor_limit(real: Realism, tau, omega, tau_max, no_load):
    """``tau`` (nu,) [N m, motor side] clipped by the torque–speed curve at motor speeds
    ``omega`` (nu,) [rad/s] (module doc); ``tau`` itself where the curve is off."""
    span = (1 - real.motor_corner) * no_load
    cap = tau_max * jnp.clip((no_load - jnp.abs(omega)) / span, 0.0, 1.0)
    driving = tau * omega > 0
    lim = jnp.where(driving, cap, tau_max)
    return jnp.where(real.motor_curve, jnp.clip(tau, -lim, lim), tau)


def actuate(c: model.Cassie, real: Realism, rs: RealState, tau, qvel, run, dt_c: float):
    """(torque the motors apply this tick (nu,) [N m], next state) for the controller's
    ``tau`` (module doc: control period, latency, lag, torque–speed curve).  ``run``: the tick
    acts (an idle tick keeps the state)."""
    lay = layout(c)
    update = (rs.tick % real.period) == 0
    cmd = jnp.where(update, tau, rs.held)
    delayed = rs.queue[jnp.clip(real.latency - 1, 0, MAX_LATENCY - 1)]
    applied = jnp.where(real.latency == 0, cmd, delayed)
    b = dt_c / (real.motor_lag + dt_c)
    motor = jnp.where(real.motor_lag > 0, rs.motor + b * (applied - rs.motor), applied)
    omega = jnp.asarray(lay.gear, tau.dtype) * qvel[lay.motor_dof]
    tau_max = jnp.asarray(np.abs(c.ctrl_range).max(axis=1), tau.dtype)
    out = motor_limit(real, motor, omega, tau_max, jnp.asarray(lay.no_load, tau.dtype))
    nxt = rs._replace(queue=jnp.concatenate([cmd[None], rs.queue[:-1]]), held=cmd, motor=motor,
                      tick=rs.tick + 1)
    return out, jax.tree.map(lambda a, b_: jnp.where(run, a, b_), nxt, rs)


def gravity(real: Realism, g):
    """Gravity (3,) [m/s²] of magnitude ``g`` in the frame of a ground plane that rises by α_x
    along its x axis and α_y along its y axis: −g n̂, n̂ ∝ (tan α_x, tan α_y, 1) (the world's
    vertical seen from the plane; (0, 0, −g) on level ground)."""
    t = jnp.tan(real.slope)
    n = jnp.concatenate([t, jnp.ones(1, t.dtype)])
    return -g * n / jnp.linalg.norm(n)


def plant_model(c: model.Cassie, real: Realism, mx):
    """The physics' MJX model: ``mx`` with the scenario's masses, pelvis COM, spring
    stiffness, friction and gravity (module doc)."""
    lay = layout(c)
    pelvis = c.index.pelvis_body
    ipos = mx.body_ipos.at[pelvis, :2].add(real.pelvis_com)
    stiff = mx.jnt_stiffness.at[lay.spring_jnt].multiply(real.stiffness_scale)
    fr = mx.geom_friction.at[lay.contact_geoms, 0].set(real.friction)
    g = float(-c.mj_model.opt.gravity[2])
    return mx.replace(body_mass=mx.body_mass * real.mass_scale,
                      body_subtreemass=mx.body_subtreemass * real.mass_scale,
                      body_inertia=mx.body_inertia * real.mass_scale, body_ipos=ipos,
                      jnt_stiffness=stiff, geom_friction=fr,
                      opt=mx.opt.replace(gravity=gravity(real, g)))
