"""The step-level interface between the closed loop and whatever executes the steps.

One *walking step* runs from one pre-impact instant SSP⁻_k to the next SSP⁻_{k+1}:
at SSP⁻_k the swing foot lands (the step u_k, already decided, is placed), then DSP, then SSP
on the new stance foot while the other foot swings towards the next step u_{k+1}.  The closed
loop (:mod:`hlip_jax.simulation.rollout`) gives the plant the H-LIP's nominal motion over that interval
and the stepping gain; the plant decides the robot's own next step by the stepping law

    u_robot = u_HLIP + K (x_robot − x_HLIP)            (per plane, x = [c, p, v])

(a discrete evaluation at SSP⁻_{k+1} for the H-LIP plant, continuously during SSP for Cassie)
and returns its state at SSP⁻_{k+1}.

A plant is any object with

    init(params, x0: (2, 3), u0: (2,), stance0, key, heading0) -> state
    step(params, state, cmd: StepCommand) -> (state, StepResult)

both pure, jit- and vmap-able; ``params`` is the plant's per-scenario pytree (built by the
plant's ``make_params`` from a :class:`hlip_jax.simulation.config.ScenarioConfig`); ``heading0`` is the
path's heading at t = 0 [rad], the way a robot with an orientation starts facing.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np



#: a batch's ground kinds, each one's scene holding what the kinds before it need: "flat" the
#: plain scene, "step" with the terrain block, "rough" with the block and the height field
GROUND_KINDS = ("flat", "step", "rough")

class StepCommand(NamedTuple):
    """What the closed loop tells the plant for the step SSP⁻_k → SSP⁻_{k+1}."""
    t: jax.Array            # time of SSP⁻_k [s]
    stance: jax.Array       # stance foot of the SSP that ended at SSP⁻_k (0 left, 1 right)
    x_hlip: jax.Array       # (2, 3) H-LIP state at SSP⁻_k
    u_hlip: jax.Array       # (2,) H-LIP step placed at SSP⁻_k [m]
    x_hlip_next: jax.Array  # (2, 3) H-LIP state at SSP⁻_{k+1}
    u_hlip_next: jax.Array  # (2,) H-LIP step to be placed at SSP⁻_{k+1} [m]
    gain: jax.Array         # (2, 3) stepping gain per plane on [c, p, v]
    heading: jax.Array      # path heading at SSP⁻_{k+1} [rad]
    t_ssp: jax.Array        # the planner's H-LIP phase durations [s] and COM height [m]
    t_dsp: jax.Array
    z0: jax.Array
    live: jax.Array = np.bool_(True)  # the step counts (robot standing, within the scenario's
                                      # steps); a plant may idle through a step that does not


class StepResult(NamedTuple):
    """The robot at SSP⁻_{k+1}."""
    x_robot: jax.Array      # (2, 3) [c, p, v] per plane (p relative to the stance foot of the SSP)
    u_robot: jax.Array      # (2,) step placed at SSP⁻_{k+1} [m]
    failed: jax.Array       # bool: the robot fell or its state is not finite
    duration: jax.Array     # plant time the step took, SSP⁻_k → SSP⁻_{k+1} [s]
    leg_gap: jax.Array      # (2,) smallest feet and lower-leg clearances during the step [m]
                            # (inf where the plant has no leg geometry)
    x_est: jax.Array        # (2, 3) x_robot as the robot's controller measured and estimated it
                            # at SSP⁻_{k+1} (equal to x_robot where the plant senses perfectly)


def push_table(pushes, n_push: int):
    """Fixed-size arrays of a scenario's pushes (:class:`hlip_jax.simulation.config.PushConfig`):
    start and end times (n_push,) [s] (unused slots −1, never active) and the horizontal force
    (n_push, 2) [N] in world x, y."""
    pushes = list(pushes)
    if len(pushes) > n_push:
        raise ValueError(f"disturbance.pushes: {len(pushes)} pushes, at most {n_push} allowed")
    start = np.full(n_push, -1.0)
    end = np.full(n_push, -1.0)
    force = np.zeros((n_push, 2))
    for i, p in enumerate(pushes):
        start[i], end[i] = p.time, p.time + p.duration
        a = np.deg2rad(p.direction)
        force[i] = p.force * np.array([np.cos(a), np.sin(a)])
    return start, end, force


def clip_step(u, heading, swing, length_max, width_min, width_max):
    """Step ``u`` (2,) [m] (world x, y) with its length along ``heading`` [rad] clipped to
    ±length_max and its width across it to [width_min, width_max] on the ``swing`` foot's side
    (0 left: +, 1 right: −) — the reach of a legged robot whose legs must not cross."""
    ch, sh = jnp.cos(heading), jnp.sin(heading)
    sgn = jnp.where(swing == 0, 1.0, -1.0)
    along = jnp.clip(ch * u[0] + sh * u[1], -length_max, length_max)
    across = sgn * jnp.clip(sgn * (-sh * u[0] + ch * u[1]), width_min, width_max)
    return jnp.stack([ch * along - sh * across, sh * along + ch * across])


def changed_field(table, names=None) -> Optional[tuple]:
    """(field, value, default) of the first field of the config table ``table`` (of ``names``,
    default all) whose value is not its class's default; None when all are (no import of the
    config layer: the defaults come from the table's own class).  For a plant's ``check``."""
    default = type(table)()
    for name in names if names is not None else (f.name for f in dataclasses.fields(table)):
        if getattr(table, name) != getattr(default, name):
            return name, getattr(table, name), getattr(default, name)
    return None


def show_setting(v) -> str:
    """A config value as a sweep file writes it (true/false for booleans, numbers as %g)."""
    return str(v).lower() if isinstance(v, bool) else f"{v:g}"
