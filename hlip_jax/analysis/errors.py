"""The error system of a run, defined once: from a step log to the errors e_k, the error
system's matrix A_cl and its disturbances d_k, in the frame and state the analysis uses.

With the stepping law ``u = u_HLIP + K (x_robot − x_HLIP) + δu`` (δu the foot-placement error a
robot adds) the S2S error e = x_R − x_H obeys, per plane,

    e_{k+1} = A_cl e_k + d_k,   d_k = w_k + β B δu_k,   w_k = x_R,k+1 − A x_R,k − B u_R,k,

with A_cl and β from the loop's anchoring (:func:`hlip_jax.core.invariant.closed_loop`).  The
S2S residual w is :func:`hlip_jax.core.steplog.s2s_residual`, the only definition of w.  Errors and
disturbances are rotated into the path's heading frame when both planes share one gain
(:func:`analysis_frame`).  Units: c and p in metres, v in m/s.
"""

from __future__ import annotations

import numpy as np

from hlip_jax.core import invariant as inv
from hlip_jax.core import steplog


def error_model(log: dict, s: int):
    """(A, B, K, state slice) of the error dynamics of scenario ``s`` (e⁺ = (A + BK) e + w in
    the tube; :func:`closed_loop` for every mode).

    A gain that acts on the global position c (non-zero c entry), or a nominal whose c restarts
    from the robot's every step (the log's ``anchor``), bounds the error in c: the analysis
    uses the full [c, p, v] state.  A tube gain on [p, v] only leaves c integrating
    (eigenvalue 1: no bounded invariant set in c), so the analysis then uses the 2-state
    [p, v] system."""
    A = np.asarray(log["A"][s], np.float64)
    B = np.asarray(log["B"][s], np.float64)
    K = np.asarray(log["K_gain"][s], np.float64)
    if K.shape[-1] == 3 and (np.any(K[:, 0] != 0.0) or _anchor(log, s)[0] == 1.0):
        return A, B, K, slice(0, 3)
    return A[1:, 1:], B[1:], K[:, -2:], slice(1, 3)


def _anchor(log: dict, s: int) -> np.ndarray:
    return np.asarray(log["anchor"][s], np.float64)


def error_system(log: dict, s: int):
    """(A, B, K, state slice, A_cl, β): :func:`error_model` and :func:`closed_loop` of
    scenario ``s`` from one evaluation of the error model."""
    A, B, K, sl = error_model(log, s)
    return (A, B, K, sl, *inv.closed_loop(A, B, K, _anchor(log, s)[sl]))


def closed_loop(log: dict, s: int):
    """(A_cl (2, n, n), β) of scenario ``s``'s error system e⁺ = A_cl e + w + β B δu on the
    state :func:`error_model` picks (:func:`hlip_jax.core.invariant.closed_loop`)."""
    return error_system(log, s)[4:]


#: W boxes narrower than this half-width in an axis are widened to it [m or m/s]: a state the
#: disturbance never reaches (e.g. every axis of a noise-free float64 H-LIP run) would
#: otherwise give a flat W, for which no mRPI set with an interior exists.
W_MIN_HALFWIDTH = 1e-6


def placement(log: dict, s: int) -> np.ndarray:
    """(K, 2) foot-placement errors δu_k of scenario ``s`` [m] (NaN where e is)."""
    return inv.placement_errors(log["u_robot"][s], log["u_hlip"][s], log["e"][s],
                                log["K_gain"][s])


def analysis_frame(log: dict, s: int) -> str:
    """The frame of scenario ``s``'s per-plane error analysis: "heading" (sagittal along the
    path heading θ_d(t_k), lateral to its left; :func:`hlip_jax.core.invariant.heading_frame`) when
    the stepping gain is the same in both planes, else "world" (x, y): a different gain per
    plane does not commute with the rotation."""
    K = np.asarray(log["K_gain"][s], np.float64)
    return "heading" if K.ndim == 1 or np.array_equal(K[0], K[1]) else "world"


def error_samples(log: dict, s: int, mask: np.ndarray, du: np.ndarray):
    """(A, B, K, A_cl, e, w, wmask) of scenario ``s`` in its analysis frame and state
    (:func:`analysis_frame`, :func:`error_model`): the closed-loop matrix A_cl (2, n, n) of
    :func:`closed_loop`, errors e (K, 2, n), error-system disturbances w (K−1, 2, n) with
    e_{k+1} = A_cl e_k + w_k, and the mask of counted w (both ends in ``mask``); ``du``
    (K, 2): the foot-placement errors (:func:`_placement`)."""
    A, B, Kg, sl, Acl, beta = error_system(log, s)
    x = np.asarray(log["x_robot"][s], np.float64)[:, :, sl]     # (K, 2, n)
    u = np.asarray(log["u_robot"][s], np.float64)
    e = np.asarray(log["e"][s], np.float64)[:, :, sl]
    # the error system's disturbance d = w + B δu: w from the robot's own S2S data (same
    # definition as the log's w), δu its foot-placement error
    w = steplog.s2s_residual(A, B, x, u)
    w = w + beta * B[None, None, :] * du[:-1, :, None]
    if analysis_frame(log, s) == "heading":
        e, w = inv.heading_frame(np.where(mask[:, None, None], e, 0.0), w,
                                 np.asarray(log["ref_heading"][s], np.float64), Acl[0])
    return A, B, Kg, Acl, e, w, mask[1:] & mask[:-1]
