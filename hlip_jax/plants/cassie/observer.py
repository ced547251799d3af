"""Output-acceleration disturbance observer of the walking Cassie (beyond the paper).

The CLF-QP predicts the output accelerations with a model whose leaf springs are rigid
(:mod:`dynamics`); the simulated robot's springs are not, and in double support its COM
accelerates upwards by ≈ 2.6 m/s² more than the model says (docs/cassie_mismatch).  The
observer estimates that difference on the rows that are controlled in every phase — pelvis
roll, pitch, yaw and COM height (``ROWS``) — and the tick subtracts it from the desired
accelerations, so the QP asks the model for ÿ_d − d̂ and the robot gets ≈ ÿ_d.

With ẏ_k the measured output velocities at tick k, ÿ^model_{k−1} what the model predicted for
the torques applied at tick k−1 (rigid springs, that tick's contact set) and Δt the control
period, one measurement of the disturbance is

    w_k = (ẏ_k − ẏ_{k−1}) / Δt − ÿ^model_{k−1},

and the estimate is its first-order low-pass of bandwidth ω_d [rad/s] (exact discretisation
of d̂' = ω_d (w − d̂) with w held over a tick):

    d̂_k = d̂_{k−1} + α (w_k − d̂_{k−1}),   α = 1 − exp(−ω_d Δt).

ω_d = 0 gives α = 0: d̂ stays 0 and the desired accelerations are the controller's own, bit
for bit.  The first tick after the start has no ẏ_{k−1} and leaves d̂ as it is.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from hlip_jax.plants.cassie import outputs

#: output rows the observer acts on: pelvis orientation (0..2) and COM height (3)
ROWS = slice(0, 4)
N_ROWS = 4


class Observer(NamedTuple):
    """Observer state, carried from tick to tick and from step to step."""
    d_hat: jax.Array      # (4,) disturbance estimate on ROWS [rad/s², m/s²]
    ydot: jax.Array       # (4,) ẏ on ROWS at the previous acting tick [rad/s, m/s]
    ydd_model: jax.Array  # (4,) model ÿ on ROWS for the torques applied then [rad/s², m/s²]
    primed: jax.Array     # bool: ydot and ydd_model hold a previous tick


def alpha(bandwidth, dt) -> float:
    """Low-pass gain α = 1 − exp(−ω_d Δt) of bandwidth ``bandwidth`` [rad/s], period ``dt`` [s]."""
    if not bandwidth >= 0:
        raise ValueError(f"dob_bandwidth must be ≥ 0 rad/s, got {bandwidth}")
    return float(-np.expm1(-bandwidth * dt))


def zeros(dtype) -> Observer:
    z = jnp.zeros(N_ROWS, dtype)
    return Observer(d_hat=z, ydot=z, ydd_model=z, primed=jnp.zeros((), bool))


def update(obs: Observer, ydot, gain, dt) -> Observer:
    """The estimate after measuring ``ydot`` (16,) at this tick (module doc)."""
    y = ydot[ROWS]
    w = (y - obs.ydot) / dt - obs.ydd_model
    d_hat = jnp.where(obs.primed, obs.d_hat + gain * (w - obs.d_hat), obs.d_hat)
    return obs._replace(d_hat=d_hat)


def record(obs: Observer, ydot, ydd_model) -> Observer:
    """Keep this tick's ẏ and the model's ÿ for the applied torques (both (16,)) for the next."""
    return obs._replace(ydot=ydot[ROWS], ydd_model=ydd_model[ROWS],
                        primed=jnp.ones((), bool))


def compensate(des: outputs.Desired, obs: Observer) -> outputs.Desired:
    """Desired outputs with ÿ_d − d̂ on ROWS."""
    return des._replace(yddot=des.yddot.at[ROWS].add(-obs.d_hat))
