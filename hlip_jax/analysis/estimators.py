"""W estimators and the error sets E built from them: one registry, distinct names.

Each method turns a training side (the kept disturbance samples d of one plane, pooled over the
training runs, and each training run's kept errors) into a disturbance set W and an error set
E for e⁺ = A_cl e + d (:mod:`hlip_jax.analysis.errors`):

``box``
    W = the per-axis [min, max] box of the samples; E = mRPI(A_cl, W) (Raković et al. 2005,
    outer set F_s/(1−α); :func:`hlip_jax.sets.mrpi`).  Invariance: if every future d stays in
    W, every error started in E stays in E.  No probability statement.
``hull``
    W = the convex hull of the samples; E = mRPI(A_cl, W) (template outer approximation).
``conformal_step``
    W = [−r, r], r_j the ⌈(n+1) q⌉-th smallest |d_j| of the n pooled steps (split conformal
    per coordinate); E = mRPI(A_cl, W).  The level q is a statement about single steps that are
    exchangeable, which serially correlated steps of one run are not; kept as a comparison.
``conformal_run``
    The run-level calibrated set.  E_shape = mRPI(A_cl, box W); each training run i scores
    s_i = max_k g(e_k), the largest gauge (:func:`hlip_jax.sets.gauge`: the scale of E_shape
    about its centre that just holds e_k) over its kept errors, +inf for a run that fell (a
    fallen training run is scored, not dropped); E_q = s_(m) E_shape with m = ⌈(n+1) q⌉ over
    the n training runs.  Guarantee (split conformal prediction over runs): a new run drawn
    exchangeably with the training runs stays in E_q at every kept step, and does not fall,
    with probability ≥ q (and < q + 1/(n+1) without ties), marginally over the training draw.
    Needs n ≥ q / (1 − q) runs and fewer than (1 − q)(n + 1) falls.

The box and hull sets are fitted to the training runs that walked (a fall's last steps are the
controller failing, not a disturbance it met while walking); the conformal_run score counts
the falls.
"""

from __future__ import annotations

import math
from typing import Callable, NamedTuple, Sequence

import numpy as np

from hlip_jax import invariant as inv
from hlip_jax import sets
from hlip_jax.analysis.errors import W_MIN_HALFWIDTH


class Method(NamedTuple):
    """A registered method: ``w`` (samples (N, n), q) → W; ``calibrated``: E is scaled to the
    training runs' scores (run-level conformal) instead of being W's mRPI set."""
    name: str
    w: Callable
    calibrated: bool
    uses_q: bool


def conformal_rank(n: int, q: float) -> int:
    """m = ⌈(n+1) q⌉, the order statistic of a split-conformal bound over n scores;
    ValueError when m > n (n ≥ q / (1 − q) needed)."""
    if not 0.0 < q < 1.0:
        raise ValueError(f"q: expected a level in (0, 1), got {q!r}")
    m = math.ceil((n + 1) * q - 1e-12)
    if m > n:
        raise ValueError(f"conformal level q = {q}: needs n >= {math.ceil(q / (1 - q) - 1e-9)} "
                         f"training units, got {n}")
    return max(m, 1)


def _samples(d) -> np.ndarray:
    P = np.asarray(d, np.float64).reshape(-1, np.shape(d)[-1])
    if P.shape[0] == 0:
        raise ValueError("no disturbance samples on the training side")
    return P


def box_w(d, q=None) -> sets.Box:
    """Per-axis [min, max] of the samples d (N, n)."""
    P = _samples(d)
    return sets.Box(P.min(axis=0), P.max(axis=0))


def hull_w(d, q=None) -> sets.Hull:
    """Convex hull of the samples d (N, n) (scipy Qhull)."""
    return inv.estimate_w(_samples(d), method="hull")


def conformal_step_w(d, q: float) -> sets.Box:
    """Symmetric box [−r, r], r_j the ⌈(n+1) q⌉-th smallest |d_j| of the N samples."""
    P = np.abs(_samples(d))
    r = np.sort(P, axis=0)[conformal_rank(P.shape[0], q) - 1]
    return sets.Box(-r, r)


#: the registry, in the order coverage.csv lists the methods
METHODS = {m.name: m for m in (
    Method("box", box_w, False, False),
    Method("hull", hull_w, False, False),
    Method("conformal_step", conformal_step_w, False, True),
    Method("conformal_run", box_w, True, True),
)}


def method(name: str) -> Method:
    """The registered method ``name``; ValueError listing the names otherwise."""
    if name not in METHODS:
        raise ValueError(f"W method {name!r}; allowed: {', '.join(METHODS)}")
    return METHODS[name]


def run_scores(E_shape, runs_e: Sequence[np.ndarray], fell: Sequence[bool]) -> np.ndarray:
    """Per run: max over its kept errors (each (k_i, n)) of the gauge of E_shape; +inf for a
    run that fell; 0 for a run without kept errors."""
    out = np.zeros(len(runs_e))
    for i, (e, f) in enumerate(zip(runs_e, fell)):
        if f:
            out[i] = math.inf
        elif len(e):
            out[i] = float(np.max(sets.gauge(E_shape, e)))
    return out


def calibrate(E_shape, scores: np.ndarray, q: float) -> sets.Scaled:
    """E_q = s_(⌈(n+1) q⌉) E_shape; ValueError when that score is +inf (too many falls)."""
    s = np.sort(np.asarray(scores, np.float64))[conformal_rank(len(scores), q) - 1]
    if not math.isfinite(s):
        raise ValueError(f"conformal_run q = {q}: more than a fraction 1 - q of the "
                         f"{len(scores)} training runs fell; E_q is unbounded")
    return sets.Scaled(E_shape, float(s))


def fit(name: str, A_cl: np.ndarray, d, runs_e: Sequence[np.ndarray], fell: Sequence[bool],
        q: float):
    """(W, E) of method ``name`` for one plane: A_cl (n, n); d (N, n) the kept disturbance
    samples of the training runs that walked; runs_e: each training run's kept errors
    (k_i, n); fell: whether each training run fell.  ValueError when the set cannot be formed
    (no samples, too few runs for q, A_cl not Schur stable)."""
    m = method(name)
    if not inv.schur_stable(A_cl):
        raise ValueError("A + BK is not Schur stable: no bounded E")
    W = m.w(d, q)
    E = inv.mrpi(A_cl, W, min_halfwidth=W_MIN_HALFWIDTH if isinstance(W, sets.Box) else None)
    if m.calibrated:
        E = calibrate(E, run_scores(E, runs_e, fell), q)
    return W, E


def half_widths(E, dim: int) -> np.ndarray:
    """max(h_E(u_j), h_E(−u_j)) per state axis j: E's reach from the origin along c, p, v."""
    D = np.concatenate([np.eye(dim), -np.eye(dim)])
    h = np.asarray(E.support(D), np.float64)
    return np.maximum(h[:dim], h[dim:])
