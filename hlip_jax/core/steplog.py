"""The step log: what the closed loop records at every pre-impact instant SSP⁻_k, and the few
quantities everything downstream derives from it — defined once, used by the rollout, the
store, the analysis, the report and the tests.

Axes: S scenarios, K logged steps (k = 0 … K−1), planes (sagittal world x, lateral world y),
and the H-LIP state [c, p, v] of one plane: c the global COM position [m], p the COM relative
to the stance foot [m], v the COM velocity [m/s].

:class:`Log` fields are listed in :data:`FIELD_DOC`, ``name: meaning [unit] (shape) dtype``
(dtype float64 where none is given); :func:`zeros` reads the shapes and dtypes from that list
(a constant, not this docstring, which ``python -OO`` removes), so a field is defined there
and in :class:`Log` and nowhere else.
"""

from __future__ import annotations

import re
from typing import NamedTuple

import numpy as np

STATUS_OK, STATUS_FELL, STATUS_NONFINITE, STATUS_QP_FAILED = 0, 1, 2, 3
#: status code → the name the results directory uses
STATUS_NAMES = {STATUS_OK: "ok", STATUS_FELL: "fell", STATUS_NONFINITE: "nonfinite",
                STATUS_QP_FAILED: "qp_failed"}


#: the fields of :class:`Log`, ``name: meaning [unit] (shape) dtype`` (float64 where none is
#: given), one entry per field (an entry may run over several lines)
FIELD_DOC = """
    t: the planner's clock at SSP⁻_k, k T with T = T_SSP + T_DSP [s] (S, K)
    t_plant: the plant's own clock at SSP⁻_k (a Cassie step ends at its detected touchdown,
      so its steps need not last T) [s] (S, K)
    stance: stance foot of the step that starts at SSP⁻_k, 0 left 1 right (S, K) int32
    x_hlip: the H-LIP nominal's state x_H,k per plane [m, m, m/s] (S, K, 2, 3)
    x_robot: the robot's state x_R,k per plane [m, m, m/s] (S, K, 2, 3)
    x_est: x_R,k as the robot's controller measured and estimated it (sensing noise, IMU bias,
      the COM velocity filter of a non-ideal Cassie; equal to x_robot on a plant that senses
      perfectly) [m, m, m/s] (S, K, 2, 3)
    e: tracking error x_R,k − x_H,k [m, m, m/s] (S, K, 2, 3)
    w: S2S residual x_R,k+1 − A x_R,k − B u_R,k (:func:`s2s_residual`); NaN where step k or
      k+1 is not valid [m, m, m/s] (S, K, 2, 3)
    u_hlip: the H-LIP's step u_H,k per plane [m] (S, K, 2)
    u_robot: the robot's executed step u_R,k per plane [m] (S, K, 2)
    ref_pos: the path's point at t_k [m] (S, K, 2)
    ref_vel: the path's velocity at t_k [m/s] (S, K, 2)
    ref_heading: the path's heading θ_d(t_k) [rad] (S, K)
    qp_status: the MPC QP's status code (:mod:`hlip_jax.core.qp`) (S, K) int32
    qp_iter: the MPC QP's ADMM iterations (S, K) int32
    obstacle_slack: largest keep-out slack of the MPC plan [m] (S, K)
    clearance: smallest COM distance to an obstacle's keep-out disc (inf without obstacles)
      [m] (S, K)
    leg_gap: smallest clearance of step k (SSP⁻_k → SSP⁻_k+1) between the two feet and between
      any two lower-leg links of opposite legs (:mod:`hlip_jax.plants.cassie.collisions`;
      below zero: the links overlap; inf on the point-foot H-LIP plant) [m] (S, K, 2)
    valid: step k was simulated and the robot still walked (S, K) bool
    status: the scenario's outcome, one of :data:`STATUS_NAMES` (S,) int32
    fail_step: first step at which the robot fell, −1 if it did not (S,) int32
    A: the planner's 3-state S2S matrix per scenario (S, 3, 3)
    B: the planner's S2S input vector (S, 3)
    K_gain: the stepping gain per plane on [c, p, v] (S, 2, 3)
    anchor: 1 for each coordinate of [c, p, v] that the nominal restarts from the robot's
      state before every plan (``mpc.mode``: "tube" none, "position" c, "measured" all, and
      then with the robot's executed step too; :func:`hlip_jax.core.invariant.closed_loop`) (S, 3)
"""


class Log(NamedTuple):
    """Per-step record of a batch of closed loops; fields in :data:`FIELD_DOC`."""
    t: np.ndarray
    t_plant: np.ndarray
    stance: np.ndarray
    x_hlip: np.ndarray
    x_robot: np.ndarray
    x_est: np.ndarray
    e: np.ndarray
    w: np.ndarray
    u_hlip: np.ndarray
    u_robot: np.ndarray
    ref_pos: np.ndarray
    ref_vel: np.ndarray
    ref_heading: np.ndarray
    qp_status: np.ndarray
    qp_iter: np.ndarray
    obstacle_slack: np.ndarray
    clearance: np.ndarray
    leg_gap: np.ndarray
    valid: np.ndarray
    status: np.ndarray
    fail_step: np.ndarray
    A: np.ndarray
    B: np.ndarray
    K_gain: np.ndarray
    anchor: np.ndarray


#: every field, in order
FIELDS = Log._fields


def _documented_layout() -> dict[str, tuple[tuple, str]]:
    """{field: (shape with "S" and "K" for the scenario and step axes, dtype)} parsed from the
    :data:`FIELD_DOC`'s ``name: ... (shape) dtype`` entries (an entry may run over several
    lines)."""
    entries = re.split(r"\n    (?=\w+: )", "\n" + FIELD_DOC)[1:]
    out = {}
    for e in entries:
        name = e.split(":", 1)[0]
        m = re.search(r"\(([SK0-9, ]+)\)\s*(\w+)?\s*$", e.strip())
        dims = tuple(d if d in "SK" else int(d) for d in m.group(1).replace(" ", "").split(",") if d)
        out[name] = (dims, m.group(2) or "float64")
    return out


#: field → (documented shape, dtype), from :data:`FIELD_DOC` (:func:`_documented_layout`)
LAYOUT = _documented_layout()
#: the fields with a step axis (axis 1), padded when chunks of different K are joined
STEP_FIELDS = tuple(f for f in FIELDS if LAYOUT[f][0][1:2] == ("K",))


def zeros(S: int, K: int) -> dict[str, np.ndarray]:
    """A zero-filled log of S scenarios and K steps, one array per field with its documented
    shape and dtype (the tests' fake closed loops start from it)."""
    size = {"S": S, "K": K}
    return {f: np.zeros(tuple(size.get(d, d) for d in LAYOUT[f][0]), LAYOUT[f][1])
            for f in FIELDS}


def alive(valid: np.ndarray) -> np.ndarray:
    """Steps before the first invalid one, per scenario: cumprod of ``valid`` along the step
    axis (bool, same shape)."""
    return np.cumprod(np.asarray(valid, bool), axis=-1).astype(bool)


def s2s_residual(A: np.ndarray, B: np.ndarray, x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """w_k = x_{k+1} − A x_k − B u_k per plane for one scenario: A (3, 3), B (3,), x (K, 2, 3),
    u (K, 2); returns (K−1, 2, 3)."""
    return x[1:] - x[:-1] @ A.T - u[:-1, :, None] * B


def to_heading_frame(vec: np.ndarray, heading: np.ndarray) -> np.ndarray:
    """World (x, y) pairs on the plane axis (−2 for [..., 2, n] arrays, −1 for [..., 2]) seen in
    the frame of ``heading`` θ (broadcast over the leading axes): (along θ, to its left)."""
    vec = np.asarray(vec)
    th = np.asarray(heading)
    c, s = np.cos(th), np.sin(th)
    if vec.ndim == th.ndim + 2:                     # [..., 2, n]: planes of a state
        c, s = c[..., None], s[..., None]
        x, y = vec[..., 0, :], vec[..., 1, :]
        return np.stack([c * x + s * y, -s * x + c * y], axis=-2)
    x, y = vec[..., 0], vec[..., 1]
    return np.stack([c * x + s * y, -s * x + c * y], axis=-1)
