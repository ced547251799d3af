"""How far a robot's step-to-step (S2S) map is from the H-LIP's: a least-squares fit from the
step log.

The paper approximates the robot's S2S dynamics by the H-LIP's, x_{k+1} = A x_k + B u_k + w_k,
and bounds the residual w.  Part of w can be systematic: a robot whose steps move its COM
less than the H-LIP predicts has, in effect, other A and B.  This module fits, per plane of the
path's heading frame (sagittal, lateral), the 2-state map of [p, v] (p the COM relative to the
stance foot [m], v the COM velocity [m/s], at SSP⁻)

    [p, v]_{k+1} = Â [p, v]_k + B̂ u_k + ĉ_s,        ĉ_s one offset per stance foot s,

by least squares over every pair of valid consecutive steps (k, k+1) of the chosen scenarios
(states and steps rotated into the heading frame θ_d(t_k) of step k).  The stance offsets take
the constant, side-alternating part of w (a lateral gait's P2 orbit); Â, B̂ the part that
scales with the state and the step.  Where B̂'s velocity row is smaller in magnitude than the
H-LIP's −λ sinh(λ T_SSP), a step moves the robot's velocity less than the planner assumes:
a stepping gain designed on the H-LIP (deadbeat above all) then mis-corrects.

The fit needs excitation: steps that vary independently of the state (noise, pushes, changing
speeds).  ``rank`` reports the regressor's rank; a rank below 5 (p, v, u, two offsets) leaves
the coefficients undetermined (they are then the minimum-norm solution).
"""

from __future__ import annotations

from typing import NamedTuple, Sequence

import numpy as np

from hlip_jax.core import steplog


class S2SFit(NamedTuple):
    """Fitted S2S map per plane (axis 0: sagittal, lateral of the heading frame)."""
    A: np.ndarray        # (2, 2, 2) Â of [p, v] [—, s; 1/s, —]
    B: np.ndarray        # (2, 2) B̂ on the step u [—; 1/s]
    offset: np.ndarray   # (2, 2, 2) ĉ per plane, stance (0 left, 1 right), [p, v] [m; m/s]
    rms: np.ndarray      # (2, 2) RMS of the fit's residual on [p, v] [m; m/s]
    n: int               # step pairs used
    rank: np.ndarray     # (2,) rank of each plane's regressor (5 = fully determined)


def pairs(log: dict, scenarios: Sequence[int], skip: int = 4):
    """Regressors and targets of every usable step pair: (X (n, 2, 5), Y (n, 2, 2)) with
    X = [p_k, v_k, u_k, stance_k = left, stance_k = right] and Y = [p_{k+1}, v_{k+1}], per
    plane in the heading frame of step k.  A pair is usable when both steps are valid,
    finite, and k ≥ ``skip`` (the start-up steps from rest are left out)."""
    X, Y = [], []
    for s in scenarios:
        valid = steplog.alive(log["valid"][s])
        x = steplog.to_heading_frame(log["x_robot"][s], log["ref_heading"][s])    # (K, 2, 3)
        u = steplog.to_heading_frame(log["u_robot"][s], log["ref_heading"][s])    # (K, 2)
        x_next = steplog.to_heading_frame(log["x_robot"][s][1:], log["ref_heading"][s][:-1])
        stance = log["stance"][s]
        for k in range(skip, len(valid) - 1):
            if not (valid[k] and valid[k + 1] and np.all(np.isfinite(x_next[k]))):
                continue
            side = np.array([stance[k] == 0, stance[k] == 1], float)
            X.append([np.r_[x[k, j, 1:], u[k, j], side] for j in range(2)])
            Y.append(x_next[k, :, 1:])
    return np.asarray(X, float).reshape(-1, 2, 5), np.asarray(Y, float).reshape(-1, 2, 2)


def fit(log: dict, scenarios: Sequence[int] | None = None, skip: int = 4) -> S2SFit:
    """Least-squares S2S map (module doc) from the step log ``log`` (arrays as
    :func:`hlip_jax.sweepio.store.load_log` returns them) over ``scenarios`` (default: all)."""
    if scenarios is None:
        scenarios = range(np.asarray(log["valid"]).shape[0])
    X, Y = pairs(log, list(scenarios), skip)
    if len(X) < 5:
        raise ValueError(f"scenarios: {len(X)} usable step pairs; the fit needs at least 5")
    A, B, off, rms, rank = (np.zeros((2, 2, 2)), np.zeros((2, 2)), np.zeros((2, 2, 2)),
                            np.zeros((2, 2)), np.zeros(2, int))
    for j in range(2):
        coef, _, rank[j], _ = np.linalg.lstsq(X[:, j], Y[:, j], rcond=None)       # (5, 2)
        A[j], B[j], off[j] = coef[:2].T, coef[2], coef[3:]
        rms[j] = np.sqrt(np.mean((Y[:, j] - X[:, j] @ coef) ** 2, axis=0))
    return S2SFit(A=A, B=B, offset=off, rms=rms, n=len(X), rank=rank)


def hlip_rows(A3: np.ndarray, B3: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The H-LIP's 2-state (A (2, 2), B (2,)) on [p, v] from its 3-state A3 (3, 3), B3 (3,) on
    [c, p, v] (the rows and columns of p and v)."""
    A3, B3 = np.asarray(A3), np.asarray(B3)
    return A3[1:, 1:], B3[1:]


def residuals(log: dict, scenarios: Sequence[int], model: S2SFit | None, skip: int = 4,
              hlip: tuple | None = None) -> np.ndarray:
    """Residuals Y − X θ (n, 2 planes, [p, v]) of the step pairs of ``scenarios``
    (:func:`pairs`) under ``model`` (a fit), or under the H-LIP's ``hlip`` = (A (2, 2), B (2,))
    (no stance offsets) when ``model`` is None: held-out runs measure how much of w a fit
    explains [m; m/s]."""
    X, Y = pairs(log, list(scenarios), skip)
    out = np.empty_like(Y)
    for j in range(2):
        if model is None:
            A, B = hlip
            coef = np.vstack([A.T, B[None], np.zeros((2, 2))])
        else:
            coef = np.vstack([model.A[j].T, model.B[j][None], model.offset[j]])
        out[:, j] = Y[:, j] - X[:, j] @ coef
    return out
