"""Orbit walking without the MPC: the H-LIP nominal follows P1 (sagittal) / P2 (lateral)
orbit steps in a turning heading frame and the robots step by the stepping law
(:func:`walk_orbits`).  A driver for tests and benchmarks of the Cassie plant on its own
(outside the package: tests import ``support.cassie_orbits``, benchmark scripts
``tests.support.cassie_orbits`` with the repository root on their path)."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from hlip_jax.core import hlip
from hlip_jax.plants.base import StepCommand
from hlip_jax.plants.cassie import gaits, model, plant, tick

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

#: the default orbit walk: the "paper" gait preset's H-LIP T_SSP, T_DSP [s], COM height z0 [m]
#: and 3-state LQR stepping gain Q = diag(q_c, 1, q_v), R = r (see :func:`lqr_step_gain`), with
#: a nominal step width [m]
_P = gaits.preset(gaits.DEFAULT)
WALK_DEFAULTS = dict(t_ssp=_P["hlip.t_ssp"], t_dsp=_P["hlip.t_dsp"], z0=_P["hlip.z0"], width=0.2,
                     q_c=_P["gain.q_c"], q_v=_P["gain.q_v"], r=_P["gain.r"])


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
    ``gait`` a :class:`hlip_jax.simulation.config.CassieConfig` or a sequence of B of them; ``noise_v``
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
    params = _walk_params(B, t_ssp, t_dsp, gait, pushes, noise_v, step_error)
    x0 = jnp.zeros((2, 3))
    one = plant.init(None, x0, None, None, jax.random.PRNGKey(0))       # every robot starts alike
    state = jax.tree.map(lambda a: jnp.broadcast_to(a, (B,) + a.shape), one)
    keys = jax.vmap(jax.random.PRNGKey)(jnp.arange(B))
    state = state._replace(key=keys)
    if batch_step is None:
        batch_step = jax.jit(jax.vmap(plant.step_with_log))
    k_h = np.asarray(jax.vmap(hlip.deadbeat_gain)(z0, t_ssp, t_dsp))             # (B, 2)
    # nominal at SSP⁻_0: right stance ended, the left foot lands with u_H,0
    stance = 1
    heading = np.zeros(B)
    u_h, p_h, v_h = orbit_step(z0, t_ssp, t_dsp, v_fwd, v_lat, width, heading, 1 - stance)
    x_h = np.stack([np.stack([np.zeros(B), p_h[0], v_h[0]], -1),
                    np.stack([np.zeros(B), p_h[1], v_h[1]], -1)], 1)          # (B, 2, 3)
    terms = jax.vmap(lambda d: model.robot_terms(plant.cassie(), d))(state.d)
    x_r0 = np.asarray(jax.vmap(tick.robot_state, in_axes=(0, None))(terms, stance)[0])
    ankle = np.asarray(terms.ankle)
    u_r0 = ankle[:, 0, :2] - ankle[:, 1, :2]
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
                          t_ssp=jnp.asarray(t_ssp), t_dsp=jnp.asarray(t_dsp), z0=jnp.asarray(z0),
                          live=jnp.ones(B, bool))
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
    return _walk_log(log, A, Bm), ticks


def _walk_params(B: int, t_ssp, t_dsp, gait, pushes, noise_v, step_error) -> "plant.Params":
    """The plant's params of :func:`walk_orbits`'s B robots (an ideal batch: no realism); the
    tick budget holds the longest step, T_DSP + the swing duration (:func:`tick.swing_duration`)."""
    if gait is None or not isinstance(gait, (list, tuple)):
        gaits = [plant.make_gait(gait)] * B
    else:
        if len(gait) != B:
            raise ValueError(f"gait: expected one CassieConfig per robot ({B}), got {len(gait)}")
        gaits = [plant.make_gait(g) for g in gait]
    n_push = 1 if pushes is None else len(pushes)
    params = plant.Params(push_start=np.full((B, n_push), -1.0), push_end=np.full((B, n_push), -1.0),
                          push_force=np.zeros((B, n_push, 2)),
                          ticks=np.zeros((B, plant.tick_budget(max(
                              float(td + tick.swing_duration(ts, g))
                              for g, ts, td in zip(gaits, t_ssp, t_dsp))))),
                          gait=jax.tree.map(lambda *a: np.stack(a), *gaits),
                          noise_v=np.broadcast_to(np.asarray(noise_v, float), (B,)).copy(),
                          step_error=np.broadcast_to(np.asarray(step_error, float), (B,)).copy(),
                          real=None)
    if pushes is not None:
        for i, (t0, t1, fx, fy) in enumerate(pushes):
            params.push_start[:, i], params.push_end[:, i] = t0, t1
            params.push_force[:, i] = np.stack(np.broadcast_arrays(fx, fy), -1)
    return jax.tree.map(jnp.asarray, params)


def _walk_log(log: dict, A, Bm) -> "WalkLog":
    """Per-step lists (axis 1 after stacking) → :class:`WalkLog` with w, e and the sticky
    ``failed`` flag."""
    out = {k: np.stack(v, axis=1) for k, v in log.items()}
    xr, ur = out["x_robot"], out["u_robot"]
    out["w"] = (xr[:, 2:] - np.einsum("bij,bkpj->bkpi", A, xr[:, 1:-1])
                - ur[:, 1:-1, :, None] * Bm[:, None, None])
    out["e"] = xr - out["x_hlip"]
    out["failed"] = np.cumsum(out["failed"], axis=1) > 0
    return WalkLog(**out)


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
