"""CLF-QP torque controller for Cassie (one robot; vmap over a batch).

Output dynamics.  With η_i = [e_i, ė_i] (output error and its rate, :mod:`outputs`) every
active output is a double integrator driven by μ_i = ÿ_i − ÿ_d,i, and through the condensed
constrained dynamics (:mod:`dynamics`) μ is affine in the motor torques τ:

    μ = J_y (Q_τ τ + q̈₀) + J̇_y q̇ − ÿ_d  =:  A_μ τ + b_μ.

CLF.  For ė = [[0, 1], [0, 0]] η + [0, 1] μ and Q_i = diag(k_p², k_d² − 2k_p), R = 1 the
continuous Riccati equation (CARE) has the closed-form solution

    P_i = [[k_p k_d, k_p], [k_p, k_d]],   LQR gain K_i = Gᵀ P_i = [k_p, k_d],

(checked against scipy in the tests); with k_p = ω², k_d = 2ζω the closed loop is the PD
μ = −k_p e − k_d ė.  Under the LQR feedback η_iᵀP_iη_i decays at least at the rate γ_i, the
smallest generalised eigenvalue of (Q_i + K_iᵀK_i, P_i) (:func:`clf_rate`; γ_i ∝ ω_i).

The outputs fall into groups with their own time scales (``outputs.GROUPS``: pelvis
orientation, COM, foot position and slope, foot yaw).  Each group g has its own CLF

    V_g = Σ_{i∈g} m_i η_iᵀ P_i η_i,   γ_g = min_{i∈g} γ_i      (m_i the mode's output mask),

so the decay rate asked of a group is that of its own slowest output, not of the slowest
output of the robot (one CLF over all rows would let the fast swing and pelvis outputs decay
at the COM height's rate).  Along the output dynamics

    V̇_g = L_fV_g + L_gV_g μ,   L_fV_g = Σ_{i∈g} 2 m_i (k_p k_d e_i + k_p ė_i) ė_i,
    (L_gV_g)_i = 2 m_i (k_p e_i + k_d ė_i)  (i ∈ g, 0 elsewhere).

QP over x = [τ (nu), δ (4)]:

    min  ½ ‖W (A_μ τ + b_μ − μ_PD)‖² + ½ w_τ ‖τ‖² + ½ w_c ‖τ − τ_prev‖² + ½ p ‖δ‖²
    s.t. L_fV_g + L_gV_g (A_μ τ + b_μ) ≤ −γ_g V_g + δ_g,   δ_g ≥ 0  (per group, relaxed)
         λ_z ≥ 0,  |λ_x|, |λ_y| ≤ μ_f λ_z  at every active contact   (unilateral, pyramid)
         τ_min ≤ τ ≤ τ_max                                          (motor limits; a passive
                                                                     motor has τ_min = τ_max = 0)

with τ_prev the previous tick's solution (the chatter term w_c, 0 by default, smooths the
torques from tick to tick as Xiong's Cassie controller does) and μ_PD = −k_p e − k_d ė the CLF's own LQR input (the tracking term keeps the QP strictly
convex and the torque near the LQR's; the CLF rows are the guarantee), solved by
:func:`hlip_jax.core.qp.solve` warm-started from the previous tick; with ``fallback`` a tick whose QP is not
solved within the iteration budget (typically infeasible contact rows at an impact) keeps the
previous tick's torques, otherwise the last iterate is used (clipped to the limits).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from hlip_jax.core import qp
from hlip_jax.plants.cassie import dynamics, outputs

N_SITES = 4
N_FRICTION_ROWS = 5 * N_SITES
N_GROUPS = len(outputs.GROUPS)
#: (N_GROUPS, N_OUT) 0/1 membership of the outputs in the CLF groups
MEMBERS = np.stack([np.eye(outputs.N_OUT)[g].sum(axis=0) for g in outputs.GROUPS])


class Gains(NamedTuple):
    """Per-output PD / CLF gains and QP weights (arrays of length N_OUT, or scalars)."""
    kp: jax.Array          # (16,) [1/s²]
    kd: jax.Array          # (16,) [1/s]
    weight: jax.Array      # (16,) tracking weights W² (dimensionless)
    gamma: jax.Array       # (N_GROUPS,) CLF decay rate of each output group [1/s]
    w_tau: jax.Array       # torque regularisation weight [1/(N m)²]
    w_chatter: jax.Array   # weight of the torque change from the previous tick [1/(N m)²]
    w_delta: jax.Array     # CLF relaxation weight
    friction: jax.Array    # pyramid friction coefficient used in the QP (≤ the model's)


def care_matrix(kp, kd) -> np.ndarray:
    """P (2, 2) of one output: the CARE solution for Q = diag(kp², kd² − 2kp), R = 1."""
    return np.array([[kp * kd, kp], [kp, kd]], dtype=float)


def clf_rate(kp, kd) -> float:
    """γ with V̇ ≤ −γ V under the LQR feedback, for one output (smallest generalised eigenvalue
    of (Q + KᵀK, P)); a group of outputs takes the minimum of its own."""
    import scipy.linalg

    P = care_matrix(kp, kd)
    K = np.array([[kp, kd]])
    Q = np.diag([kp ** 2, kd ** 2 - 2 * kp])
    return float(scipy.linalg.eigh(Q + K.T @ K, P, eigvals_only=True).min())


def make_gains(omega, zeta=1.0, weight=None, w_tau=1e-4, w_delta=1e2, friction=0.6,
               w_chatter=0.0) -> Gains:
    """Gains from natural frequencies ``omega`` (16,) [rad/s] and damping ratio ζ ≥ 1/√2
    (k_d² ≥ 2k_p keeps the CARE weight Q ⪰ 0)."""
    omega = np.broadcast_to(np.asarray(omega, float), (outputs.N_OUT,))
    if np.any(omega <= 0):
        raise ValueError(f"omega must be > 0 for every output, got {omega}")
    if zeta < 1 / np.sqrt(2):
        raise ValueError(f"zeta must be ≥ 1/√2 ≈ 0.707, got {zeta}")
    kp, kd = omega ** 2, 2 * zeta * omega
    rates = np.array([clf_rate(a, b) for a, b in zip(kp, kd)])
    gamma = np.array([rates[g].min() for g in outputs.GROUPS])
    weight = np.ones(outputs.N_OUT) if weight is None else np.broadcast_to(weight, (outputs.N_OUT,))
    return Gains(kp=kp, kd=kd, weight=np.asarray(weight, float), gamma=gamma,
                 w_tau=np.float64(w_tau), w_chatter=np.float64(w_chatter),
                 w_delta=np.float64(w_delta),
                 friction=np.float64(friction))


DEFAULT_SETTINGS = qp.Settings(eps_abs=1e-4, eps_rel=1e-4, max_iter=150, check_interval=25,
                               adaptive_rho_interval=25, scaling=5)


class Problem(NamedTuple):
    P: jax.Array
    q: jax.Array
    A: jax.Array
    l: jax.Array
    u: jax.Array
    V: jax.Array          # (N_GROUPS,) CLF value of each group [—]
    Vdot_free: jax.Array  # (N_GROUPS,) L_fV_g + L_gV_g b_μ (V̇_g at τ = 0)
    LgV_A: jax.Array      # (N_GROUPS, nu) ∂V̇_g/∂τ


def build(meas: outputs.Measured, des: outputs.Desired, cond: dynamics.Condensed,
          contact, tau_min, tau_max, gains: Gains, tau_prev=0.0) -> Problem:
    """The CLF-QP of the module doc as (P, q, A, l, u) over x = [τ, δ]; ``tau_prev`` (nu,)
    [N m] is the chatter term's reference (the previous tick's torques)."""
    e, edot = outputs.errors(meas, des)
    m = des.mask
    kp, kd = jnp.asarray(gains.kp), jnp.asarray(gains.kd)
    A_mu = meas.J @ cond.qdd_tau                                      # (16, nu)
    b_mu = meas.J @ cond.qdd0 + meas.jdqd - des.yddot                 # (16,)
    mu_pd = -kp * e - kd * edot
    W = m * jnp.asarray(gains.weight)
    nu = A_mu.shape[1]
    dt = A_mu.dtype
    G = N_GROUPS
    H = A_mu.T @ (W[:, None] * A_mu) + (gains.w_tau + gains.w_chatter) * jnp.eye(nu, dtype=dt)
    g = A_mu.T @ (W * (b_mu - mu_pd)) - gains.w_chatter * jnp.asarray(tau_prev, dt)
    P = jnp.zeros((nu + G, nu + G), dt).at[:nu, :nu].set(H)
    P = P.at[nu:, nu:].set(gains.w_delta * jnp.eye(G, dtype=dt))
    q = jnp.concatenate([g, jnp.zeros(G, dt)])
    # CLF rows: LgV_g A τ − δ_g ≤ −γ_g V_g − LfV_g − LgV_g b
    M = jnp.asarray(MEMBERS, dt)
    V = M @ (m * (kp * kd * e ** 2 + 2 * kp * e * edot + kd * edot ** 2))
    LfV = M @ (2 * m * (kp * kd * e + kp * edot) * edot)
    LgV = M * (2 * m * (kp * e + kd * edot))[None, :]                  # (G, 16)
    LgV_A = LgV @ A_mu
    clf_rows = jnp.concatenate([LgV_A, -jnp.eye(G, dtype=dt)], axis=1)
    clf_ub = -jnp.asarray(gains.gamma, dt) * V - LfV - LgV @ b_mu
    F, fric_l, fric_u = _friction(cond, contact, gains.friction, nu, dt)
    F = jnp.concatenate([F, jnp.zeros((N_FRICTION_ROWS, G), dt)], axis=1)
    box = jnp.eye(nu + G, dtype=dt)
    A = jnp.concatenate([clf_rows, F, box], axis=0)
    l = jnp.concatenate([jnp.full(G, -jnp.inf, dt), fric_l,
                         jnp.asarray(tau_min, dt), jnp.zeros(G, dt)])
    u = jnp.concatenate([clf_ub, fric_u, jnp.asarray(tau_max, dt), jnp.full(G, jnp.inf, dt)])
    return Problem(P=P, q=q, A=A, l=l, u=u, V=V, Vdot_free=LfV + LgV @ b_mu, LgV_A=LgV_A)


def _friction(cond: dynamics.Condensed, contact, mu_f, nu: int, dt):
    """Unilateral and pyramid friction rows on the contact forces (rows of λ after the loop
    closures) as (F (20, nu), lower, upper): l ≤ F τ; rows of sites out of contact are free."""
    c0, c1 = dynamics.N_LOOP_ROWS, dynamics.N_LOOP_ROWS + dynamics.N_CONTACT_ROWS
    Lc = cond.lam_tau[c0:c1].reshape(N_SITES, 3, nu)
    lc0 = cond.lam0[c0:c1].reshape(N_SITES, 3)
    sel = jnp.array([[0, 0, 1], [-1, 0, mu_f], [1, 0, mu_f], [0, -1, mu_f], [0, 1, mu_f]], dt)
    F = jnp.einsum("rk,skn->srn", sel, Lc).reshape(N_FRICTION_ROWS, nu)
    f0 = jnp.einsum("rk,sk->sr", sel, lc0).reshape(N_FRICTION_ROWS)
    on = jnp.repeat(jnp.asarray(contact, dt) > 0.5, 5)
    return F, jnp.where(on, -f0, -jnp.inf), jnp.full(N_FRICTION_ROWS, jnp.inf, dt)


def n_vars(nu: int) -> int:
    """QP variables: the torques and one relaxation per CLF group."""
    return nu + N_GROUPS


def n_rows(nu: int) -> int:
    """QP rows: the CLF rows, the friction rows and the box rows of every variable."""
    return N_GROUPS + N_FRICTION_ROWS + nu + N_GROUPS


class Result(NamedTuple):
    tau: jax.Array        # (nu,) motor torques [N m], clipped to the limits
    delta: jax.Array      # (N_GROUPS,) CLF relaxations
    V: jax.Array          # (N_GROUPS,) CLF values
    Vdot: jax.Array       # (N_GROUPS,) predicted V̇_g at the returned τ
    status: jax.Array
    iterations: jax.Array
    warm: tuple           # (x, y, ρ) for the next tick


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
          settings: qp.Settings = DEFAULT_SETTINGS, fallback=False, active=True,
          compact: bool = False, rho_previous=False) -> Result:
    """Build and solve the CLF-QP; ``warm`` = (x, y, ρ) from the previous tick (zeros and
    ``settings.rho`` at start).

    ``fallback`` (bool or traced boolean scalar): when the QP is not solved, return the previous
    tick's solution instead of the clipped last iterate (per scenario while walking:
    ``CassieConfig.qp_fallback``; standing push recovery does better with the iterate).
    ``active`` false (traced boolean): the tick's torques are not used; a trivial QP is solved
    instead (:func:`idle`) and the result carries ``warm`` unchanged.  ``compact`` (static):
    a batch vmapped around this call is solved with straggler compaction
    (:func:`hlip_jax.core.qp.solve`).  ``rho_previous`` (bool or traced boolean scalar): start
    the ADMM from the previous tick's final step size ρ (``warm[2]``) instead of
    ``settings.rho``, as OSQP does when its workspace is updated and warm-started."""
    nu = jnp.shape(tau_min)[0]
    prob = build(meas, des, cond, contact, tau_min, tau_max, gains, tau_prev=warm[0][:nu])
    P, q, l, u, w = idle(prob, warm, active)
    rho0 = jnp.where(rho_previous, warm[2], settings.rho)
    sol = qp.solve(P, q, prob.A, l, u, settings=settings, warm_start=w, compact=compact,
                   rho_start=rho0)
    # with ``fallback`` a problem the ADMM budget did not solve (typically infeasible contact
    # rows at an impact) keeps the previous tick's torques instead of an unconverged iterate;
    # without it only a non-finite iterate falls back
    finite = jnp.all(jnp.isfinite(sol.x)) & jnp.all(jnp.isfinite(sol.y))
    solved = (sol.status == qp.SOLVED) | (sol.status == qp.SOLVED_INACCURATE)
    ok = finite & (solved | jnp.logical_not(fallback)) & active
    x = jnp.where(ok, sol.x, warm[0])
    y = jnp.where(ok, sol.y, warm[1])
    rho = jnp.where(ok, sol.rho, warm[2])
    tau = jnp.clip(x[:nu], tau_min, tau_max)
    return Result(tau=tau, delta=x[nu:], V=prob.V, Vdot=prob.Vdot_free + prob.LgV_A @ tau,
                  status=sol.status, iterations=sol.iterations, warm=(x, y, rho))
