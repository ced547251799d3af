"""W estimators and the error sets E built from them: one registry, distinct names.

Each method turns a training side (per training run of one plane: its kept disturbance samples
d, its kept errors e, whether it fell) into a disturbance set W and an error set E for
e⁺ = A_cl e + d (:mod:`hlip_jax.analysis.errors`):

``box``
    W = the per-axis [min, max] box of the samples; E = mRPI(A_cl, W) (Raković et al. 2005,
    outer set F_s/(1−α); :func:`hlip_jax.core.sets.mrpi`).  Invariance: if every future d stays in
    W, every error started in E stays in E.  No probability statement.
``hull``
    W = the convex hull of the samples; E = mRPI(A_cl, W) (template outer approximation).
``conformal_step``
    W = [−r, r], r_j the ⌈(n+1) q⌉-th smallest |d_j| of the n pooled steps (split conformal
    per coordinate); E = mRPI(A_cl, W).  The level q is a statement about single steps that are
    exchangeable, which serially correlated steps of one run are not; kept as a comparison.
``conformal_run``
    The run-level calibrated set.  E_shape = mRPI(A_cl, box W), W from the shape half of the
    training runs (:func:`shape_and_calibration`); each calibration run i scores
    s_i = max_k g(e_k), the largest gauge (:func:`hlip_jax.core.sets.gauge`: the scale of E_shape
    about its centre that just holds e_k) over its kept errors, +inf for a run that fell (a
    fallen run is scored, not dropped); E_q = s_(m) E_shape with m = ⌈(n+1) q⌉ over the n
    calibration runs.  Guarantee (split conformal prediction over runs): a new run drawn
    exchangeably with the training runs stays in E_q at every kept step, and does not fall,
    with probability ≥ q (and < q + 1/(n+1) without ties), marginally over the training draw.
    Needs n ≥ q / (1 − q) calibration runs (2n training runs) and fewer than (1 − q)(n + 1)
    falls among them.
``conformal_box``
    The same run-level calibration with E_shape the box of the shape half's errors instead of
    an mRPI set: centre ē the mean of the walking shape runs' kept errors, half-width
    t_j the median over those runs of each run's largest |e_j − ē_j|.  The gauge is then
    max_j |e_j − ē_j| / t_j, so every coordinate is equally likely to set a run's score, and
    E_q = s_(m) E_shape reaches along each coordinate about as far as the runs' errors do.
    An mRPI shape cannot: its extent in each direction is the worst-case sum of disturbances
    through A_cl, whose corners the runs' errors, partly cancelling from step to step, do not
    reach, so the scale that holds a run's errors in p or v leaves E far beyond them in c.
    Same guarantee as ``conformal_run``; not an invariant set.

W and E_shape are fitted to the runs that walked (a fall's last steps are the controller
failing, not a disturbance it met while walking); the calibrated methods' scores count the
falls.
"""

from __future__ import annotations

import math
from typing import Callable, NamedTuple, Sequence

import numpy as np

from hlip_jax.core import invariant as inv
from hlip_jax.core import sets
from hlip_jax.analysis.errors import W_MIN_HALFWIDTH


class Method(NamedTuple):
    """A registered method: ``w`` (samples (N, n), q) → W; ``shape`` (A_cl, W, the walking
    training runs' kept errors) → E (or E_shape); ``calibrated``: E_shape is scaled to the
    training runs' scores (run-level conformal) instead of being the set itself."""
    name: str
    w: Callable
    shape: Callable
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


def mrpi_shape(A_cl: np.ndarray, W, runs_e=None):
    """E = mRPI(A_cl, W) (:func:`hlip_jax.core.invariant.mrpi`; a flat box axis is widened to
    :data:`W_MIN_HALFWIDTH`)."""
    return inv.mrpi(A_cl, W, min_halfwidth=W_MIN_HALFWIDTH if isinstance(W, sets.Box) else None)


def error_box(A_cl, W, runs_e: Sequence[np.ndarray]) -> sets.Box:
    """E_shape of ``conformal_box``: centre ē = mean of the kept errors of ``runs_e`` (each
    (k_i, n)), half-width t_j = median over the runs of max_k |e_kj − ē_j| (at least
    :data:`W_MIN_HALFWIDTH`); ValueError when no run has a kept error."""
    runs_e = [np.asarray(e, np.float64) for e in runs_e if len(e)]
    if not runs_e:
        raise ValueError("no kept errors on the training side")
    c = np.concatenate(runs_e).mean(axis=0)
    t = np.median([np.max(np.abs(e - c), axis=0) for e in runs_e], axis=0)
    t = np.maximum(t, W_MIN_HALFWIDTH)
    return sets.Box(c - t, c + t)


#: the registry, in the order coverage.csv lists the methods
METHODS = {m.name: m for m in (
    Method("box", box_w, mrpi_shape, False, False),
    Method("hull", hull_w, mrpi_shape, False, False),
    Method("conformal_step", conformal_step_w, mrpi_shape, False, True),
    Method("conformal_run", box_w, mrpi_shape, True, True),
    Method("conformal_box", box_w, error_box, True, True),
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
    walked = [i for i, (e, f) in enumerate(zip(runs_e, fell)) if not f and len(e)]
    if walked:              # one gauge call over every run's errors, then the max per run
        parts = [np.asarray(runs_e[i], np.float64) for i in walked]
        g = sets.gauge(E_shape, np.concatenate(parts))
        starts = np.r_[0, np.cumsum([len(x) for x in parts])[:-1]]
        out[walked] = np.maximum.reduceat(g, starts)
    out[[i for i, f in enumerate(fell) if f]] = math.inf
    return out


def calibrate(E_shape, scores: np.ndarray, q: float) -> sets.Scaled:
    """E_q = s_(⌈(n+1) q⌉) E_shape; ValueError when that score is +inf (too many falls)."""
    s = np.sort(np.asarray(scores, np.float64))[conformal_rank(len(scores), q) - 1]
    if not math.isfinite(s):
        raise ValueError(f"conformal_run q = {q}: more than a fraction 1 - q of the "
                         f"{len(scores)} training runs fell; E_q is unbounded")
    return sets.Scaled(E_shape, float(s))


class Fitted(NamedTuple):
    """A method's sets for one plane: ``W`` the disturbance set, ``E`` the error set (for a
    calibrated method E_q = s E_shape, a :class:`hlip_jax.core.sets.Scaled`), ``samples`` the
    disturbance samples W came from, ``calibration_runs`` the runs scored (0 for an
    uncalibrated method)."""
    W: object
    E: object
    samples: int
    calibration_runs: int


def shape_and_calibration(n: int) -> tuple[list, list]:
    """The training runs' roles in a calibrated method: (shape, calibration) indices into the
    n training runs, alternate positions (0, 2, 4, … shape; 1, 3, 5, … calibrate).  E_shape
    then does not depend on the runs that are scored, so the calibration runs and a new run
    are exchangeable given E_shape: the split-conformal guarantee is exact."""
    return list(range(0, n, 2)), list(range(1, n, 2))


def _walkers(runs_x: Sequence[np.ndarray], fell: Sequence[bool]) -> list:
    return [x for x, f in zip(runs_x, fell) if not f]


def fit(name: str, A_cl: np.ndarray, runs_d: Sequence[np.ndarray], runs_e: Sequence[np.ndarray],
        fell: Sequence[bool], q: float) -> Fitted:
    """The sets of method ``name`` for one plane: A_cl (n, n); per training run its kept
    disturbances (k_i, n), its kept errors (k_i, n) and whether it fell.  W and E_shape come
    from the runs that walked; a calibrated method takes them from half of the training runs
    and scores the other half (:func:`shape_and_calibration`), falls included.  ValueError
    when the set cannot be formed (no samples, too few runs for q, A_cl not Schur stable)."""
    m = method(name)
    if not inv.schur_stable(A_cl):
        raise ValueError("A + BK is not Schur stable: no bounded E")
    shape_ix, cal_ix = (shape_and_calibration(len(runs_e)) if m.calibrated
                        else (range(len(runs_e)), []))
    sd = _walkers([runs_d[i] for i in shape_ix], [fell[i] for i in shape_ix])
    se = _walkers([runs_e[i] for i in shape_ix], [fell[i] for i in shape_ix])
    d = np.concatenate(sd) if sd else np.zeros((0, np.shape(A_cl)[-1]))
    W = m.w(d, q)
    E = m.shape(A_cl, W, se)
    if m.calibrated:
        E = calibrate(E, run_scores(E, [runs_e[i] for i in cal_ix], [fell[i] for i in cal_ix]), q)
    return Fitted(W, E, int(d.shape[0]), len(cal_ix))


def half_widths(E, dim: int) -> np.ndarray:
    """max(h_E(u_j), h_E(−u_j)) per state axis j: E's reach from the origin along c, p, v."""
    D = np.concatenate([np.eye(dim), -np.eye(dim)])
    h = np.asarray(E.support(D), np.float64)
    return np.maximum(h[:dim], h[dim:])
