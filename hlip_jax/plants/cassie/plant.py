"""The Cassie plant: MJX Cassie walking one step per call under the H-LIP stepping law and a
CLF-QP, behind the step-level interface of :mod:`hlip_jax.plants.base`.

One call of :func:`step` runs SSP⁻_k → SSP⁻_{k+1} as a ``lax.scan`` of the 1 kHz control tick
of :mod:`hlip_jax.plants.cassie.tick` (the controller, its stages and its phases are described
there): DSP for T_DSP, then SSP on the new stance foot ``1 − cmd.stance`` until the swing
foot's touchdown is detected.  SSP⁻_{k+1} is that touchdown, so a step lasts as long as the
robot took (the plant clock ``State.time`` advances by it; pushes act on that clock).

Step noise (``disturbance.noise_v``, ``disturbance.step_error``; the PRNG key of the state,
split once per step): a horizontal pelvis force F = M dv / (T_SSP + T_DSP) held over the step,
dv uniform in ±noise_v per world axis (M the robot's mass: it changes the COM velocity by
about dv over the step), and a landing-target offset uniform in ±step_error per world axis.

The number of ticks per step is static (``Params.ticks`` carries it as a shape) and covers the
longest step the tick allows (T_DSP + ``tick.LATE_SSP`` · T_SSP); ticks after the touchdown
are idle.  ``failed`` is set when the robot fell (:func:`tick.fell`) or its state is not finite.
"""

from __future__ import annotations

import functools

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from hlip_jax.plants.base import GROUND_KINDS
from hlip_jax.plants.cassie.mjx_import import mjx
from hlip_jax.plants import Plant
from hlip_jax.plants.base import StepCommand, StepResult, push_table
from hlip_jax.plants.cassie import clfqp, control, model, outputs, realism, terrain, tick

cassie = tick.cassie
#: ``fold_in`` index of the sensing noise's PRNG stream: far from the split indices (0, 1, 2)
#: of the step noise, which under JAX's partitionable threefry equal fold_in indices
SENSING_STREAM = 0x5E7501


class Gait(NamedTuple):
    """Per-scenario gait parameters (scalars; see :class:`hlip_jax.plants.cassie.config.CassieConfig` for
    meanings and units) and the CLF-QP gains they imply."""
    clearance: jax.Array
    strike: jax.Array
    reach: jax.Array
    freeze: jax.Array
    early_contact: jax.Array
    step_length_max: jax.Array
    step_width_min: jax.Array
    step_width_max: jax.Array
    damping: jax.Array         # (4,) simulated leaf-spring damping, left shin, left heel, right
                               # shin, right heel [N m s/rad]
    hold_unsolved: jax.Array   # 1.0: an unsolved CLF-QP keeps the previous torques, 0.0: last iterate
    from_stance: jax.Array     # 1.0: heights measured from the stance foot's sole, 0.0: from z = 0
    rho_previous: jax.Array    # 1.0: the CLF-QP starts from the previous tick's ADMM step size ρ,
                               # 0.0: from the solver's default
    gains: clfqp.Gains


_GAIT_CACHE: dict = {}


def make_gait(cfg=None) -> Gait:
    """:class:`Gait` (numpy) of a :class:`hlip_jax.plants.cassie.config.CassieConfig` (defaults if None).

    Output frequencies per row of :mod:`outputs`: pelvis orientation (0..2) ``omega_pelvis``,
    COM height (3) ``omega_height``, both feet's position and sole slope (6..13)
    ``omega_swing``, foot yaw (14, 15) ``omega_yaw``; rows 4, 5 (horizontal COM) are never
    active while walking (their frequency is the height's, for a well-defined CLF).  QP
    weights 1 except the pelvis rows (``weight_pelvis``); torque-change weight ``w_chatter``."""
    from hlip_jax.plants.cassie.config import CassieConfig

    cfg = CassieConfig() if cfg is None else cfg
    if cfg in _GAIT_CACHE:
        return _GAIT_CACHE[cfg]
    omega = np.array([cfg.omega_pelvis] * 3 + [cfg.omega_height] * 3 + [cfg.omega_swing] * 8
                     + [cfg.omega_yaw] * 2, float)
    weight = np.array([cfg.weight_pelvis] * 3 + [1.0] * 13, float)
    f = np.float64
    g = Gait(clearance=f(cfg.clearance), strike=f(cfg.strike), reach=f(cfg.reach),
             freeze=f(cfg.freeze), early_contact=f(cfg.early_contact),
             step_length_max=f(cfg.step_length_max), step_width_min=f(cfg.step_width_min),
             step_width_max=f(cfg.step_width_max),
             damping=np.array([cfg.shin_damping, cfg.heel_damping] * 2, float),
             hold_unsolved=f(cfg.qp_fallback == "hold"),
             from_stance=f(cfg.height_reference == "stance_foot"),
             rho_previous=f(cfg.qp_rho_start == "previous"),
             gains=clfqp.make_gains(omega, weight=weight, w_chatter=cfg.w_chatter))
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
    real: realism.Realism | None  # departures from the ideal plant (motors, sensing, model,
                                  # slope); None in a batch of ideal robots (not compiled)
    terrain: terrain.Terrain | None = None  # step or rough ground; None in a batch on flat ground


class State(NamedTuple):
    d: mjx.Data
    warm: tuple
    time: jax.Array          # plant clock at the current SSP⁻ [s]
    yaw: jax.Array           # pelvis heading target at the current SSP⁻ [rad]
    land_xy: jax.Array       # (2,) where the landing foot's centre was aimed [m]
    key: jax.Array
    real: realism.RealState | None  # what the non-ideal stages carry from step to step


def step_span(cfg) -> float:
    """Longest walking step [s] of a scenario before the late-touchdown limit scales it: T_DSP
    plus the swing profile's duration T_SSP / s* (:func:`tick.swing_duration`)."""
    s_star = landing_fraction(float(cfg.cassie.clearance), float(cfg.cassie.strike))
    return cfg.hlip.t_dsp + cfg.hlip.t_ssp / s_star


@functools.lru_cache(maxsize=4096)
def landing_fraction(clearance: float, strike: float) -> float:
    """:func:`outputs.landing_fraction` of one gait as a Python float, computed once per
    (clearance, strike): called eagerly, the bisection loop is compiled anew on every call
    (≈ 65 ms), which made building a sweep of 1024 scenarios take minutes."""
    return float(outputs.landing_fraction(clearance, strike))


def tick_budget(t_step: float) -> int:
    """Static 1 kHz ticks per step for steps whose :func:`step_span` is ≤ ``t_step`` [s]: room
    for the latest touchdown (T_DSP + LATE_SSP · swing duration ≤ LATE_SSP · t_step), rounded
    up to 10 ms (a batch uses the longest step of the sweep)."""
    return int(10 * math.ceil(round(tick.LATE_SSP * t_step / (10 * control.CONTROL_DT), 6)))


def make_params(cfg, n_push: int, t_step: float = 0.0, non_ideal: bool = False,
                ground: str = "flat") -> Params:
    """Per-scenario plant data from a :class:`hlip_jax.simulation.config.ScenarioConfig`; pushes act on
    the pelvis (force and direction of each :class:`hlip_jax.simulation.config.PushConfig`).  The tick
    budget covers steps of ``max(t_step, step_span(cfg))`` (pass the sweep's longest span so
    that every chunk has one shape).  ``non_ideal``: the batch has a robot that departs from
    the ideal plant (``cfg.realism``), so every robot carries realism data; otherwise none
    does, and a scenario that departs is an error.  ``ground``: the batch's ground kind
    (:data:`hlip_jax.plants.base.GROUND_KINDS`; "step": every robot walks on the scene with the terrain block,
    "rough": with the block and the height field)."""
    if not non_ideal and cfg.realism != type(cfg.realism)():
        raise ValueError(f"realism: scenario {cfg.name!r} departs from the ideal plant; build "
                         "it with non_ideal=True (arrays.shapes_of sets it for the batch)")
    need = cfg.realism.ground_kind()
    if GROUND_KINDS.index(need) > GROUND_KINDS.index(ground):
        f = "rough_height" if need == "rough" else "step_height"
        raise ValueError(f"realism.{f}: scenario {cfg.name!r} has uneven ground; build it "
                         f"with ground in {GROUND_KINDS[GROUND_KINDS.index(need):]} "
                         "(arrays.shapes_of sets it)")
    start, end, force = push_table(cfg.disturbance.pushes, n_push)
    ticks = np.zeros(tick_budget(max(t_step, step_span(cfg))))
    return Params(push_start=start, push_end=end, push_force=force, ticks=ticks,
                  gait=make_gait(cfg.cassie), noise_v=np.float64(cfg.disturbance.noise_v),
                  step_error=np.float64(cfg.disturbance.step_error),
                  real=realism.make(cfg.realism) if non_ideal else None,
                  terrain=terrain.make(cfg.realism.step_height, cfg.realism.step_x,
                                       cfg.realism.rough_height, cfg.seed, ground == "rough")
                  if ground != "flat" else None)


def init(params: Params, x0, u0, stance0, key, heading0=0.0) -> State:
    """Cassie at the "stand" keyframe, turned by ``heading0`` [rad] about the vertical through
    its COM and shifted so the COM is at x0's c (per plane).

    The robot starts facing along the path (``heading0`` is the path's heading at t = 0), so a
    path that leaves the origin at an angle does not begin with a turn.  Both feet are on the
    ground, so the first step's DSP starts from rest; u0 and stance0 are implied by the pose
    (left foot 0.26 m left of the right one)."""
    del u0, stance0
    c = cassie()
    m, mx = ((c.mj_model, c.mjx_model) if params is None or params.terrain is None
             else terrain.scene_of(params.terrain))
    dm = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, dm, c.index.stand_key)
    mujoco.mj_forward(m, dm)
    com = dm.subtree_com[c.index.pelvis_body].copy()
    d = mjx.put_data(m, dm, impl=c.mjx_model.impl)
    dt = x0.dtype
    d = _floats_as(d, dt)
    # root pose: position rotated about the COM, orientation q ← q_z(θ0) ⊗ q (MuJoCo w, x, y, z)
    th = jnp.asarray(heading0, dt)
    ch, sh = jnp.cos(th), jnp.sin(th)
    r0 = c.index.root_qpos
    px, py, pz, w, qx, qy, qz = (d.qpos[r0 + i] for i in range(7))
    rx, ry = px - com[0], py - com[1]
    hw, hz = jnp.cos(th / 2), jnp.sin(th / 2)
    root = jnp.stack([x0[0, 0] + ch * rx - sh * ry, x0[1, 0] + sh * rx + ch * ry, pz,
                      hw * w - hz * qz, hw * qx - hz * qy, hw * qy + hz * qx, hw * qz + hz * w])
    d = control.canonical(c, d.replace(qpos=d.qpos.at[r0:r0 + 7].set(root)), mx)
    terms = model.robot_terms(c, d)
    feet = outputs.foot_centres(terms)
    real = None if params is None or params.real is None else \
        realism.init_state(c.index.nu, terms.com_vel, jax.random.fold_in(key, SENSING_STREAM), dt)
    return State(d=d, warm=control.warm_zeros(c, dt), time=jnp.zeros((), dt),
                 yaw=outputs.wrap(th), land_xy=feet[0, :2], key=key, real=real)


def measure(params: Params, state: State, stance) -> jax.Array:
    """The robot's S2S state [c, p, v] (2, 3) in ``state``: the COM and its velocity, p from the
    ``stance`` foot's ankle pivot (:func:`tick.robot_state`), on the controller's model.  At the
    start (standing on both feet, stance the right foot) p is the COM's offset from the right
    ankle, not the H-LIP's start."""
    del params
    return tick.robot_state(model.robot_terms(cassie(), state.d), stance)[0]


def _floats_as(tree, dt):
    """``tree`` with its floating leaves in dtype ``dt`` (integer and bool leaves as they are)."""
    return jax.tree.map(lambda a: jnp.asarray(a, dt) if jnp.issubdtype(jnp.asarray(a).dtype, jnp.floating)
                        else a, tree)


def _step_noise(params: Params, state: State, t_step, dt):
    """(next key, pelvis force (2,) [N], landing-target error (2,) [m]) of this step."""
    key, k_v, k_u = jax.random.split(state.key, 3)
    dv = jax.random.uniform(k_v, (2,), dt, -1.0, 1.0) * jnp.asarray(params.noise_v, dt)
    du = jax.random.uniform(k_u, (2,), dt, -1.0, 1.0) * jnp.asarray(params.step_error, dt)
    return key, jnp.asarray(cassie().total_mass, dt) * dv / t_step, du


def _physics_model(gait, real, physics: str, ground=None):
    """(the controller's MJX-JAX model, the physics' model in MJX-JAX, the physics' model in
    the implementation ``physics`` steps it with): leaf-spring damping, then the realism
    edits, applied alike to either implementation's base model; with a ``ground``
    (:class:`terrain.Terrain`) the physics steps the scene with the terrain block (MJX-JAX
    only: the sweep validator keeps steps off the Warp physics)."""
    def edited(base, damping, real):
        mx = tick.scenario_model(damping, base)
        return mx, (mx if real is None else realism.plant_model(cassie(), real, mx))

    mx, mx_plant = edited(None, gait.damping, real)
    if ground is not None:
        return mx, mx_plant, terrain.place(edited(terrain.scene_of(ground)[1], gait.damping,
                                                  real)[1], ground)
    if physics == "jax":
        return mx, mx_plant, mx_plant
    from hlip_jax.plants.cassie import warp_physics
    f32 = lambda tree: _floats_as(tree, jnp.float32)          # Warp's model is float32
    return mx, mx_plant, edited(warp_physics.base_model(cassie().mj_model), f32(gait.damping),
                                f32(real))[1]


def _context(params: Params, state: State, cmd: StepCommand, f_noise, du_err,
             physics: str = "jax") -> tick.Context:
    dt = state.d.qpos.dtype
    gait = jax.tree.map(lambda a: jnp.asarray(a, dt), params.gait)
    ctrl = cassie().ctrl_range
    real = _floats_as(params.real, dt)
    ground = _floats_as(params.terrain, dt)
    mx, mx_plant, mx_physics = _physics_model(gait, real, physics, ground)
    return tick.Context(
        cmd=cmd, gait=gait, mx=mx, mx_plant=mx_plant, mx_physics=mx_physics, real=real,
        terrain=ground,
        new_st=1 - cmd.stance,
        sw=cmd.stance, yaw_from=state.yaw, dyaw=outputs.wrap(cmd.heading - state.yaw),
        land_xy=state.land_xy, f_noise=f_noise, du_err=du_err, t0=state.time,
        push_start=jnp.asarray(params.push_start, dt), push_end=jnp.asarray(params.push_end, dt),
        push_force=jnp.asarray(params.push_force, dt), tau_lo=jnp.asarray(ctrl[:, 0], dt),
        tau_hi=jnp.asarray(ctrl[:, 1], dt))


def _first_tick(ctx: tick.Context, state: State) -> tick.TickState:
    """The tick carry at SSP⁻_k (the swing foot's lift-off pose is recorded by the first SSP
    tick, :func:`tick.lift_off`)."""
    dt = state.d.qpos.dtype
    zero = jnp.zeros((), dt)
    return tick.TickState(d=state.d, warm=state.warm,
                          phase=jnp.where(ctx.cmd.t_dsp > 0, tick.DSP, tick.SSP).astype(jnp.int32),
                          t_phase=zero, t_step=zero, sw_start=jnp.zeros(3, dt), sw_yaw0=zero,
                          sw_offset=jnp.zeros(2, dt), u_last=ctx.cmd.u_hlip_next,
                          touch=jnp.zeros((), jnp.int32),
                          fell=~jnp.asarray(ctx.cmd.live, bool),   # a dead step idles throughout
                          gap=jnp.full(2, jnp.inf, dt), real=state.real)


def _prepare(params: Params, state: State, cmd: StepCommand, physics: str = "jax"):
    """(cmd in the state's dtype, next PRNG key, step-noise landing error, tick context)."""
    dt = state.d.qpos.dtype
    cmd = _floats_as(cmd, dt)
    key, f_noise, du_err = _step_noise(params, state, cmd.t_ssp + cmd.t_dsp, dt)
    return cmd, key, du_err, _context(params, state, cmd, f_noise, du_err, physics)


def _finish(state: State, cmd: StepCommand, ctx: tick.Context, s: tick.TickState, key, du_err,
            terms_impl: str):
    """(plant state at SSP⁻_{k+1}, StepResult) from the last tick state of the step (the
    true state, on the physics' own model: a pelvis COM error moves the COM it reports).
    ``terms_impl``: how the whole-body terms are computed (:class:`tick.Settings`' ``terms``),
    as the controller's ticks compute them."""
    terms = model.robot_terms(cassie(), s.d, ctx.mx_plant, terms_impl)
    x_r, st_xy = tick.robot_state(terms, ctx.new_st)
    sw_xy = jnp.where(ctx.sw == 0, terms.ankle[0, :2], terms.ankle[1, :2])
    failed = s.fell | ~jnp.all(jnp.isfinite(x_r))
    x_est = x_r if ctx.real is None else _estimated_state(ctx, s, terms_impl)
    new = State(d=s.d, warm=s.warm, time=state.time + s.t_step,
                yaw=outputs.wrap(cmd.heading), land_xy=st_xy + s.u_last + s.sw_offset + du_err,
                key=key, real=s.real)
    return new, StepResult(x_robot=x_r, x_est=x_est, u_robot=sw_xy - st_xy, failed=failed,
                           duration=s.t_step, leg_gap=s.gap)


def _estimated_state(ctx: tick.Context, s: tick.TickState, terms_impl: str):
    """[c, p, v] per plane (2, 3) at SSP⁻_{k+1} as the non-ideal robot's controller has it:
    the measurement and velocity estimate that the next tick's ``sense`` and ``estimate``
    stages make from this state (the same noise key and filter state), on the controller's
    model.  With exact sensing, no filter and no model error this is the true state."""
    c = cassie()
    dm, _ = realism.sense(c, ctx.real, s.real, s.d)
    terms = tick.measure(ctx, dm, terms_impl)
    est = realism.estimate_velocity(ctx.real, s.real, terms.com_vel, control.CONTROL_DT)
    x, _ = tick.robot_state(terms, ctx.new_st)
    return x.at[:, 2].set(est.v_est[:2])


def step_with_log(params: Params, state: State, cmd: StepCommand,
                  settings: tick.Settings = tick.Settings()):
    """:func:`step` that also returns the per-tick log (:class:`tick.TickLog`, one row per
    tick of the static budget; the rows after the step's end repeat its final state)."""
    cmd, key, du_err, ctx = _prepare(params, state, cmd, settings.physics)
    s, log = jax.lax.scan(lambda s, _: tick.tick(ctx, s, settings), _first_tick(ctx, state),
                          None, length=params.ticks.shape[0])
    return (*_finish(state, cmd, ctx, s, key, du_err, settings.terms), log)


def step(params: Params, state: State, cmd: StepCommand,
         settings: tick.Settings = tick.Settings()):
    """One walking step SSP⁻_k → SSP⁻_{k+1} (module doc); ``settings`` (static,
    :class:`tick.Settings`): the CLF-QP's ADMM settings and the physics' implementation.
    Returns (state, StepResult).

    The ticks run in a ``lax.while_loop`` that ends when the step is over (touchdown, late
    limit or fall: :func:`tick.running` false) or at the static budget.  A tick that does not
    run leaves its state as it is (:func:`tick.advance`), so the result is that of the
    fixed-length scan of :func:`step_with_log`; but a vmapped batch stops at its slowest
    robot's touchdown instead of paying the whole budget (T_DSP + 1.2 T_SSP) every step."""
    cmd, key, du_err, ctx = _prepare(params, state, cmd, settings.physics)
    budget = params.ticks.shape[0]

    def body(carry):
        i, s = carry
        return i + 1, tick.tick(ctx, s, settings)[0]

    def more(carry):
        i, s = carry
        return (i < budget) & tick.running(s)

    _, s = jax.lax.while_loop(more, body, (jnp.zeros((), jnp.int32), _first_tick(ctx, state)))
    return _finish(state, cmd, ctx, s, key, du_err, settings.terms)


def settings(cfg, robots: int = 1) -> tick.Settings:
    """The tick's static settings of a scenario simulated in a batch of ``robots``: the
    CLF-QP's ADMM settings (``cassie.qp_max_iter``, ``qp_eps``, ``impl.qp_loop``,
    ``qp_linsys``, ``qp_kernel``), the condensation's solve (``impl.condense``), how the whole-body terms
    are computed (``impl.terms``), the physics' implementation (``impl.physics``; "warp"
    raises ``ValueError`` where warp-lang is missing) and the batch size (Warp's contact
    buffer holds the whole batch's contacts)."""
    if cfg.impl.physics == "warp":
        from hlip_jax.plants.cassie import warp_physics
        warp_physics.require()
    qp_settings = clfqp.DEFAULT_SETTINGS._replace(
        max_iter=cfg.cassie.qp_max_iter, eps_abs=cfg.cassie.qp_eps, eps_rel=cfg.cassie.qp_eps,
        early_exit=cfg.impl.qp_loop != "fixed", linsys=cfg.impl.qp_linsys,
        block_kernel=cfg.impl.qp_kernel)
    return tick.Settings(qp=qp_settings, qp_compact=cfg.impl.qp_loop == "compact",
                         physics=cfg.impl.physics, robots=int(robots),
                         condense=cfg.impl.condense, terms=cfg.impl.terms)


PLANT = Plant(name="cassie", make_params=make_params, init=init, measure=measure,
              step=step, step_with_log=step_with_log, step_span=step_span, settings=settings)
