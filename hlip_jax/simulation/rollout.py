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
closed-loop matrix (:func:`hlip_jax.core.invariant.closed_loop`).  Before the loop the MPC plans
u_H,0 from x_H,0.
The log's ``t`` is the planner's t_k; ``t_plant`` is the plant's own clock at SSP⁻_k (a Cassie
step ends at its detected touchdown, so its steps need not last T).

A scenario whose QP fails keeps walking on its previous plan (shifted) and counts the failure;
a robot that falls is frozen from that step on and marked; neither touches other scenarios.
"""


from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from hlip_jax.core import mpc, paths, qp
from hlip_jax import plants
from hlip_jax.simulation.arrays import Scenario, Static
from hlip_jax.plants.base import StepCommand
from hlip_jax.core.steplog import STATUS_FELL, STATUS_NONFINITE, STATUS_OK, STATUS_QP_FAILED

STANCE_LEFT, STANCE_RIGHT = 0, 1


# ----------------------------------------------------------------------------------------------
# the loop

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
    for the MPC's QP, :func:`hlip_jax.core.mpc.build_qp`)."""
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
    robot's (:data:`hlip_jax.simulation.arrays.ANCHOR`: none for "tube", c for "position", all for "measured"); ũ is
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
def run_whole(batch: Scenario, static: Static):
    return jax.vmap(lambda s: simulate_one(s, static))(batch)


@functools.partial(jax.jit, static_argnames=("static",))
def start_batch(batch: Scenario, static: Static):
    return jax.vmap(lambda s: _start(s, static))(batch)


@functools.partial(jax.jit, static_argnames=("static",))
def segment_batch(batch: Scenario, carry: Carry, ks, static: Static):
    """Steps ``ks`` (L,) of every scenario: (carry, log rows with a (scenarios, L) front)."""
    def one(scn, c):
        return jax.lax.scan(lambda c, k: _step(scn, static, c, k), c, ks)
    return jax.vmap(one)(batch, carry)


finish_batch = jax.jit(jax.vmap(_finish))


def segment_length(n_steps: int) -> int:
    """Steps per compiled segment when progress is reported: about 20 segments a run."""
    return max(1, math.ceil(n_steps / 20))
