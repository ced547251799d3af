"""The closed loop: MPC on the H-LIP → stepping law → plant, scanned over walking steps and
vmapped over scenarios.

Timeline of step k (t_k = k T, T = T_SSP + T_DSP of the planner's H-LIP):

1. at SSP⁻_k the H-LIP is at x_H,k and places u_H,k; the robot is at x_R,k and places u_R,k;
2. the H-LIP's next pre-impact state is known: x_H,k+1 = A x_H,k + B u_H,k  (``mode="tube"``;
   with ``mode="position"`` the nominal's c first restarts from the robot's c_R,k; with
   ``mode="measured"`` the whole nominal is re-anchored on the robot: x_H,k+1 = A x_R,k + B u_R,k);
3. the MPC plans u_H,k+1 … u_H,k+N from x_H,k+1 with the path preview at t_{k+1} + jT
   (warm-started from the previous plan, obstacles re-linearised there);
4. the plant walks SSP⁻_k → SSP⁻_{k+1} and chooses u_R,k+1 = u_H,k+1 + K (x_R,k+1 − x_H,k+1).

So e_k = x_R,k − x_H,k obeys e_{k+1} = (A + BK) e_k + w_k with w_k = x_R,k+1 − A x_R,k − B u_R,k
(the robot's S2S residual against the H-LIP) in the tube; the anchored modes change the
closed-loop matrix (:func:`hlip_jax.invariant.closed_loop`).  Before the loop the MPC plans
u_H,0 from x_H,0.
The log's ``t`` is the planner's t_k; ``t_plant`` is the plant's own clock at SSP⁻_k (a Cassie
step ends at its detected touchdown, so its steps need not last T).

A scenario whose QP fails keeps walking on its previous plan (shifted) and counts the failure;
a robot that falls is frozen from that step on and marked; neither touches other scenarios.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
from typing import NamedTuple, Optional, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from hlip_jax import hlip, mpc, paths, progress, qp, robust, s2s_model, trace_cache
from hlip_jax.config import (GROUND_KINDS, STATIC_FIELDS, RealismConfig, ScenarioConfig,
                             field_value)
from hlip_jax import plants
from hlip_jax.plants.base import StepCommand
from hlip_jax.steplog import STATUS_FELL, STATUS_NONFINITE, STATUS_OK, STATUS_QP_FAILED, Log

STANCE_LEFT, STANCE_RIGHT = 0, 1

#: mpc.mode -> which of the nominal's [c, p, v] restart from the robot's state before every plan
#: (the log's ``anchor``; the error system it gives: :func:`hlip_jax.invariant.closed_loop`)
ANCHOR = {"tube": np.zeros(3, np.float32), "measured": np.ones(3, np.float32),
          "position": np.array([1.0, 0.0, 0.0], np.float32)}


class Scenario(NamedTuple):
    """Batched per-scenario data (leading axis = scenarios)."""
    mpc: mpc.MPCParams
    path: paths.Path
    gain: jax.Array       # (2, 3)
    z0: jax.Array
    t_ssp: jax.Array
    t_dsp: jax.Array
    x0: jax.Array         # (2, 3) initial state (robot and H-LIP)
    n_steps: jax.Array    # steps to simulate (≤ the static K)
    anchor: jax.Array     # (3,) 1 where the nominal [c, p, v] restarts from the robot's each step
    plant: object         # the plant's params pytree
    key: jax.Array


class Static(NamedTuple):
    """Shapes and solver settings: one compile per distinct value."""
    n_steps: int
    horizon: int
    settings: qp.Settings
    plant: str
    viability: bool = False                        # the MPC's viability rows (mpc.viability)
    plant_settings: Optional[object] = None   # the plant's static settings (Cassie: tick.Settings)
    keep_ticks: bool = False                       # also return the plant's per-tick log
    progress: bool = False                         # report each finished step (progress.py)


# ----------------------------------------------------------------------------------------------
# configs → arrays

def stepping_gain(cfg: ScenarioConfig) -> np.ndarray:
    """K (2, 3) per plane on [c, p, v]; the c entry is zero for a 2-state gain.  Designed on
    the scenario's S2S map (:func:`s2s_of`)."""
    return _cached_gain(cfg.hlip, cfg.gain, cfg.s2s).copy()


def s2s_of(cfg: ScenarioConfig) -> tuple[np.ndarray, np.ndarray]:
    """(A (3, 3), B (3,)) on [c, p, v] of the scenario's S2S map: the H-LIP's, or the
    identified model of ``s2s.file`` lifted (:func:`hlip_jax.s2s_model.lifted`)."""
    if cfg.s2s.model == "identified":
        return _cached_identified(cfg.s2s.file)
    return _cached_s2s(cfg.hlip)


@functools.lru_cache(maxsize=64)
def _cached_identified(path: str) -> tuple[np.ndarray, np.ndarray]:
    return s2s_model.lifted(s2s_model.read(path))


def _stepping_gain(h, g, s) -> np.ndarray:
    plane_gain = (_plane_gain if s.model == "hlip" else
                  functools.partial(_model_gain, *_cached_identified(s.file)))
    K = plane_gain(h, g)
    if g.lateral == "deadbeat" and g.type != "deadbeat":
        K[1] = plane_gain(h, dataclasses.replace(g, type="deadbeat"))[1]
    return K


def _model_gain(A3, B3, h, g) -> np.ndarray:
    """The gain of design ``g`` on an identified map (A3, B3): deadbeat by Ackermann's
    placement (every eigenvalue of A + BK at zero), LQR by the Riccati equation; on [p, v]
    alone without ``g.with_position``."""
    A, B = (A3, B3) if g.with_position else (A3[1:, 1:], B3[1:])
    if g.type == "deadbeat":
        k = hlip.place_gain_ackermann(jnp.asarray(A), jnp.asarray(B))
    else:
        q = [g.q_c, g.q_p, g.q_v] if g.with_position else [g.q_p, g.q_v]
        k = hlip.lqr_gain(A, B, jnp.diag(jnp.array(q)), jnp.array(g.r))
    k = np.asarray(k, np.float64)
    return np.tile(k if g.with_position else np.concatenate([[0.0], k]), (2, 1))


def _plane_gain(h, g) -> np.ndarray:
    if g.with_position:
        if g.type == "deadbeat":
            k = hlip.deadbeat_gain(h.z0, h.t_ssp, h.t_dsp, h.g, with_position=True)
        else:
            A, B = hlip.s2s_matrices(h.z0, h.t_ssp, h.t_dsp, h.g, with_position=True)
            k = hlip.lqr_gain(A, B, jnp.diag(jnp.array([g.q_c, g.q_p, g.q_v])), jnp.array(g.r))
        k = np.asarray(k, np.float64)
    else:
        if g.type == "deadbeat":
            k = hlip.deadbeat_gain(h.z0, h.t_ssp, h.t_dsp, h.g)
        else:
            A, B = hlip.s2s_matrices(h.z0, h.t_ssp, h.t_dsp, h.g, with_position=False)
            k = hlip.lqr_gain(A, B, jnp.diag(jnp.array([g.q_p, g.q_v])), jnp.array(g.r))
        k = np.concatenate([[0.0], np.asarray(k, np.float64)])
    return np.tile(k, (2, 1))


def tube_of(cfg: ScenarioConfig, A, B) -> robust.Tightening:
    """The MPC's tube tightening (:mod:`hlip_jax.robust`): none unless ``mpc.robust``."""
    m = cfg.mpc
    if not m.robust:
        return robust.NONE
    w = np.array([[m.w_c_1, m.w_p_1, m.w_v_1], [m.w_c_2, m.w_p_2, m.w_v_2]])
    hull = robust.read_hull(m.w_hull_file) if m.w_shape == "hull" else None
    return robust.tightening(A, B, stepping_gain(cfg), w, m.w_frame, hull)


def n_steps_of(cfg: ScenarioConfig) -> int:
    return int(math.ceil(cfg.duration / (cfg.hlip.t_ssp + cfg.hlip.t_dsp) - 1e-9))


def _freeze(v):
    if isinstance(v, dict):
        return tuple(sorted((k, _freeze(x)) for k, x in v.items()))
    if isinstance(v, (list, tuple)):
        return tuple(_freeze(x) for x in v)
    return v


@functools.lru_cache(maxsize=4096)
def _cached_path(shape: str, frozen: tuple) -> paths.Path:
    params = {k: (list(map(list, v)) if isinstance(v, tuple) else v) for k, v in frozen}
    return jax.tree.map(np.asarray, paths.make_path(shape, **params))


def _path_of(cfg: ScenarioConfig, t_final: float, n_samples: int) -> paths.Path:
    """The path table of a scenario (memoised: a sweep repeats the same paths many times).
    The table length and time span are set by the batch so every path has the same shape."""
    params = dict(cfg.path.params)
    params["t_final"] = t_final
    params["n_samples"] = n_samples
    return _cached_path(cfg.path.shape, _freeze(params))


@functools.lru_cache(maxsize=4096)
def _cached_s2s(h) -> tuple[np.ndarray, np.ndarray]:
    A, B = hlip.s2s_matrices(h.z0, h.t_ssp, h.t_dsp, h.g)
    return np.asarray(A, np.float64), np.asarray(B, np.float64)


@functools.lru_cache(maxsize=4096)
def _cached_gain(hlip_cfg, gain_cfg, s2s_cfg) -> np.ndarray:
    return _stepping_gain(hlip_cfg, gain_cfg, s2s_cfg)


def default_dtype():
    """float64 where JAX has x64 enabled (CPU runs, tests), else float32 (GPU)."""
    return jnp.float64 if jax.config.jax_enable_x64 else jnp.float32


class Shapes(NamedTuple):
    """Array sizes of a batch.  Chunks of one sweep built with the sweep-wide ``shapes_of``
    share one compile."""
    n_steps: int
    n_obstacles: int
    n_pushes: int
    t_final: float
    t_step: float = 0.0      # longest step span [s] (Plant.step_span; the Cassie tick budget)
    non_ideal: bool = False  # a scenario departs from the ideal robot (``realism``): every
                             # robot of the batch carries the realism data (compiled in)
    terrain: str = "flat"    # the batch's ground: "rough" if a scenario has rough ground
                             # (``realism.rough_height``), else "step" if one has a step
                             # (``realism.step_height``), else "flat"; every robot of the batch
                             # walks on that scene (:mod:`hlip_jax.plants.cassie.terrain`)


def shapes_of(configs: Sequence[ScenarioConfig]) -> Shapes:
    """The smallest shapes that fit every scenario of ``configs``."""
    K = max(n_steps_of(c) for c in configs)
    horizon = max(c.mpc.horizon for c in configs)
    return Shapes(
        n_steps=K,
        n_obstacles=max((len(c.obstacles) for c in configs), default=0),
        n_pushes=max(1, max(len(c.disturbance.pushes) for c in configs)),
        t_final=max((K + horizon + 2) * (c.hlip.t_ssp + c.hlip.t_dsp) for c in configs),
        t_step=max(_step_span(c) for c in configs),
        non_ideal=any(c.realism != RealismConfig() for c in configs),
        terrain=max((c.realism.ground_kind() for c in configs), key=GROUND_KINDS.index,
                    default="flat"))


def _step_span(c: ScenarioConfig) -> float:
    """Longest step of one scenario [s], as its plant counts it (:attr:`plants.Plant.step_span`)."""
    return plants.load(c.plant).step_span(c)


def build(configs: Sequence[ScenarioConfig], *, n_samples: int = 2048, dtype=None,
          shapes: Shapes | None = None):
    """Validated configs → (Scenario batch, Static).  The horizon, the QP settings and the
    plant must agree across the batch (they are shapes / static settings).  ``shapes``
    (default: :func:`shapes_of` the batch) must fit every scenario."""
    if not configs:
        raise ValueError("build: no scenarios")
    first = configs[0]
    for c in configs:
        for name in STATIC_FIELDS:
            a, b = field_value(c, name), field_value(first, name)
            if a != b:
                raise ValueError(f"{name} must be the same for every scenario of a batch "
                                 f"(it fixes shapes/compiled settings): got {a!r} and {b!r}")
    need = shapes_of(configs)
    shapes = shapes or need
    for f in Shapes._fields:
        if getattr(shapes, f) < getattr(need, f):
            raise ValueError(f"shapes.{f} = {getattr(shapes, f)} is smaller than the batch needs "
                             f"({getattr(need, f)})")
    K, t_final = shapes.n_steps, shapes.t_final
    n_obs, n_push = shapes.n_obstacles, shapes.n_pushes
    horizon = first.mpc.horizon

    rows = []
    for c in configs:
        A, B = s2s_of(c)
        obs = np.zeros((n_obs, 4))
        act = np.zeros(n_obs, bool)
        for i, o in enumerate(c.obstacles):
            obs[i] = (o.x, o.y, o.radius + o.margin, o.radius)
            act[i] = True
        m = c.mpc
        mp = mpc.MPCParams(A=np.asarray(A), B=np.asarray(B), w_pos=m.w_pos, w_vel=m.w_vel,
                           alpha=m.alpha, length_min=m.step_length_min,
                           length_max=m.step_length_max, width_min=m.step_width_min,
                           width_max=m.step_width_max, obstacle_weight=m.obstacle_weight,
                           obstacles=obs, obstacle_active=act, **tube_of(c, A, B)._asdict())
        path = _path_of(c, t_final, n_samples)
        start = np.array([float(path.x[0]), float(path.y[0])])
        x0 = np.stack([np.array([start[0], 0.0, 0.0]), np.array([start[1], 0.0, 0.0])])
        plant = plants.load(c.plant).make_params(c, n_push, shapes.t_step, shapes.non_ideal,
                                                 shapes.terrain)
        rows.append(Scenario(mpc=mp, path=path, gain=stepping_gain(c), z0=c.hlip.z0,
                             t_ssp=c.hlip.t_ssp, t_dsp=c.hlip.t_dsp, x0=x0,
                             n_steps=np.int32(n_steps_of(c)), anchor=ANCHOR[m.mode],
                             plant=plant, key=None))
    batch = jax.tree.map(lambda *a: np.stack([np.asarray(x) for x in a]), *rows)
    batch = batch._replace(key=_keys([c.seed for c in configs]))

    dtype = dtype or default_dtype()

    def cast(x):
        x = np.asarray(x)
        return x.astype(dtype) if np.issubdtype(x.dtype, np.floating) else x

    batch = jax.tree.map(cast, batch)
    settings = qp.Settings(eps_abs=first.mpc.qp_eps, eps_rel=first.mpc.qp_eps,
                           max_iter=first.mpc.qp_max_iter, check_interval=25,
                           adaptive_rho_interval=50)
    plant_settings = plants.load(first.plant).settings(first, len(configs))
    return batch, Static(n_steps=K, horizon=horizon, settings=settings, plant=first.plant,
                         viability=first.mpc.viability,
                         plant_settings=plant_settings)


# ----------------------------------------------------------------------------------------------
# the loop

def _keys(seeds: Sequence[int]) -> np.ndarray:
    """Every scenario's PRNG key data, ``jax.random.PRNGKey(seed)`` of each seed, in one call
    (one call per scenario took a quarter of building 2048 Cassie scenarios)."""
    return np.asarray(jax.random.key_data(jax.vmap(jax.random.PRNGKey)(np.asarray(seeds, np.int64))))


def _preview(path, t_start, T, N):
    """Path preview for a plan from time t_start: targets at t_start + jT (j = 1..N),
    headings at the step instants t_start + jT (j = 0..N-1)."""
    times = t_start + T * jnp.arange(N + 1, dtype=T.dtype)
    ref = jax.vmap(lambda t: paths.reference(path, t))(times)
    return mpc.Preview(pos=ref.position[1:], vel=ref.velocity[1:], heading=ref.heading[:-1])


def _plan(scn: Scenario, static: Static, x_start, t_start, stance, prev_plan, step):
    """One MPC solve from the H-LIP state ``x_start`` at ``t_start`` (absolute step ``step``),
    warm-started from ``prev_plan``; on failure the previous plan shifted by one step.
    Returns (plan, solved)."""
    N, O = static.horizon, scn.mpc.obstacles.shape[0]
    prev = _preview(scn.path, t_start, scn.t_ssp + scn.t_dsp, N)
    prev_c = prev_plan.states[:, :, 0]
    ws = mpc.shift_warm_start(prev_plan, N, O)
    new = mpc.solve(scn.mpc, x_start, prev, stance, prev_c, static.settings, warm_start=ws,
                    step0=step, viability=static.viability)
    ok = (new.status == qp.SOLVED) | (new.status == qp.SOLVED_INACCURATE)
    ok = ok & jnp.all(jnp.isfinite(new.u))
    shifted_u = jnp.concatenate([prev_plan.u[1:], prev_plan.u[-1:]])
    u = jnp.where(ok, new.u, shifted_u)
    result = new._replace(u=u, states=mpc.predict(scn.mpc, x_start, u),
                          z=jnp.where(ok, new.z, ws[0]), y=jnp.where(ok, new.y, ws[1]))
    return result, ok


def _cold_plan(scn: Scenario, N: int, viability: bool) -> mpc.Plan:
    """The 'previous plan' of the first solve: resting on the start, zero warm start (sized
    for the MPC's QP, :func:`hlip_jax.mpc.build_qp`)."""
    O, dt = scn.mpc.obstacles.shape[0], scn.x0.dtype
    n_var, n_con = 2 * N + O + int(viability), 2 * N + N * O + O + (2 * N + 1) * int(viability)
    return mpc.Plan(u=jnp.zeros((N, 2), dt), states=jnp.broadcast_to(scn.x0, (N, 2, 3)),
                    slack=jnp.zeros((), dt), z=jnp.zeros((n_var,), dt),
                    y=jnp.zeros((n_con,), dt), status=jnp.int32(1), iterations=jnp.int32(0))


def _finish(out: dict, ok0) -> dict:
    """Per-run status and first failed step from the per-step flags; e = x_R − x_H."""
    failed_steps = out.pop("failed_now")
    nonfinite = out.pop("nonfinite")
    qp_failed = out.pop("qp_failed")
    any_fail = jnp.any(failed_steps)
    fail_step = jnp.where(any_fail, jnp.argmax(failed_steps), -1)
    status = jnp.where(jnp.any(nonfinite), STATUS_NONFINITE,
                       jnp.where(any_fail, STATUS_FELL,
                                 jnp.where(jnp.any(qp_failed) | ~ok0, STATUS_QP_FAILED, STATUS_OK)))
    # w_k needs the robot at k+1: valid only when step k+1 is valid too
    out["e"] = out["x_robot"] - out["x_hlip"]
    out["status"] = status
    out["fail_step"] = fail_step
    return out


class Carry(NamedTuple):
    """The closed loop's scan carry at SSP⁻_k (see the module doc for the timeline)."""
    x_h: jax.Array        # (2, 3) H-LIP state
    u_h: jax.Array        # (2,) H-LIP step placed at SSP⁻_k [m]
    x_r: jax.Array        # (2, 3) robot state
    x_e: jax.Array        # (2, 3) robot state as its controller estimated it
    u_r: jax.Array        # (2,) robot step placed at SSP⁻_k [m]
    plan: mpc.Plan        # the MPC plan that chose u_h
    pstate: object        # the plant's state
    alive: jax.Array      # bool: not fallen
    qp_ok: jax.Array      # bool: every MPC solve so far succeeded
    t_plant: jax.Array    # the plant's clock [s]


def _plant_step(plant, scn: Scenario, static: Static, pstate, cmd):
    """One walking step of the plant: (state, StepResult, per-tick log or None)."""
    if static.keep_ticks:
        return plant.step_with_log(scn.plant, pstate, cmd, static.plant_settings)
    if static.plant_settings is None:
        return (*plant.step(scn.plant, pstate, cmd), None)
    return (*plant.step(scn.plant, pstate, cmd, static.plant_settings), None)


def _start(scn: Scenario, static: Static):
    """The loop's carry at SSP⁻_0 and whether the first plan solved: the MPC plans u_H,0..
    from x_H,0 (a cold start: the previous plan rests on the start) and the plant starts."""
    plant = plants.load(static.plant)
    dt = scn.x0.dtype
    stance0 = jnp.int32(STANCE_RIGHT)
    plan0, ok0 = _plan(scn, static, scn.x0, jnp.zeros((), dt), stance0,
                       _cold_plan(scn, static.horizon, static.viability), 0)
    u_h0 = plan0.u[0]
    u_r0 = u_h0          # the first step is the plan's: the robot starts standing
    heading0 = paths.reference(scn.path, jnp.zeros((), dt)).heading
    pstate = plant.init(scn.plant, scn.x0, u_r0, stance0, scn.key, heading0)
    x_r0 = jnp.asarray(plant.measure(scn.plant, pstate, stance0), dt)   # measured, not x_H,0
    carry0 = Carry(x_h=scn.x0, u_h=u_h0, x_r=x_r0, x_e=x_r0, u_r=u_r0, plan=plan0, pstate=pstate,
                   alive=jnp.bool_(True), qp_ok=ok0, t_plant=jnp.zeros((), dt))
    return carry0, ok0


def _step(scn: Scenario, static: Static, carry: Carry, k):
    """Walking step k of the module doc's timeline: (carry at SSP⁻_{k+1}, the step's log row).
    A step at or beyond the scenario's ``n_steps``, or of a fallen robot, is not active: it
    leaves the carry as it is and its row is marked invalid."""
    plant = plants.load(static.plant)
    A, B = scn.mpc.A, scn.mpc.B
    dt = scn.x0.dtype
    T = scn.t_ssp + scn.t_dsp
    t_k = k.astype(dt) * T
    stance_k = (STANCE_RIGHT + k) % 2
    active = carry.alive & (k < scn.n_steps)
    # 2. the nominal's next pre-impact state
    x_h_next = _nominal_next(scn, carry)
    # 3. plan from it
    new_plan, ok = _plan(scn, static, x_h_next, t_k + T, 1 - stance_k, carry.plan, k + 1)
    u_h_next = new_plan.u[0]
    # 4. the plant walks one step
    heading_next = paths.reference(scn.path, t_k + T).heading
    cmd = StepCommand(t=t_k, stance=stance_k, x_hlip=carry.x_h, u_hlip=carry.u_h,
                      x_hlip_next=x_h_next, u_hlip_next=u_h_next, gain=scn.gain,
                      heading=heading_next, t_ssp=scn.t_ssp, t_dsp=scn.t_dsp, z0=scn.z0,
                      live=active)
    pnext, res, ticks = _plant_step(plant, scn, static, carry.pstate, cmd)
    ref = paths.reference(scn.path, t_k)
    obs = scn.mpc.obstacles
    gap = jnp.linalg.norm(carry.x_r[:, 0][None, :] - obs[:, :2], axis=-1) - obs[:, 3]
    clearance = jnp.min(jnp.where(scn.mpc.obstacle_active, gap, jnp.inf), initial=jnp.inf)
    w = res.x_robot - (carry.x_r @ A.T) - carry.u_r[:, None] * B
    out = dict(t=t_k, t_plant=carry.t_plant, stance=stance_k, x_hlip=carry.x_h, x_robot=carry.x_r,
               x_est=carry.x_e,
               u_hlip=carry.u_h, u_robot=carry.u_r, w=w, ref_pos=ref.position,
               ref_vel=ref.velocity, ref_heading=ref.heading, qp_status=new_plan.status,
               qp_iter=new_plan.iterations, obstacle_slack=new_plan.slack,
               clearance=clearance, leg_gap=res.leg_gap, valid=active,
               failed_now=active & res.failed,
               nonfinite=active & ~jnp.all(jnp.isfinite(res.x_robot)),
               qp_failed=active & ~ok)
    if ticks is not None:
        out["ticks"] = ticks
    keep = active & ~res.failed

    def sel(new, old):
        return jax.tree.map(lambda a, b: jnp.where(keep, a, b), new, old)

    nxt = Carry(x_h=sel(x_h_next, carry.x_h), u_h=sel(u_h_next, carry.u_h),
                x_r=sel(res.x_robot, carry.x_r), x_e=sel(res.x_est, carry.x_e),
                u_r=sel(res.u_robot, carry.u_r),
                plan=sel(new_plan, carry.plan), pstate=sel(pnext, carry.pstate),
                alive=carry.alive & ~(active & res.failed),
                qp_ok=carry.qp_ok & (ok | ~active),
                t_plant=sel(carry.t_plant + jnp.asarray(res.duration, dt), carry.t_plant))
    return nxt, out


def _nominal_next(scn: Scenario, carry: Carry):
    """x_H,k+1 = A x̃_k + B ũ_k: x̃ is the nominal with the anchored coordinates replaced by the
    robot's (:data:`ANCHOR`: none for "tube", c for "position", all for "measured"); ũ is
    the robot's executed step u_R,k when the whole state is anchored, else u_H,k."""
    x0 = jnp.where(scn.anchor == 1, carry.x_r, carry.x_h)
    u0 = jnp.where(jnp.all(scn.anchor == 1), carry.u_r, carry.u_h)
    return (x0 @ scn.mpc.A.T) + u0[:, None] * scn.mpc.B


def simulate_one(scn: Scenario, static: Static):
    """One scenario's closed loop in one scan over all ``static.n_steps`` steps (vmap this).
    Returns a dict of per-step arrays."""
    carry0, ok0 = _start(scn, static)
    _, out = jax.lax.scan(lambda c, k: _step(scn, static, c, k), carry0,
                          jnp.arange(static.n_steps))
    return _finish(out, ok0)


@functools.partial(jax.jit, static_argnames=("static",))
def _run_whole(batch: Scenario, static: Static):
    return jax.vmap(lambda s: simulate_one(s, static))(batch)


@functools.partial(jax.jit, static_argnames=("static",))
def _start_batch(batch: Scenario, static: Static):
    return jax.vmap(lambda s: _start(s, static))(batch)


@functools.partial(jax.jit, static_argnames=("static",))
def _segment_batch(batch: Scenario, carry: Carry, ks, static: Static):
    """Steps ``ks`` (L,) of every scenario: (carry, log rows with a (scenarios, L) front)."""
    def one(scn, c):
        return jax.lax.scan(lambda c, k: _step(scn, static, c, k), c, ks)
    return jax.vmap(one)(batch, carry)


_finish_batch = jax.jit(jax.vmap(_finish))


def compiled_loops() -> int:
    """How many compiled closed-loop programs this process holds (whole runs and segments,
    traced here, loaded by :mod:`hlip_jax.trace_cache` or compiled ahead beside the start
    program): a sweep whose chunks share their shapes adds one."""
    loops = [_run_whole, _segment_batch]
    loops += [p for whole, _, segment in _per_mesh.values() for p in (whole, segment)]
    return sum(f._cache_size() + trace_cache.loaded(f.__name__)
               + trace_cache.compiled_ahead(f.__name__) for f in loops)


def segment_length(n_steps: int) -> int:
    """Steps per compiled segment when progress is reported: about 20 segments a run."""
    return max(1, math.ceil(n_steps / 20))


def _compile_ahead(start, segment, batch: Scenario, static: Static, L: int,
                   split: Optional[jax.sharding.Sharding]) -> None:
    """Trace or load the ``start`` and ``segment`` programs (through :mod:`hlip_jax.trace_cache`
    where it serves them, else by their own jit: MJX's Warp physics) and compile both at once
    (the segment's carry shapes from the start's program).  ``split``: where the batch's
    arrays are committed (:func:`_committed_to`), the carry is placed the same way and the
    step indices given whole to its device(s); None for a host batch."""
    shapes = trace_cache.out_shapes(start, static, batch)
    if shapes is None:
        return
    carry, ks = shapes[0], jax.ShapeDtypeStruct((L,), jax.dtypes.canonicalize_dtype(jnp.int_))
    if split is not None:
        carry = jax.tree.map(lambda a: jax.ShapeDtypeStruct(a.shape, a.dtype, sharding=split),
                             carry)
        whole = (jax.sharding.NamedSharding(split.mesh, jax.sharding.PartitionSpec())
                 if isinstance(split, jax.sharding.NamedSharding) else split)
        ks = jax.ShapeDtypeStruct(ks.shape, ks.dtype, sharding=whole)
    trace_cache.compile_together([(start, static, (batch,)),
                                  (segment, static, (batch, carry, ks))])


def _committed_to(batch) -> Optional[jax.sharding.Sharding]:
    """The sharding a batch's arrays are committed to (:func:`place`, or one device by
    :func:`run_blocks`); None for host (numpy) or uncommitted arrays."""
    leaf = jax.tree.leaves(batch)[0]
    return leaf.sharding if getattr(leaf, "committed", False) else None


def _mesh_of(batch) -> Optional[jax.sharding.Mesh]:
    """The mesh a batch is split over when it spans several devices (:func:`place`), else
    None (a batch on one device)."""
    sharding = getattr(jax.tree.leaves(batch)[0], "sharding", None)
    if isinstance(sharding, jax.sharding.NamedSharding) and sharding.mesh.size > 1:
        return sharding.mesh
    return None


def _per_device(fn, mesh, replicated: int = 0):
    """``fn`` (a jitted ``(batch, ..., static=)`` closed-loop program) run by every device of
    ``mesh`` on its own scenarios: ``shard_map`` over the scenario axis, the last
    ``replicated`` arguments given whole to every device.  Scenarios never communicate, so
    the devices never do either: left to XLA's partitioner, the tick loop's stopping test
    (any robot of the batch still in its step) became a cross-device reduction every tick,
    83× slower in a toy loop on two CPU devices (docs/benchmarks/sweeps.md, "CPU cores as devices")."""
    from jax.sharding import PartitionSpec
    split = PartitionSpec(mesh.axis_names[0])

    def program(*args, static):
        specs = (split,) * (len(args) - replicated) + (PartitionSpec(),) * replicated
        body = functools.partial(fn.__wrapped__, static=static)
        return jax.shard_map(body, mesh=mesh, in_specs=specs, out_specs=split,
                             check_vma=False)(*args)

    program.__name__ = f"{fn.__name__}_on_{mesh.size}_{mesh.devices.flat[0].platform}"
    return jax.jit(program, static_argnames=("static",))


def _check_cpu_pool(mesh: jax.sharding.Mesh) -> None:
    """Refuse a batch split over as many CPU devices of this process as XLA's CPU thread
    pool has threads under jaxlib < 0.11, whose batched LAPACK kernels then wait forever for
    a free thread (:mod:`hlip_jax.xla_flags`).  The pool has ``PJRT_NPROC`` (or ``NPROC``)
    threads, else one per usable core."""
    from hlip_jax import xla_flags
    if mesh.devices.flat[0].platform != "cpu" or _jaxlib_version() >= (0, 11):
        return
    pool = xla_flags.cpu_pool_threads()
    here = sum(d.process_index == jax.process_index() for d in mesh.devices.flat)
    if here >= pool:
        raise xla_flags.PoolTooSmall(
            f"the batch is split over {here} CPU devices of this process, but XLA's CPU thread "
            f"pool has {pool} threads: jaxlib {jax.lib.__version__} can deadlock unless it has "
            f"more (set PJRT_NPROC={2 * here} before JAX starts, as hlip-sweep does)")


def _jaxlib_version() -> tuple[int, ...]:
    return tuple(int(p) for p in jax.lib.__version__.split(".")[:2] if p.isdigit())


_per_mesh: dict = {}     # mesh -> its (whole run, start, segment) programs


def _jitted_call(fn, static, *args):
    """``fn(*args, static=static)`` without the trace cache (programs XLA partitions over
    several devices: their export is not kept)."""
    return fn(*args, static=static)


def _programs(mesh: Optional[jax.sharding.Mesh]):
    """(whole run, start, segment) programs for a batch on ``mesh`` (None: one device).
    Several CPU devices get per-device loops (:func:`_per_device`); a batch placed over
    several GPUs gets the loops XLA partitions (the per-device programs crashed XLA's GPU
    compile on two H200s, jax 0.11.2: docs/benchmarks/sweeps.md, "CPU cores as devices"),
    which :func:`run_on` avoids by giving each GPU its own block (:func:`spread_of`)."""
    if mesh is None or mesh.devices.flat[0].platform != "cpu":
        return _run_whole, _start_batch, _segment_batch
    if mesh not in _per_mesh:
        _check_cpu_pool(mesh)
        _per_mesh[mesh] = (_per_device(_run_whole, mesh), _per_device(_start_batch, mesh),
                           _per_device(_segment_batch, mesh, replicated=1))
    return _per_mesh[mesh]


class _Route(NamedTuple):
    """How one batch's closed loop is called: its (whole run, start, segment) programs, the
    call that runs them (through :mod:`hlip_jax.trace_cache` or straight by jit) and, for the
    per-device programs of several CPU devices, the batch's split (None otherwise)."""
    whole: object
    start: object
    segment: object
    call: object
    split: Optional[jax.sharding.NamedSharding]


def _route(batch: Scenario) -> _Route:
    mesh = _mesh_of(batch)
    whole, start, segment = _programs(mesh)
    per_device = mesh is not None and mesh in _per_mesh
    call = trace_cache.call if mesh is None or per_device else _jitted_call
    split = jax.tree.leaves(batch)[0].sharding if per_device else None
    return _Route(whole, start, segment, call, split)


def run(batch: Scenario, static: Static):
    """Every scenario's closed loop (the batch on the devices it was placed on).

    Without ``static.progress`` the whole run is one compiled call.  With it the steps run in
    segments of :func:`segment_length` (one compiled program serves every segment: the step
    indices are data, and steps past ``n_steps`` are inactive), and every finished segment is
    reported to :func:`hlip_jax.progress.step_done` from Python — no host callback inside the
    compiled loop, so it stays cacheable on disk (:mod:`hlip_jax.compile_cache`; the traced
    programs too, :mod:`hlip_jax.trace_cache`).  Both give the same numbers: a segment
    boundary only splits the scan."""
    return run_each([batch], static)[0]


def run_each(batches: Sequence[Scenario], static: Static) -> list:
    """:func:`run` of several batches at once, each on its own device(s), each from its own
    thread: a GPU program with a while loop holds the thread that launched it until it ends
    (the loop's test is read back every trip), so calls from one thread run one device after
    the other (two H200s, 65,536 robots: no faster than one).  Each thread compiles its own
    executable (concurrently) and runs its batch's loop; the first batch's segments are the
    ones reported to :mod:`hlip_jax.progress`.  The matmul precision of the calling thread
    holds in every thread."""
    if len(batches) == 1:
        return [_run_one(batches[0], static, True)]
    from concurrent.futures import ThreadPoolExecutor
    precision = jax.config.jax_default_matmul_precision

    def one(i):
        with jax.default_matmul_precision(precision):
            return _run_one(batches[i], static, i == 0)
    with ThreadPoolExecutor(len(batches)) as pool:
        return list(pool.map(one, range(len(batches))))


def _run_one(batch: Scenario, static: Static, report: bool):
    """:func:`run` of one batch; its segments reported to :mod:`hlip_jax.progress` where
    ``report``."""
    r = _route(batch)
    if not static.progress:
        return r.call(r.whole, static, batch)
    K, L = static.n_steps, segment_length(static.n_steps)
    if r.call is trace_cache.call:
        _compile_ahead(r.start, r.segment, batch, static, L, r.split or _committed_to(batch))
    carry, ok0 = r.call(r.start, static, batch)
    outs = []
    for k0 in range(0, K, L):
        carry, out = _segment_call(r, static, batch, carry, k0, L)
        outs.append(out)
        jax.block_until_ready(carry)
        if report:
            progress.step_done(min(k0 + L, K) - 1, K)
    return _finish_batch(jax.tree.map(lambda *a: jnp.concatenate(a, axis=1)[:, :K], *outs), ok0)


def _segment_call(route: _Route, static: Static, batch: Scenario, carry, k0: int, L: int):
    """Steps k0 … k0 + L − 1 of one batch: (carry, their outputs)."""
    if route.split is not None:
        # per-device programs: XLA returns their empty outputs whole on every device, and the
        # segment's executable, compiled ahead, expects every carry leaf split as the batch is
        carry = jax.device_put(carry, route.split)       # no copy where already split
    return route.call(route.segment, static, batch, carry, jnp.arange(k0, k0 + L))


#: how a batch on several devices runs (:func:`spread_of`)
SPREADS = ("program", "dispatch")


def spread_of(devices: Sequence) -> str:
    """How a batch runs on several ``devices``: ``"program"`` — one program split over them
    (:func:`place` and :func:`run`: per-device loops in one ``shard_map`` program, one compile
    for all), for CPU devices; ``"dispatch"`` — the batch cut into one block per device, each
    device running the one-device program on its block (:func:`run_blocks`), for GPUs: the
    split programs crashed XLA's GPU compile (two H200s, jax 0.11.2), the program XLA
    partitions tests "any robot still stepping" across the devices every tick (no faster on
    two GPUs than on one: docs/benchmarks/sweeps.md), and the persistent cache serves the
    first GPU's executable to the others."""
    return "program" if list(devices)[0].platform == "cpu" else "dispatch"


def _local_blocks(n: int, devices: Sequence) -> list[tuple[object, slice]]:
    """(device, its scenarios) of this process's devices, the ``n`` scenarios cut into
    ``len(devices)`` equal blocks in the order of ``devices``."""
    b = n // len(devices)
    return [(d, slice(i * b, (i + 1) * b)) for i, d in enumerate(devices)
            if d.process_index == jax.process_index()]


def run_blocks(host: Scenario, static: Static, devices: Sequence) -> list:
    """The closed loop of this process's blocks of the host batch ``host`` (its length a
    multiple of ``len(devices)``), one block per device of this process, computed together
    (:func:`run_each`).  Returns the blocks' outputs (device arrays), in the order of
    ``devices``."""
    blocks = _local_blocks(len(jax.tree.leaves(host)[0]), devices)
    batches = [jax.device_put(jax.tree.map(lambda a: np.asarray(a)[s], host), d)
               for d, s in blocks]
    return run_each(batches, static)


def _gather_blocks(local: list, devices: Sequence):
    """The outputs of every process's blocks (:func:`run_blocks`; ``local`` this process's, as
    numpy trees) as one tree of numpy arrays, scenarios in the order of the blocks.  Every
    process must hold as many of ``devices`` as the others."""
    mine = jax.tree.map(lambda *a: np.concatenate(a), *local)
    if jax.process_count() == 1:
        return mine
    from jax.experimental import multihost_utils
    owners = [d.process_index for d in devices]
    counts = {p: owners.count(p) for p in set(owners)}
    if len(set(counts.values())) != 1:
        raise ValueError(f"devices: the processes hold different numbers of the devices "
                         f"({counts}); a run over several processes needs as many on each")
    every = multihost_utils.process_allgather(mine, tiled=False)     # (processes, ...)
    # gathered: process 0's blocks, then process 1's, ...; put them back in block order
    gathered = [i for p in sorted(counts) for i, o in enumerate(owners) if o == p]
    order = np.argsort(gathered)
    n_blocks = len(devices)

    def blocks_in_order(a):
        a = np.asarray(a).reshape((n_blocks, -1) + a.shape[2:])
        return a[order].reshape((-1,) + a.shape[2:])
    return jax.tree.map(blocks_in_order, every)


def scenario_sharding(devices=None):
    """Sharding that splits the leading (scenario) axis over ``devices`` (default: every
    device of every process, ``jax.devices()``): a 1-D ``Mesh`` with axis "scenarios".
    :func:`run` gives each device its own scenarios' loop (:func:`_per_device`)."""
    from jax.sharding import Mesh, NamedSharding, PartitionSpec
    devices = jax.devices() if devices is None else list(devices)
    return NamedSharding(Mesh(np.asarray(devices), ("scenarios",)), PartitionSpec("scenarios"))


def place(batch, sharding):
    """Put a host (numpy) batch on the mesh.  Each process builds the same batch from the
    same configs and contributes only the shards of its own devices, so this works
    unchanged after ``jax.distributed.initialize`` on several hosts."""
    def put(a):
        a = np.asarray(a)
        return jax.make_array_from_callback(a.shape, sharding, lambda idx: a[idx])
    return jax.tree.map(put, batch)


_barriers = itertools.count()


def _all_processes_arrive() -> None:
    """Wait (up to an hour) until every process of a ``jax.distributed`` run gets here.  The
    processes compile their programs separately and can finish minutes apart; the gather that
    follows uses the CPU collectives (Gloo), whose first use gives the others only 30 s to
    connect.  The coordination service's barrier has no such limit."""
    from jax._src import distributed          # the client jax.distributed.initialize started
    client = distributed.global_state.client
    if client is not None and jax.process_count() > 1:
        client.wait_at_barrier(f"hlip_jax_gather_{next(_barriers)}", 3_600_000)


def _to_host(a):
    if jax.process_count() > 1:
        from jax.experimental import multihost_utils
        return np.asarray(multihost_utils.process_allgather(a, tiled=True))
    return np.asarray(a)


def simulate_ticks(configs: Sequence[ScenarioConfig], index: int, *, n_samples: int = 2048,
                   dtype=None):
    """Re-simulate scenario ``index`` of ``configs`` (a Cassie sweep) alone, with the plant's
    per-tick log.  The array sizes are the whole sweep's (:func:`shapes_of`), so the run is the
    one the sweep made up to floating-point differences of a batch of one
    (:func:`simulate_chunk_ticks` repeats the sweep's own batch instead).  Returns (the step
    log as a dict of arrays (K, ...), the tick log (:class:`hlip_jax.plants.cassie.tick.TickLog`
    of arrays (K, ticks per step, ...)))."""
    configs = list(configs)
    return simulate_chunk_ticks([configs[index]], [0], n_samples=n_samples, dtype=dtype,
                                shapes=shapes_of(configs), devices=jax.devices()[:1])[0]


def _simulate_batch(configs, *, n_samples, pad_to, dtype, shapes, devices, keep_ticks,
                    spread=None):
    """:func:`simulate`'s run: (the host batch, the outputs of the first ``len(configs)``
    scenarios as numpy arrays), the tick log under "ticks" where ``keep_ticks``."""
    configs = list(configs)
    S = len(configs)
    devices = jax.devices() if devices is None else list(devices)
    n = max(pad_to or S, S)
    n = -(-n // len(devices)) * len(devices)
    padded = configs + [configs[-1]] * (n - S)
    host, static = build(padded, n_samples=n_samples, dtype=dtype, shapes=shapes)
    out = run_on(host, static._replace(progress=progress.active(), keep_ticks=keep_ticks),
                 devices, spread or spread_of(devices))
    return host, jax.tree.map(lambda a: a[:S], out)


def run_on(host: Scenario, static: Static, devices: Sequence, spread: str) -> dict:
    """Every scenario's closed loop of the host batch ``host`` (its length a multiple of
    ``len(devices)``) on ``devices``, shared as ``spread`` (:data:`SPREADS`,
    :func:`spread_of`) says, in every process of a ``jax.distributed`` run; the outputs as
    numpy arrays, scenarios in order."""
    devices = list(devices)
    if spread not in SPREADS:
        raise ValueError(f"spread: {spread!r} is not allowed; allowed: {', '.join(SPREADS)}")
    with jax.default_matmul_precision("highest"):
        if len(devices) > 1 and spread == "dispatch":
            local = run_blocks(host, static, devices)
            jax.block_until_ready(local)
            _all_processes_arrive()
            return _gather_blocks([jax.tree.map(np.asarray, o) for o in local], devices)
        # placed once: a host batch would be copied to the device again by every segment's call
        batch = (place(host, scenario_sharding(devices)) if len(devices) > 1
                 else jax.device_put(host, devices[0]))
        out = run(batch, static)
        jax.block_until_ready(out)
        _all_processes_arrive()
        return jax.tree.map(_to_host, out)


def simulate_chunk_ticks(configs: Sequence[ScenarioConfig], indices: Sequence[int], *,
                         n_samples: int = 2048, dtype=None, shapes: Shapes | None = None,
                         devices=None) -> list:
    """Simulate the batch ``configs`` exactly as :func:`simulate` does (the same padding to the
    devices, split and array sizes ``shapes``), with the plant's per-tick log, and return, for
    each scenario of ``indices``, its (step log as a dict of arrays (K, ...), tick log
    (:class:`hlip_jax.plants.cassie.tick.TickLog` of arrays (K, ticks per step, ...))).

    Given a sweep chunk's scenarios (:func:`hlip_jax.runner.chunk_configs`) on the devices it
    ran on, this is the chunk's run: the tick log rides along with the same computation, and
    the step log comes out as the sweep stored it (checked bit for bit on a float32 chunk of 10
    pushed robots over two CPU devices: ``hlip_jax.tick_report`` compares it every replay).
    :func:`simulate_ticks` (a batch of one) is not: float32 rounding changes with the batch, and
    a run at the margin can walk alone and fall in its chunk."""
    configs = list(configs)
    for j in indices:
        check_keeps_ticks(configs[j], j)
    _, out = _simulate_batch(configs, n_samples=n_samples, pad_to=None, dtype=dtype,
                             shapes=shapes, devices=devices, keep_ticks=True)
    picked = []
    for j in indices:
        one = jax.tree.map(lambda a: np.asarray(a)[j], out)
        picked.append((one, one.pop("ticks")))
    return picked


def check_keeps_ticks(cfg: ScenarioConfig, index: int) -> None:
    """ValueError naming the plants that keep one unless scenario ``index`` (``cfg``) runs a
    plant with a per-tick log."""
    if plants.load(cfg.plant).step_with_log is None:
        raise ValueError(f"plant: scenario {index}'s plant {cfg.plant!r} keeps no per-tick log; "
                         f"plants that do: " + ", ".join(
                             repr(n) for n in plants.NAMES if plants.load(n).step_with_log))


def simulate(configs: Sequence[ScenarioConfig], *, n_samples: int = 2048, pad_to: int | None = None,
             dtype=None, shapes: Shapes | None = None, devices=None,
             spread: str | None = None) -> Log:
    """Run every scenario of ``configs`` in one compiled, vmapped call and return the Log
    (numpy arrays, scenarios in the order given).

    ``pad_to`` pads the batch (repeating the last scenario) and ``shapes`` (:func:`shapes_of`
    the whole sweep) fixes the array sizes, so chunks of a sweep share one compile; padding
    is dropped from the Log.  With several devices (``devices``, default all of
    ``jax.devices()``: GPUs, or the CPU's cores as :mod:`hlip_jax.xla_flags` sets them up)
    the batch is padded to a multiple of their number and split over them along the scenario
    axis, each running its own scenarios' loop, as ``spread`` says (:data:`SPREADS`; by default
    :func:`spread_of` the devices: one split program on CPU devices, one block per GPU).
    While someone listens (:func:`hlip_jax.progress.listening`) every finished walking step
    is reported."""
    configs = list(configs)
    S = len(configs)
    host, out = _simulate_batch(configs, n_samples=n_samples, pad_to=pad_to, dtype=dtype,
                                shapes=shapes, devices=devices, keep_ticks=False, spread=spread)
    valid = out["valid"]
    valid_w = valid & np.concatenate([valid[:, 1:], np.zeros((S, 1), bool)], axis=1)  # k, k+1
    out["w"] = np.where(valid_w[..., None, None], out["w"], np.nan)
    return Log(A=np.asarray(host.mpc.A)[:S], B=np.asarray(host.mpc.B)[:S],
               K_gain=np.asarray(host.gain)[:S], anchor=np.asarray(host.anchor)[:S], **out)
