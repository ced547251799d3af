"""CLF-QP torque controller for Cassie (one robot; vmap over a batch).

Output dynamics.  With η_i = [e_i, ė_i] (output error and its rate, :mod:`outputs`) every
active output is a double integrator driven by μ_i = ÿ_i − ÿ_d,i, and through the condensed
constrained dynamics (:mod:`dynamics`) μ is affine in the motor torques τ:

    μ = J_y (Q_τ τ + q̈₀) + J̇_y q̇ − ÿ_d  =:  A_μ τ + b_μ.

CLF.  For ė = [[0, 1], [0, 0]] η + [0, 1] μ and Q_i = diag(k_p², k_d² − 2k_p), R = 1 the
continuous Riccati equation (CARE) has the closed-form solution

    P_i = [[k_p k_d, k_p], [k_p, k_d]],   LQR gain K_i = Gᵀ P_i = [k_p, k_d],

(checked against scipy in the tests); with k_p = ω², k_d = 2ζω the closed loop is the PD
μ = −k_p e − k_d ė.  V = Σ_i m_i η_iᵀ P_i η_i (m_i the mode's output mask) and along the
output dynamics

    V̇ = L_fV + L_gV μ,   L_fV = Σ 2 m_i (k_p k_d e_i + k_p ė_i) ė_i,   (L_gV)_i = 2 m_i (k_p e_i + k_d ė_i).

Under the LQR feedback V̇ = −ηᵀ(Q + PGGᵀP)η ≤ −γ_i V with γ_i the smallest generalised
eigenvalue of (Q + KᵀK, P); the CLF row uses γ = min_i γ_i (:func:`clf_rate`).

QP over x = [τ (nu), δ]:

    min  ½ ‖W (A_μ τ + b_μ − μ_PD)‖² + ½ w_τ ‖τ‖² + ½ p δ²
    s.t. L_fV + L_gV (A_μ τ + b_μ) ≤ −γ V + δ,   δ ≥ 0            (relaxed CLF decrease)
         λ_z ≥ 0,  |λ_x|, |λ_y| ≤ μ_f λ_z  at every active contact   (unilateral, pyramid)
         τ_min ≤ τ ≤ τ_max                                          (motor limits; a passive
                                                                     motor has τ_min = τ_max = 0)

with μ_PD = −k_p e − k_d ė the CLF's own LQR input (the tracking term keeps the QP strictly
convex and the torque near the LQR's; the CLF row is the guarantee), solved by
:func:`hlip_jax.qp.solve` warm-started from the previous tick; with ``fallback`` a tick whose QP is not
solved within the iteration budget (typically infeasible contact rows at an impact) keeps the
previous tick's torques, otherwise the last iterate is used (clipped to the limits).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from hlip_jax import qp
from hlip_jax.plants.cassie import dynamics, outputs

N_SITES = 4
N_FRICTION_ROWS = 5 * N_SITES


class Gains(NamedTuple):
    """Per-output PD / CLF gains and QP weights (arrays of length N_OUT, or scalars)."""
    kp: jax.Array          # (16,) [1/s²]
    kd: jax.Array          # (16,) [1/s]
    weight: jax.Array      # (16,) tracking weights W² (dimensionless)
    gamma: jax.Array       # CLF decay rate [1/s]
    w_tau: jax.Array       # torque regularisation weight [1/(N m)²]
    w_delta: jax.Array     # CLF relaxation weight
    friction: jax.Array    # pyramid friction coefficient used in the QP (≤ the model's)


def care_matrix(kp, kd) -> np.ndarray:
    """P (2, 2) of one output: the CARE solution for Q = diag(kp², kd² − 2kp), R = 1."""
    return np.array([[kp * kd, kp], [kp, kd]], dtype=float)


def clf_rate(kp, kd) -> float:
    """γ with V̇ ≤ −γ V under the LQR feedback, for one output (smallest generalised eigenvalue
    of (Q + KᵀK, P)); for several outputs take the minimum."""
    import scipy.linalg

    P = care_matrix(kp, kd)
    K = np.array([[kp, kd]])
    Q = np.diag([kp ** 2, kd ** 2 - 2 * kp])
    return float(scipy.linalg.eigh(Q + K.T @ K, P, eigvals_only=True).min())


def make_gains(omega, zeta=1.0, weight=None, w_tau=1e-4, w_delta=1e2, friction=0.6) -> Gains:
    """Gains from natural frequencies ``omega`` (16,) [rad/s] and damping ratio ζ ≥ 1/√2
    (k_d² ≥ 2k_p keeps the CARE weight Q ⪰ 0)."""
    omega = np.broadcast_to(np.asarray(omega, float), (outputs.N_OUT,))
    if np.any(omega <= 0):
        raise ValueError(f"omega must be > 0 for every output, got {omega}")
    if zeta < 1 / np.sqrt(2):
        raise ValueError(f"zeta must be ≥ 1/√2 ≈ 0.707, got {zeta}")
    kp, kd = omega ** 2, 2 * zeta * omega
    gamma = min(clf_rate(a, b) for a, b in zip(kp, kd))
    weight = np.ones(outputs.N_OUT) if weight is None else np.broadcast_to(weight, (outputs.N_OUT,))
    return Gains(kp=kp, kd=kd, weight=np.asarray(weight, float), gamma=np.float64(gamma),
                 w_tau=np.float64(w_tau), w_delta=np.float64(w_delta),
                 friction=np.float64(friction))


DEFAULT_SETTINGS = qp.Settings(eps_abs=1e-4, eps_rel=1e-4, max_iter=150, check_interval=25,
                               adaptive_rho_interval=25, scaling=5)


class Problem(NamedTuple):
    P: jax.Array
    q: jax.Array
    A: jax.Array
    l: jax.Array
    u: jax.Array
    V: jax.Array          # CLF value [—]
    Vdot_free: jax.Array  # L_fV + L_gV b_μ (V̇ at τ = 0)
    LgV_A: jax.Array      # (nu,) ∂V̇/∂τ


def build(meas: outputs.Measured, des: outputs.Desired, cond: dynamics.Condensed,
          contact, tau_min, tau_max, gains: Gains) -> Problem:
    """The CLF-QP of the module doc as (P, q, A, l, u) over x = [τ, δ]."""
    e, edot = outputs.errors(meas, des)
    m = des.mask
    kp, kd = jnp.asarray(gains.kp), jnp.asarray(gains.kd)
    A_mu = meas.J @ cond.qdd_tau                                      # (16, nu)
    b_mu = meas.J @ cond.qdd0 + meas.jdqd - des.yddot                 # (16,)
    mu_pd = -kp * e - kd * edot
    W = m * jnp.asarray(gains.weight)
    nu = A_mu.shape[1]
    dt = A_mu.dtype
    H = A_mu.T @ (W[:, None] * A_mu) + gains.w_tau * jnp.eye(nu, dtype=dt)
    g = A_mu.T @ (W * (b_mu - mu_pd))
    P = jnp.zeros((nu + 1, nu + 1), dt).at[:nu, :nu].set(H).at[nu, nu].set(gains.w_delta)
    q = jnp.concatenate([g, jnp.zeros(1, dt)])
    # CLF row: LgV A τ − δ ≤ −γV − LfV − LgV b
    V = jnp.sum(m * (kp * kd * e ** 2 + 2 * kp * e * edot + kd * edot ** 2))
    LfV = jnp.sum(2 * m * (kp * kd * e + kp * edot) * edot)
    LgV = 2 * m * (kp * e + kd * edot)
    clf_row = jnp.concatenate([LgV @ A_mu, -jnp.ones(1, dt)])
    clf_ub = -gains.gamma * V - LfV - LgV @ b_mu
    # friction pyramid and unilateral rows on the contact forces (rows 12.. of λ)
    c0, c1 = dynamics.N_LOOP_ROWS, dynamics.N_LOOP_ROWS + dynamics.N_CONTACT_ROWS
    Lc = cond.lam_tau[c0:c1].reshape(N_SITES, 3, nu)
    lc0 = cond.lam0[c0:c1].reshape(N_SITES, 3)
    mu_f = gains.friction
    sel = jnp.array([[0, 0, 1], [-1, 0, mu_f], [1, 0, mu_f], [0, -1, mu_f], [0, 1, mu_f]], dt)
    F = jnp.einsum("rk,skn->srn", sel, Lc).reshape(N_FRICTION_ROWS, nu)
    f0 = jnp.einsum("rk,sk->sr", sel, lc0).reshape(N_FRICTION_ROWS)
    on = jnp.repeat(jnp.asarray(contact, dt) > 0.5, 5)
    fric_l = jnp.where(on, -f0, -jnp.inf)
    fric_u = jnp.full(N_FRICTION_ROWS, jnp.inf, dt)
    F = jnp.concatenate([F, jnp.zeros((N_FRICTION_ROWS, 1), dt)], axis=1)
    box = jnp.eye(nu + 1, dtype=dt)
    A = jnp.concatenate([clf_row[None], F, box], axis=0)
    l = jnp.concatenate([jnp.full(1, -jnp.inf, dt), fric_l,
                         jnp.asarray(tau_min, dt), jnp.zeros(1, dt)])
    u = jnp.concatenate([clf_ub[None], fric_u, jnp.asarray(tau_max, dt), jnp.full(1, jnp.inf, dt)])
    return Problem(P=P, q=q, A=A, l=l, u=u, V=V, Vdot_free=LfV + LgV @ b_mu, LgV_A=LgV @ A_mu)


def n_rows(nu: int) -> int:
    return 1 + N_FRICTION_ROWS + nu + 1


class Result(NamedTuple):
    tau: jax.Array        # (nu,) motor torques [N m], clipped to the limits
    delta: jax.Array      # CLF relaxation
    V: jax.Array
    Vdot: jax.Array       # predicted V̇ at the returned τ
    status: jax.Array
    iterations: jax.Array
    warm: tuple           # (x, y) for the next tick


def idle(prob: Problem, warm, active):
    """(P, q, l, u, warm) of the QP actually handed to the solver: ``prob`` and ``warm`` while
    ``active``, else min ½|x|² with free rows from a zero start — solved at the first
    convergence check.  In a vmapped batch the ADMM loop runs until every problem is done, so a
    robot whose tick does not act (a fallen robot, the idle ticks after a step's touchdown)
    would otherwise hold up the whole batch with a problem of no consequence."""
    n, m = prob.P.shape[0], prob.l.shape[0]
    dt = prob.P.dtype
    P = jnp.where(active, prob.P, jnp.eye(n, dtype=dt))
    q = jnp.where(active, prob.q, 0.0)
    l = jnp.where(active, prob.l, -qp.INF_BOUND)
    u = jnp.where(active, prob.u, qp.INF_BOUND)
    w = (jnp.where(active, warm[0], 0.0), jnp.where(active, warm[1], 0.0))
    return P, q, l, u, w


def solve(meas, des, cond, contact, tau_min, tau_max, gains: Gains, warm,
          settings: qp.Settings = DEFAULT_SETTINGS, fallback=False, active=True) -> Result:
    """Build and solve the CLF-QP; ``warm`` = (x, y) from the previous tick (zeros at start).

    ``fallback`` (bool or traced boolean scalar): when the QP is not solved, return the previous
    tick's solution instead of the clipped last iterate (per scenario while walking:
    ``CassieConfig.qp_fallback``; standing push recovery does better with the iterate).
    ``active`` false (traced boolean): the tick's torques are not used; a trivial QP is solved
    instead (:func:`idle`) and the result carries ``warm`` unchanged."""
    prob = build(meas, des, cond, contact, tau_min, tau_max, gains)
    P, q, l, u, w = idle(prob, warm, active)
    sol = qp.solve(P, q, prob.A, l, u, settings=settings, warm_start=w)
    # with ``fallback`` a problem the ADMM budget did not solve (typically infeasible contact
    # rows at an impact) keeps the previous tick's torques instead of an unconverged iterate;
    # without it only a non-finite iterate falls back
    finite = jnp.all(jnp.isfinite(sol.x)) & jnp.all(jnp.isfinite(sol.y))
    solved = (sol.status == qp.SOLVED) | (sol.status == qp.SOLVED_INACCURATE)
    ok = finite & (solved | jnp.logical_not(fallback)) & active
    x = jnp.where(ok, sol.x, warm[0])
    y = jnp.where(ok, sol.y, warm[1])
    nu = prob.P.shape[0] - 1
    tau = jnp.clip(x[:nu], tau_min, tau_max)
    return Result(tau=tau, delta=x[nu], V=prob.V, Vdot=prob.Vdot_free + prob.LgV_A @ tau,
                  status=sol.status, iterations=sol.iterations, warm=(x, y))
