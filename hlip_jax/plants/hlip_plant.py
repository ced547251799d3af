"""An H-LIP "robot": executes commanded steps with disturbances, integrated exactly.

Per plane the robot is a LIP of its own (z0, T_SSP, T_DSP — they may differ from the
planner's: *model mismatch*).  A walking step from SSP⁻_k:

* DSP for T_D:   p̈ = a(t)                 (a: push acceleration F/m along that plane [m/s²])
* the step u (placed at SSP⁻_k) takes effect: p ← p − u   (c unchanged)
* SSP for T_S:   p̈ = λ² p + a(t)
* additive S2S noise (uniform box, seeded): p ← p + δp, c ← c + δp, v ← v + δv
* the next step u_{k+1} = u_HLIP,k+1 + K (x_robot,k+1 − x_HLIP,k+1) + δu (placement error),
  with ``disturbance.step_limits`` clipped to a legged robot's reach first
  (:func:`hlip_jax.plants.base.clip_step` with the ``cassie.*`` swing-target limits; the
  point-foot H-LIP otherwise steps anywhere, crossing its own stance foot if the law says so).

The global COM c moves with p inside the phases (c − p is the stance-foot position).
Pushes are piecewise-constant forces over [start, start + duration); each phase is split at the
push boundaries and every piece is integrated in closed form:

  DSP piece of length τ:  p = p₀ + v₀τ + aτ²/2,         v = v₀ + aτ
  SSP piece of length τ:  q = p + a/λ²,  p = q₀ cosh λτ + v₀ sinh(λτ)/λ − a/λ²,
                          v = q₀ λ sinh λτ + v₀ cosh λτ.

The robot falls when |p| exceeds ``fall_distance`` (the COM far outside any foot reach) or the
state stops being finite.
"""

from __future__ import annotations

from typing import NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np

from hlip_jax.plants import Plant
from hlip_jax.plants.base import StepCommand, StepResult, changed_field, clip_step, push_table


class Params(NamedTuple):
    z0: jax.Array           # [m]
    t_ssp: jax.Array        # [s]
    t_dsp: jax.Array        # [s]
    g: jax.Array            # [m/s²]
    noise: jax.Array        # (2,) half-widths of the uniform S2S noise on [p, v] (c moves with p)
    step_error: jax.Array   # half-width of the uniform placement error [m]
    push_start: jax.Array   # (P,) [s]
    push_end: jax.Array     # (P,) [s]
    push_acc: jax.Array     # (P, 2) F/m in world x, y [m/s²]
    fall_distance: jax.Array  # [m]
    reach: jax.Array        # (3,) step limits [length_max, width_min, width_max] [m]
                            # (±inf: unlimited, :func:`clip_step` is then the identity)


class State(NamedTuple):
    x: jax.Array      # (2, 3) [c, p, v] per plane at SSP⁻
    u: jax.Array      # (2,) step placed at this SSP⁻
    time: jax.Array   # the plant's own clock [s]
    key: jax.Array


def make_params(cfg, max_pushes: int) -> Params:
    """Per-scenario plant data of a scenario config ``cfg`` (:class:`hlip_jax.simulation.config.ScenarioConfig`);
    0 in a mismatch field means "the planner's value"."""
    d, h = cfg.disturbance, cfg.hlip
    start, end, force = push_table(d.pushes, max_pushes)
    acc = force / d.mass
    return Params(
        z0=np.float64(d.z0 or h.z0), t_ssp=np.float64(d.t_ssp or h.t_ssp),
        t_dsp=np.float64(d.t_dsp if d.t_dsp else h.t_dsp), g=np.float64(h.g),
        noise=np.array([d.noise_p, d.noise_v]), step_error=np.float64(d.step_error),
        push_start=start, push_end=end, push_acc=acc, fall_distance=np.float64(1.0),
        reach=_reach(cfg))


def _reach(cfg) -> np.ndarray:
    """[length_max, width_min, width_max] [m] of the plant's steps (``disturbance.step_limits``)."""
    c = cfg.cassie
    if cfg.disturbance.step_limits:
        return np.array([c.step_length_max, c.step_width_min, c.step_width_max])
    return np.array([np.inf, -np.inf, np.inf])


def _push_pieces(params: Params, t0, duration):
    """Split [t0, t0 + duration] at the push boundaries: piece lengths (2P+1,) and the
    constant push acceleration (2P+1, 2) on each piece."""
    cuts = jnp.clip(jnp.concatenate([params.push_start, params.push_end]) - t0, 0.0, duration)
    pts = jnp.sort(jnp.concatenate([cuts, jnp.zeros((1,), cuts.dtype)]))
    ends = jnp.concatenate([pts[1:], jnp.full((1,), duration, cuts.dtype)])
    lengths = ends - pts
    mid = t0 + 0.5 * (pts + ends)
    on = (mid[:, None] >= params.push_start[None]) & (mid[:, None] < params.push_end[None])
    acc = on.astype(cuts.dtype) @ params.push_acc
    return lengths, acc


def flow(p, v, a, tau, lam, ssp):
    """Exact LIP (``ssp``) or DSP flow over ``tau`` [s] with constant acceleration ``a``."""
    ch, sh = jnp.cosh(lam * tau), jnp.sinh(lam * tau)
    off = a / lam**2
    q = p + off
    p_s, v_s = q * ch + v * sh / lam - off, q * lam * sh + v * ch
    p_d, v_d = p + v * tau + 0.5 * a * tau**2, v + a * tau
    return jnp.where(ssp, p_s, p_d), jnp.where(ssp, v_s, v_d)


def _phase(params: Params, p, v, t0, duration, ssp):
    lam = jnp.sqrt(params.g / params.z0)
    lengths, acc = _push_pieces(params, t0, duration)

    def body(carry, piece):
        p, v = carry
        tau, a = piece
        return flow(p, v, a, tau, lam, ssp), None

    (p, v), _ = jax.lax.scan(body, (p, v), (lengths, acc))
    return p, v


def stepping_law(cmd_u, gain, x_robot, x_hlip):
    """u = u_HLIP + K (x_robot − x_HLIP), per plane; gain (2, 3)."""
    return cmd_u + jnp.sum(gain * (x_robot - x_hlip), axis=-1)


def init(params: Params, x0, u0, stance0, key, heading0=0.0) -> State:
    del params, stance0, heading0          # the H-LIP has no orientation
    return State(x=x0, u=u0, time=jnp.zeros((), x0.dtype), key=key)


def measure(params: Params, state: State, stance) -> jax.Array:
    """The point-mass H-LIP's state is its S2S state [c, p, v] (2, 3)."""
    del params, stance
    return state.x


def step(params: Params, state: State, cmd: StepCommand):
    c, p, v = state.x[:, 0], state.x[:, 1], state.x[:, 2]
    c_start = c - p
    p1, v1 = _phase(params, p, v, state.time, params.t_dsp, False)          # DSP
    foot = c_start + state.u                                                 # new stance foot
    p2, v2 = _phase(params, p1 - state.u, v1, state.time + params.t_dsp, params.t_ssp, True)
    key, k_noise, k_step = jax.random.split(state.key, 3)
    dx = jax.random.uniform(k_noise, (2, 2), p.dtype, -1.0, 1.0) * params.noise
    p2 = p2 + dx[:, 0]
    v2 = v2 + dx[:, 1]
    x_next = jnp.stack([foot + p2, p2, v2], axis=-1)
    du = jax.random.uniform(k_step, (2,), p.dtype, -1.0, 1.0) * params.step_error
    u_law = stepping_law(cmd.u_hlip_next, cmd.gain, x_next, cmd.x_hlip_next)
    u_next = clip_step(u_law, cmd.heading, cmd.stance, *params.reach) + du
    failed = ~jnp.all(jnp.isfinite(x_next)) | jnp.any(jnp.abs(p2) > params.fall_distance)
    new = State(x=x_next, u=u_next, time=state.time + params.t_dsp + params.t_ssp, key=key)
    return new, StepResult(x_robot=x_next, x_est=x_next, u_robot=u_next, failed=failed,
                           duration=params.t_dsp + params.t_ssp,
                           leg_gap=jnp.full(2, jnp.inf, p.dtype))   # point feet: no legs


def step_span(cfg) -> float:
    """A step of the planner's H-LIP lasts T_SSP + T_DSP [s] (the plant's own timing, when it
    differs, needs no static size)."""
    return cfg.hlip.t_ssp + cfg.hlip.t_dsp


def check(cfg) -> Optional[str]:
    """The H-LIP plant's validation of a scenario config (:func:`hlip_jax.plants.check`): None,
    or a one-line message naming a field it cannot take.  The ``realism`` and ``impl`` tables
    describe the Cassie robot and how it is computed: they must keep their defaults."""
    if (ch := changed_field(cfg.realism)) is not None:
        return (f"realism.{ch[0]}: {ch[1]!r} models the Cassie robot; "
                f"allowed with plant = 'hlip': {ch[2]!r}")
    if (ch := changed_field(cfg.impl)) is not None:
        return (f"impl.{ch[0]}: {ch[1]!r} chooses how the Cassie robot is computed; "
                f"allowed with plant = 'hlip': {ch[2]!r}")
    return None


PLANT = Plant(name="hlip", measure=measure,
              make_params=lambda cfg, n_push, t_step=0.0, non_ideal=False, terrain="flat":
              make_params(cfg, n_push),
              init=init, step=step, step_with_log=None, step_span=step_span,
              settings=lambda cfg, robots=1: None)
