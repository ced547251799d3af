"""Batched dense ADMM solver for small convex quadratic programs (OSQP's algorithm in JAX).

Solves, for each problem of a batch,

    minimise ½ xᵀ P x + qᵀ x   subject to   l ≤ A x ≤ u,

with P (n×n) symmetric positive semidefinite, A (m×n), l, u ∈ (ℝ ∪ {±∞})ᵐ.  Bounds with
|l_i|, |u_i| ≥ 1e20 are treated as infinite.  Units are those of the caller's problem.

The algorithm is OSQP's (Stellato, Banjac, Goulart, Bemporad, Boyd, "OSQP: an operator
splitting solver for quadratic programs", Math. Prog. Comp. 2020), on dense matrices:

1. *Ruiz equilibration* (``Settings.scaling`` passes) of the KKT matrix [[P, Aᵀ], [A, 0]] with
   diagonal D (n) and E (m), each pass followed by *cost scaling* c; the solver works on
   P̄ = c D P D, q̄ = c D q, Ā = E A D, l̄ = E l, ū = E u and unscales the result:
   x = D x̄, y = E ȳ / c, z = E⁻¹ z̄.
2. *Per-row step sizes* ρ_i: ρ for inequality rows, 1e3·ρ for equality rows (u_i − l_i < 1e-4 after
   scaling), 1e-6 for free rows (both bounds infinite).
3. *ADMM iteration* with over-relaxation α:  solve (P̄ + σI + Āᵀ diag(ρ) Ā) x̃ = σx − q̄ + Āᵀ(ρ∘z − y),
   z̃ = Ā x̃;  x ← αx̃ + (1−α)x;  z ← Π_[l̄,ū](αz̃ + (1−α)z + y/ρ);  y ← y + ρ∘(αz̃ + (1−α)z_prev − z).
   The linear system is factored by dense Cholesky and refactored when ρ adapts.
4. *Termination* every ``check_interval`` iterations on the unscaled residuals
   r_prim = ‖Ax − z‖∞ ≤ ε_abs + ε_rel max(‖Ax‖∞, ‖z‖∞),
   r_dual = ‖Px + q + Aᵀy‖∞ ≤ ε_abs + ε_rel max(‖Px‖∞, ‖Aᵀy‖∞, ‖q‖∞).
5. *Infeasibility certificates* from the last iterate differences δy (primal) and δx (dual).
6. *Adaptive ρ*: ρ ← ρ √((r_prim/‖·‖) / (r_dual/‖·‖)) in scaled quantities, applied when it changes
   by more than ``adaptive_rho_tolerance``, checked every ``adaptive_rho_interval`` iterations.

The iteration runs over blocks of ``check_interval`` iterations (``lax.fori_loop`` inside); a
finished problem is frozen (``jnp.where``) and keeps its own iteration count and status.  With
``Settings.early_exit`` the blocks run in a ``lax.while_loop``, so a vmapped batch stops as soon
as every problem is done; without it they run in a loop of static trip count
⌈max_iter / check_interval⌉ (no data-dependent exit).  A problem's iterates are the same either
way: the extra blocks only touch problems that are already frozen.  In the Cassie tick on an H100
the while loop is the faster one (the blocks it saves cost more than its predicate's trips to the
host; docs/benchmarks/cassie_gpu.md).  A batch solved in one piece on an accelerator runs with *straggler
compaction* (:func:`_compacted`): the problems still unfinished when half the batch
(1/``Settings.compaction_shrink``) is left continue in a batch of that size, and so on, so the
work follows the distribution of iteration counts instead of the slowest problem.  Status
codes are OSQP 1.x's.  dtype follows the inputs (float32 or float64); products run at highest precision.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple, Optional, Tuple

import jax
import jax.numpy as jnp
from jax import lax
from jax.scipy.linalg import cho_factor, cho_solve

from hlip_jax.core import qp_fused

# --- OSQP 1.x status codes -------------------------------------------------------------------
SOLVED = 1
SOLVED_INACCURATE = 2
PRIMAL_INFEASIBLE = 3
PRIMAL_INFEASIBLE_INACCURATE = 4
DUAL_INFEASIBLE = 5
DUAL_INFEASIBLE_INACCURATE = 6
MAX_ITER = 7
NON_CVX = 9
UNSOLVED = 11  # invalid (non-finite) data, or the iteration produced non-finite numbers

STATUS_NAMES = {
    SOLVED: "solved",
    SOLVED_INACCURATE: "solved inaccurate",
    PRIMAL_INFEASIBLE: "primal infeasible",
    PRIMAL_INFEASIBLE_INACCURATE: "primal infeasible inaccurate",
    DUAL_INFEASIBLE: "dual infeasible",
    DUAL_INFEASIBLE_INACCURATE: "dual infeasible inaccurate",
    MAX_ITER: "maximum iterations reached",
    NON_CVX: "non convex",
    UNSOLVED: "unsolved (invalid data)",
}

# --- OSQP constants -----------------------------------------------------------------------------
INF_BOUND = 1e20  # |bound| ≥ this is treated as infinite
_RHO_MIN = 1e-6  # ρ of free rows and lower clip of adaptive ρ
_RHO_MAX = 1e6  # upper clip of adaptive ρ
_RHO_EQ_OVER_RHO_INEQ = 1e3  # ρ factor on equality rows
_RHO_TOL = 1e-4  # rows with ū − l̄ below this are equality rows
_MIN_SCALING = 1e-4  # Ruiz norms below this are left unscaled
_MAX_SCALING = 1e4  # Ruiz norms are clipped to this
_DIV_TOL = 1e-30  # guard in the adaptive-ρ ratios
_INACCURATE_FACTOR = 10.0  # tolerance multiplier for the "inaccurate" statuses at max_iter
_UNROLL = 1  # ADMM iterations unrolled per inner-loop trip (fewer loop overheads)


class Settings(NamedTuple):
    """Static solver settings (hashable; a change recompiles).

    eps_abs, eps_rel: absolute / relative tolerance of the residual test (≥ 0, not both 0).
    eps_prim_inf, eps_dual_inf: tolerances of the infeasibility certificates (> 0).
    max_iter: ADMM iteration budget (≥ 1), honoured exactly.
    rho: initial ADMM step size (> 0).  sigma: x-regularisation σ (> 0).
    alpha: over-relaxation, in (0, 2).
    scaling: number of Ruiz equilibration passes (≥ 0; 0 = no scaling).
    adaptive_rho: adapt ρ with OSQP's rule.
    adaptive_rho_interval: iterations between ρ updates; a positive multiple of check_interval.
    adaptive_rho_tolerance: ρ changes only if the new value differs by more than this factor (≥ 1).
    check_interval: iterations per block; residuals / certificates are checked after each block.
    linsys: "cholesky" (cho_solve each iteration) or "inverse" (K⁻¹ formed once per factorisation
      from the Cholesky factor, then matrix–vector products; faster for batches, slightly less
      accurate for badly conditioned K).
    early_exit: stop the block loop when every problem is done (a while loop); False: always
      run ⌈max_iter / check_interval⌉ blocks (a loop of static trip count; same results).
    compaction_shrink: with straggler compaction (``solve(compact=True)``), each tier holds
      1/``compaction_shrink`` of the one before (:func:`compaction_tiers`; an integer ≥ 2).
    block_kernel: "xla" (each ADMM iteration as XLA operations) or "fused" (each block of
      ``check_interval`` iterations as one Pallas kernel, :mod:`hlip_jax.core.qp_fused`; needs
      ``linsys = "inverse"``; compiled on GPUs, interpreted elsewhere).
    """

    eps_abs: float = 1e-3
    eps_rel: float = 1e-3
    eps_prim_inf: float = 1e-4
    eps_dual_inf: float = 1e-4
    max_iter: int = 4000
    rho: float = 0.1
    sigma: float = 1e-6
    alpha: float = 1.6
    scaling: int = 10
    adaptive_rho: bool = True
    adaptive_rho_interval: int = 50
    adaptive_rho_tolerance: float = 5.0
    check_interval: int = 25
    linsys: str = "cholesky"
    early_exit: bool = True
    compaction_shrink: int = 2
    block_kernel: str = "xla"


class Solution(NamedTuple):
    """Solver output (unscaled); leading batch axes as the inputs.

    x (…, n): primal solution.  y (…, m): constraint multipliers (y_i > 0 at an active upper
    bound, < 0 at an active lower bound).  z (…, m): A x projected onto [l, u].
    status (…,) int32: OSQP status code.  iterations (…,) int32: ADMM iterations run.
    prim_res, dual_res (…,): ∞-norm residuals ‖Ax − z‖ and ‖Px + q + Aᵀy‖ at the last check.
    rho (…,): the step size ρ at the end (hand it to the next solve of a receding-horizon
    problem as ``rho_start``, as OSQP's workspace keeps it between solves).
    For infeasible problems x, y, z are the last iterates (not a solution).
    """

    x: jax.Array
    y: jax.Array
    z: jax.Array
    status: jax.Array
    iterations: jax.Array
    prim_res: jax.Array
    dual_res: jax.Array
    rho: jax.Array


def validate_settings(s: Settings) -> None:
    """Raise ``ValueError`` naming the offending field and its allowed range."""
    if not isinstance(s, Settings):
        raise TypeError(f"settings must be hlip_jax.core.qp.Settings, got {type(s).__name__}")

    def bad(field, rng):
        raise ValueError(f"Settings.{field} = {getattr(s, field)!r} is outside the allowed range {rng}")

    for f in ("eps_abs", "eps_rel"):
        if not (getattr(s, f) >= 0 and math.isfinite(getattr(s, f))):
            bad(f, "[0, inf)")
    if s.eps_abs == 0 and s.eps_rel == 0:
        raise ValueError("Settings.eps_abs and Settings.eps_rel are both 0; at least one must be > 0")
    for f in ("eps_prim_inf", "eps_dual_inf", "rho", "sigma"):
        if not (getattr(s, f) > 0 and math.isfinite(getattr(s, f))):
            bad(f, "(0, inf)")
    if not (0 < s.alpha < 2):
        bad("alpha", "(0, 2)")
    for f in ("max_iter", "check_interval"):
        v = getattr(s, f)
        if not (isinstance(v, int) and v >= 1):
            bad(f, "integers >= 1")
    if not (isinstance(s.scaling, int) and s.scaling >= 0):
        bad("scaling", "integers >= 0")
    v = s.adaptive_rho_interval
    if not (isinstance(v, int) and v >= 1 and v % s.check_interval == 0):
        bad("adaptive_rho_interval", f"positive multiples of check_interval ({s.check_interval})")
    if not (s.adaptive_rho_tolerance >= 1):
        bad("adaptive_rho_tolerance", "[1, inf)")
    if s.linsys not in ("cholesky", "inverse"):
        bad("linsys", "{'cholesky', 'inverse'}")
    if not isinstance(s.early_exit, bool):
        bad("early_exit", "{True, False}")
    if not (isinstance(s.compaction_shrink, int) and s.compaction_shrink >= 2):
        bad("compaction_shrink", "integers >= 2")
    if s.block_kernel not in ("xla", "fused"):
        bad("block_kernel", '"xla" or "fused"')
    if s.block_kernel == "fused" and s.linsys != "inverse":
        bad("block_kernel", '"xla" with linsys "cholesky" ("fused" needs linsys "inverse")')


# --- helpers -----------------------------------------------------------------------------------
_HI = lax.Precision.HIGHEST


def _mv(M, v):
    return jnp.matmul(M, v, precision=_HI)


def _mtv(M, v):
    return jnp.matmul(v, M, precision=_HI)


def _ninf(v):
    return jnp.max(jnp.abs(v), initial=0.0)


def _limit_scaling(v):
    """OSQP's limit_scaling: tiny norms → 1 (leave unscaled), huge norms → clipped."""
    return jnp.where(v < _MIN_SCALING, 1.0, jnp.minimum(v, _MAX_SCALING))


class _Scaled(NamedTuple):
    P: jax.Array
    q: jax.Array
    A: jax.Array
    l: jax.Array  # ±inf for infinite bounds
    u: jax.Array
    l_inf: jax.Array  # bool masks of infinite bounds
    u_inf: jax.Array
    D: jax.Array
    E: jax.Array
    c: jax.Array


def _ruiz(P, q, A, passes: int):
    """Ruiz equilibration with cost scaling (OSQP's scale_data).  Returns P̄, q̄, Ā, D, E, c."""
    n, m = P.shape[0], A.shape[0]
    D = jnp.ones((n,), P.dtype)
    E = jnp.ones((m,), P.dtype)
    c = jnp.ones((), P.dtype)

    def one_pass(_, carry):
        P, q, A, D, E, c = carry
        # Ruiz step: ∞-norms of the KKT columns [P; A] (first n) and of the rows of A (last m).
        dn = jnp.maximum(jnp.max(jnp.abs(P), axis=0), jnp.max(jnp.abs(A), axis=0))
        en = jnp.max(jnp.abs(A), axis=1)
        dt = 1.0 / jnp.sqrt(_limit_scaling(dn))
        et = 1.0 / jnp.sqrt(_limit_scaling(en))
        P = dt[:, None] * P * dt[None, :]
        A = et[:, None] * A * dt[None, :]
        q = dt * q
        D = D * dt
        E = E * et
        # Cost scaling: c ← c / max(mean column ∞-norm of P̄, ‖q̄‖∞).
        mean_p = jnp.mean(jnp.max(jnp.abs(P), axis=0))
        ct = jnp.maximum(mean_p, _limit_scaling(_ninf(q)))
        ct = 1.0 / _limit_scaling(ct)
        return ct * P, ct * q, A, D, E, c * ct

    P, q, A, D, E, c = lax.fori_loop(0, passes, one_pass, (P, q, A, D, E, c))
    return P, q, A, D, E, c


def _rho_vec(rho, d: _Scaled):
    """Per-row ρ: free rows 1e-6, equality rows 1e3·ρ, others ρ."""
    free = d.l_inf & d.u_inf
    eq = (~d.l_inf) & (~d.u_inf) & ((d.u - d.l) < _RHO_TOL)
    return jnp.where(free, _RHO_MIN, jnp.where(eq, _RHO_EQ_OVER_RHO_INEQ * rho, rho)).astype(d.q.dtype)


def _factor(d: _Scaled, sigma, rho_vec, linsys: str):
    """Factor the reduced KKT matrix K = P̄ + σI + Āᵀ diag(ρ) Ā (dense Cholesky)."""
    n = d.P.shape[0]
    K = d.P + sigma * jnp.eye(n, dtype=d.P.dtype) + jnp.matmul(d.A.T * rho_vec, d.A, precision=_HI)
    L, _ = cho_factor(K, lower=True)
    if linsys == "inverse":
        return cho_solve((L, True), jnp.eye(n, dtype=d.P.dtype))
    return L


def _linsolve(F, rhs, linsys: str):
    if linsys == "inverse":
        return _mv(F, rhs)
    return cho_solve((F, True), rhs)


class _State(NamedTuple):
    x: jax.Array
    z: jax.Array
    y: jax.Array
    dx: jax.Array  # x_k − x_{k−1} (dual infeasibility certificate)
    dy: jax.Array  # y_k − y_{k−1} (primal infeasibility certificate)
    rho: jax.Array  # scalar ρ
    F: jax.Array  # Cholesky factor L or K⁻¹
    it: jax.Array
    status: jax.Array
    done: jax.Array
    prim_res: jax.Array
    dual_res: jax.Array


def _admm_step(d: _Scaled, s: Settings, rho_vec, F, x, z, y):
    """One OSQP ADMM iteration in scaled variables."""
    sigma, alpha = s.sigma, s.alpha
    # Step 1 (linear system): (P̄ + σI + ĀᵀρĀ) x̃ = σx − q̄ + Āᵀ(ρz − y);  z̃ = Āx̃.
    rhs = sigma * x - d.q + _mtv(d.A, rho_vec * z - y)
    xt = _linsolve(F, rhs, s.linsys)
    zt = _mv(d.A, xt)
    # Step 2 (over-relaxation + x update).
    x_new = alpha * xt + (1.0 - alpha) * x
    zr = alpha * zt + (1.0 - alpha) * z
    # Step 3 (projection onto [l̄, ū]) and Step 4 (dual update).
    z_new = jnp.clip(zr + y / rho_vec, d.l, d.u)
    y_new = y + rho_vec * (zr - z_new)
    return x_new, z_new, y_new


def _residuals(d: _Scaled, x, z, y):
    """Unscaled residuals and the norms of the relative tests, plus the scaled vectors."""
    Ax = _mv(d.A, x)
    Px = _mv(d.P, x)
    Aty = _mtv(d.A, y)
    Einv = 1.0 / d.E
    Dinv = 1.0 / d.D
    cinv = 1.0 / d.c
    prim = _ninf(Einv * (Ax - z))
    prim_norm = jnp.maximum(_ninf(Einv * Ax), _ninf(Einv * z))
    dual = cinv * _ninf(Dinv * (Px + d.q + Aty))
    dual_norm = cinv * jnp.maximum(jnp.maximum(_ninf(Dinv * Px), _ninf(Dinv * Aty)), _ninf(Dinv * d.q))
    return prim, prim_norm, dual, dual_norm, (Ax, Px, Aty)


def _primal_infeasibility(d: _Scaled, dy):
    """Quantities of OSQP's primal infeasibility certificate on δy (projected onto the polar
    recession cone of [l, u]); the test at tolerance ε is
    ‖E δy‖ > ε,  uᵀ(δy)₊ + lᵀ(δy)₋ < −ε‖E δy‖,  ‖Aᵀδy‖ < ε‖E δy‖  (unscaled, δy ↦ E δy)."""
    dy = jnp.where(d.u_inf, jnp.minimum(dy, 0.0), dy)
    dy = jnp.where(d.l_inf, jnp.maximum(dy, 0.0), dy)
    norm_dy = _ninf(d.E * dy)
    ub = jnp.sum(jnp.where(d.u_inf, 0.0, d.u * jnp.maximum(dy, 0.0)))
    lb = jnp.sum(jnp.where(d.l_inf, 0.0, d.l * jnp.minimum(dy, 0.0)))
    aty = _ninf(_mtv(d.A, dy) / d.D)
    return norm_dy, ub + lb, aty


def _primal_infeasible(q, eps):
    norm_dy, bound, aty = q
    return (norm_dy > eps) & (bound < -eps * norm_dy) & (aty < eps * norm_dy)


def _dual_infeasibility(d: _Scaled, dx):
    """Quantities of OSQP's dual infeasibility certificate on δx; the test at tolerance ε is
    ‖Dδx‖ > ε, qᵀδx < −ε‖Dδx‖, ‖Pδx‖ < ε‖Dδx‖, (Aδx)_i ≤ ε‖Dδx‖ where u_i is finite and
    (Aδx)_i ≥ −ε‖Dδx‖ where l_i is finite (unscaled, δx ↦ D δx)."""
    norm_dx = _ninf(d.D * dx)
    qdx = jnp.dot(d.q, dx, precision=_HI) / d.c
    pdx = _ninf(_mv(d.P, dx) / d.D) / d.c
    adx = _mv(d.A, dx) / d.E
    # largest violation of the recession-cone conditions on A δx
    a_viol = jnp.maximum(jnp.max(jnp.where(d.u_inf, -jnp.inf, adx), initial=-jnp.inf),
                         jnp.max(jnp.where(d.l_inf, -jnp.inf, -adx), initial=-jnp.inf))
    return norm_dx, qdx, pdx, a_viol


def _dual_infeasible(q, eps):
    norm_dx, qdx, pdx, a_viol = q
    tol = eps * norm_dx
    return (norm_dx > eps) & (qdx < -tol) & (pdx < tol) & (a_viol <= tol)


def _status(s: Settings, res, pinf_q, dinf_q, factor):
    """OSQP's termination order: solved, else primal infeasible, else dual infeasible (0 = none);
    ``factor`` loosens every tolerance (the "inaccurate" test at max_iter)."""
    prim, prim_norm, dual, dual_norm = res
    solved = ((prim <= factor * (s.eps_abs + s.eps_rel * prim_norm))
              & (dual <= factor * (s.eps_abs + s.eps_rel * dual_norm)))
    pinf = _primal_infeasible(pinf_q, factor * s.eps_prim_inf)
    dinf = _dual_infeasible(dinf_q, factor * s.eps_dual_inf)
    return solved, pinf, dinf


def _sanitise(P, q, A, l, u, x0, y0, warm: bool):
    """Invalid data (non-finite P, q, A, NaN bounds or l > u) replaced by a harmless problem, so
    that nothing non-finite enters the iteration (reported as UNSOLVED); a non-finite warm start
    ignored (cold start, not an error); |bound| ≥ 1e20 → ±inf.
    Returns (P, q, A, l, u, x0, y0, valid, l_inf, u_inf)."""
    n = P.shape[0]
    valid = (jnp.all(jnp.isfinite(P)) & jnp.all(jnp.isfinite(q)) & jnp.all(jnp.isfinite(A))
             & ~jnp.any(jnp.isnan(l)) & ~jnp.any(jnp.isnan(u)) & jnp.all(l <= u))
    if warm:
        warm_ok = jnp.all(jnp.isfinite(x0)) & jnp.all(jnp.isfinite(y0))
        x0 = jnp.where(warm_ok, x0, 0.0)
        y0 = jnp.where(warm_ok, y0, 0.0)
    P = jnp.where(valid, P, jnp.eye(n, dtype=q.dtype))
    q = jnp.where(valid, q, 0.0)
    A = jnp.where(valid, A, 0.0)
    l = jnp.where(valid, l, -jnp.inf)
    u = jnp.where(valid, u, jnp.inf)
    P = 0.5 * (P + P.T)
    l_inf = l <= -INF_BOUND
    u_inf = u >= INF_BOUND
    l = jnp.where(l_inf, -jnp.inf, l)
    u = jnp.where(u_inf, jnp.inf, u)
    return P, q, A, l, u, x0, y0, valid, l_inf, u_inf


def _initial_state(d: "_Scaled", s: Settings, x0, y0, rho0, valid, warm: bool) -> "_State":
    """ρ (``Settings.rho``, or ``rho0`` where it is a positive finite number), the first
    factorisation and the first iterate: cold (0) or warm (x̄ = D⁻¹x, ȳ = c E⁻¹ y, z̄ = Āx̄)."""
    dtype = d.q.dtype
    n, m = d.q.shape[0], d.A.shape[0]
    rho = jnp.asarray(s.rho, dtype)
    if rho0 is not None:
        usable = jnp.isfinite(rho0) & (rho0 > 0)
        rho = jnp.where(usable, jnp.clip(rho0, _RHO_MIN, _RHO_MAX), rho).astype(dtype)
    F = _factor(d, s.sigma, _rho_vec(rho, d), s.linsys)
    if warm:
        x = jnp.where(valid, x0 / d.D, 0.0)
        y = jnp.where(valid, d.c * y0 / d.E, 0.0)
        z = jnp.clip(_mv(d.A, x), d.l, d.u)
    else:
        x = jnp.zeros((n,), dtype)
        y = jnp.zeros((m,), dtype)
        z = jnp.zeros((m,), dtype)
    zero = jnp.zeros((), dtype)
    return _State(x, z, y, jnp.zeros_like(x), jnp.zeros_like(y), rho, F,
                  jnp.zeros((), jnp.int32), jnp.where(valid, 0, UNSOLVED).astype(jnp.int32),
                  ~valid, zero + jnp.inf, zero + jnp.inf)


def _iterate(d: "_Scaled", s: Settings, st: "_State"):
    """``check_interval`` ADMM steps of one problem (the last, partial block stops at max_iter
    exactly).  Returns (x, z, y, dx, dy, it)."""
    if s.block_kernel == "fused":
        one = lambda t: jax.tree.map(lambda a: a[None], t)
        return tuple(a[0] for a in _iterate_fused(one(d), s, one(st)))
    rho_vec = _rho_vec(st.rho, d)
    exact_blocks = s.max_iter % s.check_interval == 0

    def it_body(_, carry):
        x, z, y, dx, dy, it = carry
        xn, zn, yn = _admm_step(d, s, rho_vec, st.F, x, z, y)
        if exact_blocks:
            return xn, zn, yn, xn - x, yn - y, it + 1
        go = it < s.max_iter
        return (jnp.where(go, xn, x), jnp.where(go, zn, z), jnp.where(go, yn, y),
                jnp.where(go, xn - x, dx), jnp.where(go, yn - y, dy), it + go.astype(it.dtype))

    return lax.fori_loop(0, s.check_interval, it_body,
                         (st.x, st.z, st.y, st.dx, st.dy, st.it), unroll=_UNROLL)


def _iterate_fused(d: "_Scaled", s: Settings, st: "_State"):
    """:func:`_iterate` for a batch (leading axis) as one Pallas kernel (``linsys`` "inverse":
    ``st.F`` is K⁻¹).  Returns (x, z, y, dx, dy, it), batched."""
    prob = qp_fused.Problems(st.F, d.A, d.q, d.l, d.u, jax.vmap(_rho_vec)(st.rho, d))
    its = qp_fused.Iterates(st.x, st.z, st.y, st.dx, st.dy, st.it)
    return tuple(qp_fused.admm_block(prob, its, sigma=s.sigma, alpha=s.alpha,
                                     iterations=s.check_interval, max_iter=s.max_iter))


def _iterate_batch(d: "_Scaled", s: Settings, st: "_State"):
    """:func:`_iterate` for every problem of a batch (leading axis)."""
    if s.block_kernel == "fused":
        return _iterate_fused(d, s, st)
    return jax.vmap(lambda d, st: _iterate(d, s, st))(d, st)


def _block_status(d: "_Scaled", s: Settings, x, z, y, dx, dy, it):
    """Termination (unscaled OSQP criteria), then infeasibility certificates; at max_iter
    OSQP's "inaccurate" statuses at tolerances loosened ×10.
    Returns (status, prim, dual, (Ax, Px, Aᵀy))."""
    prim, prim_norm, dual, dual_norm, prods = _residuals(d, x, z, y)
    res = (prim, prim_norm, dual, dual_norm)
    pq, dq = _primal_infeasibility(d, dy), _dual_infeasibility(d, dx)
    solved, pinf, dinf = _status(s, res, pq, dq, 1.0)
    status = jnp.where(solved, SOLVED, jnp.where(pinf, PRIMAL_INFEASIBLE,
                       jnp.where(dinf, DUAL_INFEASIBLE, 0)))
    a_solved, a_pinf, a_dinf = _status(s, res, pq, dq, _INACCURATE_FACTOR)
    status_max = jnp.where(a_solved, SOLVED_INACCURATE, jnp.where(
        a_pinf, PRIMAL_INFEASIBLE_INACCURATE, jnp.where(a_dinf, DUAL_INFEASIBLE_INACCURATE, MAX_ITER)))
    status = jnp.where((status == 0) & (it >= s.max_iter), status_max, status)
    finite = jnp.isfinite(prim) & jnp.isfinite(dual)
    return jnp.where(finite, status, UNSOLVED).astype(jnp.int32), prim, dual, prods


def _new_rho(d: "_Scaled", s: Settings, st: "_State", z, prods, it, done):
    """OSQP's adaptive ρ on the scaled residual ratios, on the fixed interval.
    Returns (ρ, whether it changed: the factorisation is then out of date)."""
    if not s.adaptive_rho:
        return st.rho, jnp.zeros((), bool)
    Ax, Px, Aty = prods
    pr = _ninf(Ax - z) / (jnp.maximum(_ninf(Ax), _ninf(z)) + _DIV_TOL)
    du = _ninf(Px + d.q + Aty) / (
        jnp.maximum(jnp.maximum(_ninf(Px), _ninf(Aty)), _ninf(d.q)) + _DIV_TOL)
    rho_new = jnp.clip(st.rho * jnp.sqrt(pr / (du + _DIV_TOL)), _RHO_MIN, _RHO_MAX)
    change = ((rho_new > st.rho * s.adaptive_rho_tolerance)
              | (rho_new < st.rho / s.adaptive_rho_tolerance))
    change = change & (it % s.adaptive_rho_interval == 0) & ~done & jnp.isfinite(rho_new)
    return jnp.where(change, rho_new, st.rho), change


def _after_iterate(d: "_Scaled", s: Settings, st: "_State", iterates):
    """Check the block's iterates and adapt ρ.
    Returns (new state with the old factorisation, whether ρ changed)."""
    x, z, y, dx, dy, it = iterates
    status, prim, dual, prods = _block_status(d, s, x, z, y, dx, dy, it)
    done = status != 0
    rho, change = _new_rho(d, s, st, z, prods, it, done)
    return _State(x, z, y, dx, dy, rho, st.F, it, status, done, prim, dual), change


def _block_core(d: "_Scaled", s: Settings, st: "_State"):
    """One block of the outer loop before refactorisation: iterate, check, adapt ρ."""
    return _after_iterate(d, s, st, _iterate(d, s, st))


def _freeze(old: "_State", new: "_State") -> "_State":
    """A problem finished before the block keeps its state (matters under vmap, where the
    loop runs for the batch)."""
    return jax.tree.map(lambda a, b: jnp.where(old.done, a, b), old, new)


def _block(d: "_Scaled", s: Settings, st: "_State") -> "_State":
    """One block for one problem: :func:`_block_core`, refactorising only when ρ changed."""
    new, change = _block_core(d, s, st)
    F = lax.cond(change, lambda: _factor(d, s.sigma, _rho_vec(new.rho, d), s.linsys), lambda: st.F)
    return _freeze(st, new._replace(F=F))


def _block_batch(d: "_Scaled", s: Settings, st: "_State") -> "_State":
    """One block for a batch (leading axis): :func:`_block_core` per problem, and the
    factorisations of the problems whose ρ changed, computed only in blocks where some did
    (under vmap :func:`_block`'s condition would become a select that always factors)."""
    iterates = _iterate_batch(d, s, st)
    new, change = jax.vmap(lambda d, st, i: _after_iterate(d, s, st, i))(d, st, iterates)
    refactor = jax.vmap(lambda d, rho: _factor(d, s.sigma, _rho_vec(rho, d), s.linsys))
    fresh = lambda: jnp.where(change[:, None, None], refactor(d, new.rho), st.F)
    F = lax.cond(jnp.any(change), fresh, lambda: st.F)
    return jax.vmap(_freeze)(st, new._replace(F=F))


def n_blocks(s: Settings) -> int:
    """Blocks that bring every problem to a final status: ⌈max_iter / check_interval⌉ (the
    last, partial block stops at max_iter, where every status is final)."""
    return -(-s.max_iter // s.check_interval)


def _blocks(d: "_Scaled", s: Settings, st: "_State") -> "_State":
    """The outer loop: until every problem is done (``early_exit``), or :func:`n_blocks`
    blocks (static trip count; blocks after a problem is done leave it as it is)."""
    if s.early_exit:
        return lax.while_loop(lambda st: ~st.done, lambda st: _block(d, s, st), st)
    return lax.fori_loop(0, n_blocks(s), lambda _, st: _block(d, s, st), st)


def _setup_one(P, q, A, l, u, x0, y0, rho0, s: Settings, warm: bool):
    """One problem (no batch axes) up to its first iterate: sanitise, scale (Ruiz equilibration
    and cost scaling), factor.  ``rho0``: the starting ρ, or None for ``Settings.rho``.
    Returns (scaled data, state, valid)."""
    P, q, A, l, u, x0, y0, valid, l_inf, u_inf = _sanitise(P, q, A, l, u, x0, y0, warm)
    Ps, qs, As, D, E, c = _ruiz(P, q, A, s.scaling)
    d = _Scaled(Ps, qs, As, E * l, E * u, l_inf, u_inf, D, E, c)
    return d, _initial_state(d, s, x0, y0, rho0, valid, warm), valid


def _finish_one(d: _Scaled, st: _State, valid) -> Solution:
    """Unscale the last iterate: x = D x̄, y = E ȳ / c, z = E⁻¹ z̄ (NaN for invalid data)."""
    nan = jnp.asarray(jnp.nan, d.q.dtype)
    x = jnp.where(valid, d.D * st.x, nan)
    y = jnp.where(valid, d.E * st.y / d.c, nan)
    z = jnp.where(valid, st.z / d.E, nan)
    return Solution(x, y, z, st.status, st.it, st.prim_res, st.dual_res, st.rho)


def _solve_one(P, q, A, l, u, x0, y0, rho0, s: Settings, warm: bool):
    """Solve one problem (no batch axes); traced under jit / vmap: set up, blocks of ADMM steps
    until every status is final, unscale."""
    d, st, valid = _setup_one(P, q, A, l, u, x0, y0, rho0, s, warm)
    return _finish_one(d, _blocks(d, s, st), valid)


def compaction_tiers(batch: int, shrink: int = 2, smallest: int = 256) -> Tuple[int, ...]:
    """Batch sizes of the compacted loop: ``batch``, then ÷ ``shrink`` while at least
    ``smallest`` (a tier smaller than that costs about as much per block as the one above)."""
    tiers = [batch]
    while tiers[-1] // shrink >= smallest:
        tiers.append(tiers[-1] // shrink)
    return tuple(tiers)


def _blocks_until(d: _Scaled, s: Settings, st: _State, unfinished: int) -> _State:
    """Blocks over the whole (batched) state until at most ``unfinished`` problems are left."""
    return lax.while_loop(lambda st: jnp.sum(~st.done) > unfinished,
                          lambda st: _block_batch(d, s, st), st)


def _compacted(d: _Scaled, s: Settings, st: _State, tiers: Tuple[int, ...]) -> _State:
    """Straggler compaction.  The batch runs blocks until only ``tiers[1]`` problems are
    unfinished; those are gathered into a batch of that size (slots beyond the unfinished
    ones are marked done and dropped again), which continues the same way down the tiers; the
    last tier runs until every problem is done.  A problem's iterates do not depend on the
    batch it runs in, so the results are those of the plain loop; the work follows the
    distribution of iteration counts instead of the batch's slowest problem."""
    if len(tiers) == 1:
        return _blocks_until(d, s, st, 0)
    size, cap = tiers[0], tiers[1]
    st = _blocks_until(d, s, st, cap)
    idx = jnp.nonzero(~st.done, size=cap, fill_value=size)[0]
    take = jnp.minimum(idx, size - 1)
    sub_d = jax.tree.map(lambda a: a[take], d)
    sub = jax.tree.map(lambda a: a[take], st)
    sub = _compacted(sub_d, s, sub._replace(done=sub.done | (idx == size)), tiers[1:])
    return jax.tree.map(lambda a, b: a.at[idx].set(b, mode="drop"), st, sub)


def _solve_compacted(args, s: Settings, warm: bool):
    """A batch on an accelerator: per-problem setup and unscaling vmapped, the ADMM blocks in
    the tiers of :func:`_compacted`."""
    d, st, valid = jax.vmap(lambda *a: _setup_one(*a, s, warm))(*args)
    st = _compacted(d, s, st, compaction_tiers(args[1].shape[0], s.compaction_shrink))
    return jax.vmap(_finish_one)(d, st, valid)


def _solve_flat(P, q, A, l, u, x0, y0, rho0, settings: Settings, warm: bool, batched: bool,
                chunk: int, compact: bool):
    """``rho0``: starting ρ per problem, or None (no leaves: ``Settings.rho``)."""
    args = (P, q, A, l, u, x0, y0, rho0)
    with jax.default_matmul_precision("highest"):
        f = lambda *a: _solve_one(*a, settings, warm)
        if not batched:
            return f(*args)
        B = q.shape[0]
        if compact and settings.early_exit and chunk >= B:
            return _solve_compacted(args, settings, warm)
        if chunk >= B:
            return jax.vmap(f)(*args)
        # Chunks of the batch run one after another (lax.map), each as a vmapped while loop that
        # stops when its own slowest problem is done and whose data stays in cache.
        pad = -B % chunk
        if pad:  # pad with copies of the first problem (dropped again below)
            args = jax.tree.map(lambda a: jnp.concatenate(
                [a, jnp.broadcast_to(a[:1], (pad,) + a.shape[1:])]), args)
        args = jax.tree.map(lambda a: a.reshape((-1, chunk) + a.shape[1:]), args)
        out = lax.map(lambda a: jax.vmap(f)(*a), args)
        return jax.tree.map(lambda a: a.reshape((-1,) + a.shape[2:])[:B], out)


_solve_jit = jax.jit(_solve_flat,
                     static_argnames=("settings", "warm", "batched", "chunk", "compact"))


def default_chunk() -> int:
    """Batch chunk size: 32 on CPU (cache-sized, stops per chunk), whole batch on accelerators."""
    return 32 if jax.default_backend() == "cpu" else 1 << 62


@functools.lru_cache(maxsize=None)
def _compacted_under_vmap(settings: Settings, warm: bool, with_rho: bool):
    """One problem's solve whose batching rule solves a vmapped batch in one piece with
    straggler compaction (``jax.custom_batching.custom_vmap``): a caller that vmaps a
    per-problem function around :func:`solve` (the Cassie tick over its robots) gets the
    batch's tiers instead of a loop that runs until its slowest problem is done.  Its
    arguments are P, q, A, l, u, x0, y0 and, ``with_rho``, the starting ρ."""
    full = lambda args: tuple(args) + ((None,) if not with_rho else ())

    @jax.custom_batching.custom_vmap
    def one(*args):
        return _solve_jit(*full(args), settings=settings, warm=warm, batched=False, chunk=1,
                          compact=False)

    @one.def_vmap
    def batched(axis_size, in_batched, *args):
        args = [a if b else jnp.broadcast_to(a, (axis_size,) + a.shape)
                for a, b in zip(args, in_batched)]
        sol = _solve_jit(*full(args), settings=settings, warm=warm, batched=True,
                         chunk=axis_size, compact=True)
        return sol, jax.tree.map(lambda _: True, sol)

    return one


def default_compact() -> bool:
    """Straggler compaction (:func:`_compacted`) for a batch solved in one piece: on
    accelerators (a while loop's trips cost little next to a block over the whole batch);
    not on the CPU, where the batch runs in chunks."""
    return jax.default_backend() != "cpu"


def _checked_arrays(P, q, A, l, u, warm_start):
    """The problem's arrays with their shapes checked (``ValueError`` naming the argument):
    (P, q, A, l, u, x0, y0, n, m, dtype); x0, y0 are zeros without a warm start."""
    P, q, A, l, u = (jnp.asarray(a) for a in (P, q, A, l, u))
    dtype = jnp.result_type(P, q, A, l, u, float)
    if warm_start is not None:
        x0, y0 = (jnp.asarray(a) for a in warm_start)
        dtype = jnp.result_type(dtype, x0, y0)
    if P.ndim < 2 or P.shape[-1] != P.shape[-2]:
        raise ValueError(f"P must have shape (..., n, n), got {P.shape}")
    n = P.shape[-1]
    if n < 1:
        raise ValueError("P must have n >= 1 variables")
    if q.ndim < 1 or q.shape[-1] != n:
        raise ValueError(f"q must have shape (..., {n}), got {q.shape}")
    if A.ndim < 2 or A.shape[-1] != n:
        raise ValueError(f"A must have shape (..., m, {n}), got {A.shape}")
    m = A.shape[-2]
    for name, v in (("l", l), ("u", u)):
        if v.ndim < 1 or v.shape[-1] != m:
            raise ValueError(f"{name} must have shape (..., {m}), got {v.shape}")
    if warm_start is not None:
        if x0.ndim < 1 or x0.shape[-1] != n:
            raise ValueError(f"warm_start x must have shape (..., {n}), got {x0.shape}")
        if y0.ndim < 1 or y0.shape[-1] != m:
            raise ValueError(f"warm_start y must have shape (..., {m}), got {y0.shape}")
    else:
        x0 = jnp.zeros((n,), dtype)
        y0 = jnp.zeros((m,), dtype)
    return P, q, A, l, u, x0, y0, n, m, dtype


def solve(P, q, A, l, u, *, settings: Settings = Settings(),
          warm_start: Optional[Tuple[jax.Array, jax.Array]] = None,
          batch_chunk: Optional[int] = None, compact: Optional[bool] = None,
          rho_start: Optional[jax.Array] = None) -> Solution:
    """Solve ``min ½xᵀPx + qᵀx  s.t.  l ≤ Ax ≤ u`` for one problem or a batch.

    Args:
      P: (…, n, n) symmetric PSD cost matrix (only its symmetric part is used).
      q: (…, n) linear cost.
      A: (…, m, n) constraint matrix.
      l, u: (…, m) bounds; ±inf or |bound| ≥ 1e20 means unbounded.
      settings: static ``Settings``.
      warm_start: optional ``(x, y)`` with shapes (…, n), (…, m) (e.g. the previous solution of a
        receding-horizon problem); z starts at A x.
      rho_start: optional (…,) starting step size ρ of each problem (e.g. ``Solution.rho`` of
        the previous solve, as OSQP keeps ρ between warm-started solves); entries that are
        not positive and finite start from ``Settings.rho``.  Default: ``Settings.rho``.
      batch_chunk: problems per vmapped chunk (chunks run sequentially, each until its own
        problems are done); default ``default_chunk()``.  Results do not depend on it.
      compact: run a batch solved in one piece with straggler compaction (:func:`_compacted`;
        with ``Settings.early_exit`` only); default ``default_compact()``.  For a single
        problem, ``True`` compacts the batch of an external vmap around this call
        (:func:`_compacted_under_vmap`); the default leaves it a plain vmapped loop.  Results
        do not depend on it beyond the rounding of differently compiled programs.
    Leading batch axes of all arguments broadcast against each other; the batch is vmapped
    internally.  dtype is the inputs' common float type.  Works under ``jit`` and ``vmap``.

    Returns:
      ``Solution`` with the batch shape in front of every field.
    """
    validate_settings(settings)
    chunk = default_chunk() if batch_chunk is None else batch_chunk
    if not (isinstance(chunk, int) and chunk >= 1):
        raise ValueError(f"batch_chunk = {batch_chunk!r} is outside the allowed range: integers >= 1")
    if not (compact is None or isinstance(compact, bool)):
        raise ValueError(f"compact = {compact!r} is outside the allowed range: True or False")
    P, q, A, l, u, x0, y0, n, m, dtype = _checked_arrays(P, q, A, l, u, warm_start)
    m_eff = m
    if m == 0:  # no constraints: one free row keeps every shape non-empty
        A = jnp.zeros(A.shape[:-2] + (1, n), dtype)
        l = jnp.full(l.shape[:-1] + (1,), -jnp.inf, dtype)
        u = jnp.full(u.shape[:-1] + (1,), jnp.inf, dtype)
        y0 = jnp.zeros(y0.shape[:-1] + (1,), dtype)
        m_eff = 1
    arrays = [P, q, A, l, u, x0, y0]
    shapes = [(n, n), (n,), (m_eff, n), (m_eff,), (m_eff,), (n,), (m_eff,)]
    if rho_start is not None:
        arrays.append(jnp.asarray(rho_start))
        shapes.append(())
    batch = jnp.broadcast_shapes(*(a.shape[:a.ndim - len(sh)] for a, sh in zip(arrays, shapes)))
    args = [jnp.broadcast_to(a.astype(dtype), batch + sh).reshape((-1,) + sh) if batch else
            a.astype(dtype) for a, sh in zip(arrays, shapes)]
    warm = warm_start is not None
    if not batch and compact:
        sol = _compacted_under_vmap(settings, warm, rho_start is not None)(*args)
    else:
        rho0 = args[7] if rho_start is not None else None
        sol = _solve_jit(*args[:7], rho0, settings=settings, warm=warm, batched=bool(batch),
                         chunk=chunk, compact=default_compact() if compact is None else compact)
    if batch:
        sol = jax.tree.map(lambda a: a.reshape(batch + a.shape[1:]), sol)
    if m == 0:
        sol = sol._replace(y=sol.y[..., :0], z=sol.z[..., :0])
    return sol
