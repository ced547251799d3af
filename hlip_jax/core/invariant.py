"""Disturbance sets W and error-invariant sets E of the step-to-step (S2S) error dynamics.

With the stepping law ``u = u_HLIP + K (x_robot − x_HLIP)`` the S2S error e = x_robot − x_HLIP
obeys (per plane, sagittal and lateral)

    e⁺ = A_cl e + w,   A_cl = A + B K,   w ∈ W,

where ``w_k = x_{k+1} − A x_k − B u_k`` is measured from the robot's own pre-impact states and
executed step sizes.  A robot whose feet do not land exactly where the law asks adds the
foot-placement error δu_k = u_k − (u_HLIP,k + K e_k) (:func:`placement_errors`):

    e⁺ = A_cl e + w + B δu,

so the disturbance the error dynamics actually see is d = w + B δu = e⁺ − A_cl e;
:func:`analyse` bounds d when it is given the H-LIP steps (on a plant that places its feet
exactly, d = w).  The smallest set that every error trajectory started at 0 stays in is the
minimal robust positively invariant (mRPI) set

    F_∞ = ⊕_{i≥0} A_cl^i W.

The sets (boxes, zonotopes, hulls, the mRPI bracket of Raković et al. 2005) are in
:mod:`hlip_jax.core.sets`; figures of them in :mod:`hlip_jax.presentation.set_figures`.  This module turns a
run's step log into disturbance samples, estimates W, builds E and measures coverage.
"""

from __future__ import annotations

from typing import Any, NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np

from hlip_jax.core import steplog
# the set types and the mRPI construction live in hlip_jax.core.sets; re-exported for the analysis API
from hlip_jax.core.sets import (MRPI, Box, Hull, TemplatePolytope, Zonotope,  # noqa: F401
                           as_float64, convex_hull, mrpi, schur_stable, truncated_sum, vertices,
                           zonotope, zonotope_halfspaces)

# ---------------------------------------------------------------------------------------------
# disturbances and W estimators
# ---------------------------------------------------------------------------------------------

class Disturbances(NamedTuple):
    """w samples per plane: ``w`` (..., n_steps−1, 2, n), ``mask`` (..., n_steps−1) bool.
    w[..., k, plane, :] = x_{k+1} − A x_k − B u_k (n = 3 for [c, p, v], 2 for [p, v])."""
    w: jax.Array
    mask: jax.Array


def _plane_mats(A, B, n_state=None):
    A = jnp.asarray(A)
    B = jnp.asarray(B)
    if A.ndim == 2:
        A = jnp.broadcast_to(A, (2,) + A.shape)
    if B.ndim == 1:
        B = jnp.broadcast_to(B, (2,) + B.shape)
    n = A.shape[-1]
    if A.shape != (2, n, n) or n not in (2, 3):
        raise ValueError(f"A: shape (n, n) or (2, n, n) with n in (2, 3) expected, got {A.shape}")
    if B.shape != (2, n):
        raise ValueError(f"B: shape ({n},) or (2, {n}) expected to match A, got {B.shape}")
    return A, B


def _states(x, n):
    """Select [c, p, v] (n = 3) or [p, v] (n = 2, drop c) from (..., 3) states."""
    if x.shape[-1] != 3:
        raise ValueError(f"x_robot / e: last axis must be the per-plane state [c, p, v] (size 3), "
                         f"got {x.shape[-1]}")
    return x if n == 3 else x[..., 1:]


def step_mask(valid, transient: int = 0):
    """Valid-and-settled mask (..., n_steps): step k counts if k ≥ transient and every step
    0..k is valid (so everything after the first failure is dropped)."""
    valid = jnp.asarray(valid, bool)
    alive = jnp.cumprod(valid.astype(jnp.int32), axis=-1).astype(bool)
    k = jnp.arange(valid.shape[-1])
    return alive & (k >= transient)


@jax.jit
def _disturbances(x, u, valid, A, B, transient):
    n = A.shape[-1]
    xs = _states(x, n)  # (..., T, 2, n)
    pred = jnp.einsum("pij,...pj->...pi", A, xs[..., :-1, :, :]) + B * u[..., :-1, :, None]
    w = xs[..., 1:, :, :] - pred
    m = step_mask(valid, transient)
    mask = m[..., :-1] & m[..., 1:]
    return Disturbances(w, mask)


def disturbances(x_robot, u_exec, valid, A, B, transient: int = 0) -> Disturbances:
    """Per-plane S2S disturbances w_k = x_{k+1} − A x_k − B u_k from a log.

    Args:
      x_robot: (..., n_steps, 2, 3) pre-impact states [c [m], p [m], v [m/s]] per plane
        (plane 0 sagittal, 1 lateral).
      u_exec: (..., n_steps, 2) executed step sizes [m].
      valid: (..., n_steps) bool, step data valid.
      A, B: (n, n), (n,) or per plane (2, n, n), (2, n); n = 3 uses [c, p, v], n = 2 drops c.
      transient: steps k < transient are excluded (w_k needs steps k and k+1 counted).
    Returns :class:`Disturbances` (w (..., n_steps−1, 2, n), mask (..., n_steps−1)).
    """
    x = jnp.asarray(x_robot)
    u = jnp.asarray(u_exec, x.dtype)
    v = jnp.asarray(valid, bool)
    if x.ndim < 3 or x.shape[-2:] != (2, 3):
        raise ValueError(f"x_robot: shape (..., n_steps, 2, 3) expected, got {x.shape}")
    if u.shape != x.shape[:-1]:
        raise ValueError(f"u_exec: shape {x.shape[:-1]} expected (..., n_steps, 2), got {u.shape}")
    if v.shape != x.shape[:-2]:
        raise ValueError(f"valid: shape {x.shape[:-2]} expected (..., n_steps), got {v.shape}")
    if x.shape[-3] < 2:
        raise ValueError(f"x_robot: n_steps ≥ 2 needed, got {x.shape[-3]}")
    if int(transient) < 0:
        raise ValueError(f"transient: must be ≥ 0, got {transient}")
    Ap, Bp = _plane_mats(A, B)
    return _disturbances(x, u, v, Ap.astype(x.dtype), Bp.astype(x.dtype), int(transient))


def placement_errors(u_exec, u_hlip, e, K):
    """Foot-placement errors δu_k = u_k − (u_HLIP,k + K e_k) [m] per plane: how far the executed
    step (robot foot to foot at SSP⁻_k) lies from the step the stepping law asks for at the
    same pre-impact error e_k.  0 on the H-LIP plant without step noise.

    Args:
      u_exec, u_hlip: (..., n_steps, 2) executed and H-LIP step sizes [m].
      e: (..., n_steps, 2, 3) errors x_robot − x_HLIP per plane [c, p, v].
      K: stepping gain (n,) or per plane (2, n); n = 2 acts on [p, v].
    Returns (..., n_steps, 2)."""
    e = as_float64(e)
    K = as_float64(K)
    n = K.shape[-1]
    Kp = np.broadcast_to(K, (2, n))
    return as_float64(u_exec) - as_float64(u_hlip) - np.einsum("pj,...pj->...p", Kp, _states(e, n))


#: the two planes of the per-plane error analysis, named per frame: the path's heading frame
#: (plane 0 sagittal along the heading θ, plane 1 lateral to its left; :func:`heading_frame`)
#: or the world's axes (plane 0 world x, plane 1 world y).  coverage.csv's ``plane`` column and
#: the tube's W frame (:mod:`hlip_jax.core.robust`) use these names.
PLANES = {"heading": ("sagittal", "lateral"), "world": ("world x", "world y")}


def to_heading(v, heading):
    """Per-plane vectors v (..., 2, n) [world x, y] → (sagittal, lateral) of the frame turned by
    ``heading`` θ (...) [rad]: v'_0 = cos θ v_x + sin θ v_y, v'_1 = −sin θ v_x + cos θ v_y."""
    return steplog.to_heading_frame(as_float64(v), as_float64(heading))


def closed_loop(A, B, K, anchor=None):
    """The error system e_{k+1} = A_cl e_k + w_k + β B δu_k of a loop whose nominal restarts
    the coordinates ``anchor`` from the robot's state before every plan (the log's ``anchor``;
    δu the foot-placement error, :func:`placement_errors`).

    With M = diag(anchor) on the state the analysis uses ([c, p, v] or [p, v]), the nominal
    steps from x̃_H = x_H + M e with u_H, and the robot with u_R = u_H + K e + δu, so
    e⁺ = (A (I − M) + B K) e + w + B δu (tube: M = 0, A_cl = A + B K).  When the whole state
    is anchored ("measured") the nominal also takes the robot's executed step u_R: e⁺ = w,
    A_cl = 0, β = 0.

    Args:
      A (n, n) or per plane (2, n, n), B (n,) or (2, n): S2S matrices; K (n,) or (2, n).
      anchor: (n,) 0/1, or None for the tube.
    Returns (A_cl (2, n, n), β)."""
    Ap, Bp = _plane_mats(A, B)
    Ap, Bp = np.asarray(Ap, np.float64), np.asarray(Bp, np.float64)
    n = Ap.shape[-1]
    Kp = np.broadcast_to(as_float64(K), (2, n))
    m = np.zeros(n) if anchor is None else as_float64(anchor).reshape(n)
    if np.all(m == 1.0):
        return np.zeros((2, n, n)), 0.0
    return Ap * (1.0 - m)[None, None, :] + Bp[:, :, None] * Kp[:, None, :], 1.0


def heading_frame(e, d, heading, A_cl):
    """Errors and error-system disturbances of a log, rotated from the world planes (x, y) into
    the path's heading frame (sagittal along θ_k, lateral to its left).

    Per state component j (c, p, v alike: each is a horizontal vector split over the planes),
    e'_k = R(θ_k) e_k with R(θ) = [[cos θ, sin θ], [−sin θ, cos θ]] acting on the plane axis.
    When the closed loop is the same in both planes, A_cl commutes with R and the world
    recursion e_{k+1} = A_cl e_k + d_k becomes

        e'_{k+1} = A_cl e'_k + d'_k,   d'_k = R(θ_{k+1}) d_k + A_cl (R(θ_{k+1}) − R(θ_k)) e_k:

    the disturbance as the walking robot sees it plus the term the turning frame adds (zero on
    a straight path).  d' = e'_{k+1} − A_cl e'_k exactly, so the mRPI analysis of (A_cl, W') in
    the heading frame is the same theory as in the world frame; what changes is which
    disturbances are pooled: a bias along the walking direction (an over-step, a lag) keeps
    its sign when the path turns round, instead of flipping between +x and −x.

    Args:
      e: (..., n_steps, 2, n) world-frame errors [m, m/s].
      d: (..., n_steps − 1, 2, n) world-frame disturbances with e_{k+1} = A_cl e_k + d_k.
      heading: (..., n_steps) path heading θ_k [rad] at each pre-impact instant.
      A_cl: (n, n), or (2, n, n) with both planes equal (a different gain per plane does not
        commute with the rotation; ValueError).
    Returns (e', d') with the shapes of e and d; plane 0 sagittal, 1 lateral."""
    e = as_float64(e)
    d = as_float64(d)
    th = as_float64(heading)
    Acl = as_float64(A_cl)
    if Acl.ndim == 3:
        if Acl.shape[0] != 2 or not np.allclose(Acl[0], Acl[1], rtol=1e-12, atol=1e-12):
            raise ValueError("A_cl: the heading frame needs the same closed loop in both planes "
                             "(gain.lateral = 'same'); got different per-plane A + BK")
        Acl = Acl[0]
    n = Acl.shape[-1]
    if e.ndim < 3 or e.shape[-2:] != (2, n):
        raise ValueError(f"e: shape (..., n_steps, 2, {n}) expected, got {e.shape}")
    if d.shape != e.shape[:-3] + (e.shape[-3] - 1, 2, n):
        raise ValueError(f"d: shape {e.shape[:-3] + (e.shape[-3] - 1, 2, n)} expected, got {d.shape}")
    if th.shape != e.shape[:-2]:
        raise ValueError(f"heading: shape {e.shape[:-2]} expected (..., n_steps), got {th.shape}")
    e_rot = to_heading(e, th)
    # A_cl (R(θ_{k+1}) − R(θ_k)) e_k: the frame's turn between the two pre-impact instants
    turn = (to_heading(e[..., :-1, :, :], th[..., 1:]) - e_rot[..., :-1, :, :]) @ Acl.T
    return e_rot, to_heading(d, th[..., 1:]) + turn


def estimate_w(samples, mask=None, method: str = "box", quantile: float = 0.99):
    """Disturbance set W from samples (N, n) of one plane (rows with ``mask`` False dropped).

    method: "box" (per-axis min/max), "quantile" (per-axis [Q(1−q), Q(q)], q = ``quantile``
    in (0.5, 1]; q = 1 is the min/max box), or "hull" (convex hull, scipy Qhull).
    """
    P = as_float64(samples).reshape(-1, np.shape(samples)[-1])
    if mask is not None:
        P = P[np.asarray(mask, bool).reshape(-1)]
    if P.shape[0] == 0:
        raise ValueError("estimate_w: no valid samples (mask selects none)")
    if method == "box":
        return Box(P.min(axis=0), P.max(axis=0))
    if method == "quantile":
        if not 0.5 < quantile <= 1.0:
            raise ValueError(f"quantile: must be in (0.5, 1], got {quantile}")
        lo = np.quantile(P, 1.0 - quantile, axis=0)
        hi = np.quantile(P, quantile, axis=0)
        return Box(jnp.asarray(lo), jnp.asarray(hi))
    if method == "hull":
        return convex_hull(P)
    raise ValueError(f"method: one of 'box', 'quantile', 'hull' expected, got {method!r}")


# ---------------------------------------------------------------------------------------------
# coverage and whole-log analysis
# ---------------------------------------------------------------------------------------------

class Coverage(NamedTuple):
    """Fraction of samples inside the inner set (F_s) and inside the outer set (F_s/(1−α));
    the true mRPI coverage lies in [inner, outer].  n: number of samples counted."""
    inner: float
    outer: float
    n: int


def coverage(E, e_samples, mask=None, tol: float | None = None) -> Coverage:
    """Coverage bracket of error samples e (..., n) (rows with ``mask`` False ignored).

    ``tol`` (relative to the set's size) defaults to 1e-9, raised to 50 machine epsilons of
    the samples' dtype: errors logged in float32 carry ~1e-7 relative rounding, and a sample
    that lies on E's boundary by construction (W estimated from the same data) must count
    as inside."""
    e = np.asarray(e_samples)
    if tol is None:
        eps = np.finfo(e.dtype).eps if np.issubdtype(e.dtype, np.floating) else 0.0
        tol = max(1e-9, 50.0 * float(eps))
    m = np.ones(e.shape[:-1], bool) if mask is None else np.asarray(mask, bool)
    if m.shape != e.shape[:-1]:
        raise ValueError(f"mask: shape {e.shape[:-1]} expected, got {m.shape}")
    cnt = int(m.sum())
    if cnt == 0:
        return Coverage(float("nan"), float("nan"), 0)
    inner_set = E.inner if isinstance(E, MRPI) else E
    outer_set = E.outer if isinstance(E, MRPI) else E
    pts = e[m]  # only the counted samples are tested
    fi = float(np.sum(np.asarray(inner_set.contains(pts, tol)))) / cnt
    fo = fi if outer_set is inner_set else float(np.sum(np.asarray(outer_set.contains(pts, tol)))) / cnt
    return Coverage(fi, fo, cnt)


class PlaneAnalysis(NamedTuple):
    """Per-plane result of :func:`analyse`.  W, E from all scenarios; coverage in-sample;
    W_train, E_train from the training split and heldout = coverage on the held-out split."""
    W: Any
    E: MRPI
    s: int
    alpha: float
    volume: float
    coverage: Coverage
    W_train: Any
    E_train: Optional[MRPI]
    heldout: Optional[Coverage]
    n_w: int


class Analysis(NamedTuple):
    """``planes`` = (sagittal, lateral) :class:`PlaneAnalysis`; ``combined`` = joint coverage
    (a step counts when both planes' errors are inside), in-sample and held-out;
    ``train``/``test``: scenario indices of the split (leading axis)."""
    planes: tuple
    combined: Coverage
    combined_heldout: Optional[Coverage]
    train: np.ndarray
    test: np.ndarray


def _joint(E_pair, e, mask, tol):
    """Joint coverage bracket of both planes; e (..., 2, n), mask (...)."""
    m = np.asarray(mask, bool)
    cnt = int(m.sum())
    if cnt == 0:
        return Coverage(float("nan"), float("nan"), 0)
    pts = e[m]  # (cnt, 2, n)
    ins_i = np.ones(cnt, bool)
    ins_o = np.ones(cnt, bool)
    for p, E in enumerate(E_pair):
        ins_i &= np.asarray(E.inner.contains(pts[:, p, :], tol))
        ins_o &= np.asarray(E.outer.contains(pts[:, p, :], tol))
    return Coverage(float(ins_i.sum()) / cnt, float(ins_o.sum()) / cnt, cnt)


def _checked_log(x_robot, e, holdout_fraction):
    """(x_robot, e) as float64 after :func:`analyse`'s shape and range checks (ValueError
    naming the argument)."""
    x = as_float64(x_robot)
    if x.ndim < 4:
        raise ValueError(f"x_robot: shape (n_scenarios, ..., n_steps, 2, 3) expected, got {x.shape}")
    e = as_float64(e)
    if e.shape != x.shape:
        raise ValueError(f"e: shape {x.shape} (same as x_robot) expected, got {e.shape}")
    if not 0.0 <= holdout_fraction < 1.0:
        raise ValueError(f"holdout_fraction: must be in [0, 1), got {holdout_fraction}")
    return x, e


def analyse(x_robot, u_exec, valid, e, A, B, K, W_estimator: str = "box",
            quantile: float = 0.99, transient: int = 0, holdout_fraction: float = 0.0,
            seed: int = 0, eps: float = 1e-5, directions=None, tol: float = 1e-9,
            min_halfwidth=None, u_hlip=None, heading=None, anchor=None) -> Analysis:
    """Per-plane W / E / coverage of a whole log.

    Args:
      x_robot (..., n_steps, 2, 3), u_exec (..., n_steps, 2), valid (..., n_steps): the log
        (see :func:`disturbances`); e (..., n_steps, 2, 3): errors x_robot − x_HLIP, counted
        with the same mask as the states (:func:`step_mask`).
      A, B: S2S matrices, shared or per plane; their size selects [c, p, v] or [p, v].
      K: stepping gain (n,) or per plane (2, n); A_cl = A + B K in the tube.
      anchor: (n,) coordinates the nominal restarts from the robot's before every plan (the
        log's ``anchor`` on the analysed state), or None (the tube): :func:`closed_loop`.
      u_hlip: (..., n_steps, 2) H-LIP steps, or None.  Given, W bounds the error system's
        disturbance d = w + B δu (:func:`placement_errors`), which the errors obey exactly
        (e⁺ = A_cl e + d); None bounds the robot's S2S disturbance w alone.
      W_estimator, quantile: see :func:`estimate_w`.
      holdout_fraction: in [0, 1); the leading axis (scenarios) is split with
        ``numpy.random.default_rng(seed)``: W is re-estimated on the training scenarios and
        coverage measured on the held-out ones.  0 skips the held-out part.
      eps, directions, min_halfwidth: passed to :func:`mrpi`.
      heading: (..., n_steps) path heading θ_k [rad], or None.  Given, the planes are the
        heading frame's sagittal and lateral ones (:func:`heading_frame`; needs the same gain
        in both planes); None keeps the world's x and y.
    """
    x, e = _checked_log(x_robot, e, holdout_fraction)
    Ap, Bp = _plane_mats(A, B)
    Ap, Bp = np.asarray(Ap, np.float64), np.asarray(Bp, np.float64)
    n = Ap.shape[-1]
    K64 = as_float64(K)
    Kp = np.broadcast_to(K64, (2, n)) if K64.shape in ((n,), (2, n)) else None
    if Kp is None:
        raise ValueError(f"K: shape ({n},) or (2, {n}) expected, got {np.shape(K)}")
    Acl, beta = closed_loop(Ap, Bp, Kp, anchor)

    d = disturbances(x, u_exec, valid, Ap, Bp, transient)
    w, wmask = np.asarray(d.w, np.float64), np.asarray(d.mask)
    if u_hlip is not None:
        du = placement_errors(u_exec, u_hlip, e, Kp)                  # (..., n_steps, 2)
        w = w + beta * Bp * du[..., :-1, :, None]
    es = _states(e, n)
    if heading is not None:
        es, w = heading_frame(es, w, heading, Acl)
    alive = np.cumprod(np.asarray(valid, bool), axis=-1).astype(bool)
    emask = alive & (np.arange(alive.shape[-1]) >= transient)  # = step_mask, in numpy

    n_scen = x.shape[0]
    n_test = int(round(holdout_fraction * n_scen))
    if holdout_fraction > 0:
        n_test = min(max(n_test, 1), n_scen - 1)
        if n_test < 1:
            raise ValueError(f"holdout_fraction: needs ≥ 2 scenarios on the leading axis, got {n_scen}")
    perm = np.random.default_rng(seed).permutation(n_scen)
    test = np.sort(perm[:n_test])
    train = np.sort(perm[n_test:])

    planes, Es, Es_tr = [], [], []
    for p in range(2):
        W = estimate_w(w[..., p, :], wmask, W_estimator, quantile)
        E = mrpi(Acl[p], W, eps=eps, directions=directions, min_halfwidth=min_halfwidth)
        cov = coverage(E, es[..., p, :], emask, tol)
        W_tr = E_tr = held = None
        if n_test:
            W_tr = estimate_w(w[train][..., p, :], wmask[train], W_estimator, quantile)
            E_tr = mrpi(Acl[p], W_tr, eps=eps, directions=directions,
                        min_halfwidth=min_halfwidth)
            held = coverage(E_tr, es[test][..., p, :], emask[test], tol)
        Es.append(E)
        Es_tr.append(E_tr)
        planes.append(PlaneAnalysis(W, E, E.s, E.alpha, float(E.volume()), cov, W_tr, E_tr,
                                    held, int(wmask.sum())))
    comb = _joint(Es, es, emask, tol)
    comb_h = _joint(Es_tr, es[test], emask[test], tol) if n_test else None
    return Analysis(tuple(planes), comb, comb_h, train, test)
