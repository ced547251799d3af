"""Hybrid-LIP (H-LIP) step-to-step (S2S) dynamics, orbits and stepping gains.

The H-LIP (Xiong & Ames) models the horizontal centre-of-mass (COM) motion of a walking
robot with constant COM height ``z0`` [m] in each of the sagittal and lateral planes:

* single support (SSP, duration ``t_ssp`` [s]):  p̈ = λ² p,   λ = √(g / z0)  [1/s]
* double support (DSP, duration ``t_dsp`` [s]):  p̈ = 0
* the step ``u`` [m] (new stance foot − old stance foot) is taken at the end of DSP.

``p`` [m] is the COM relative to the stance foot, ``v`` [m/s] its velocity and ``c`` [m] the
global COM position.  The state is sampled at the end of SSP (SSP⁻, "pre-impact").  With
C = cosh(λ T_S), S = sinh(λ T_S) the S2S map over one step, T = T_S + T_D, is

    [p, v]⁺    = A2 [p, v]    + B2 u,   A2 = [[C, T_D C + S/λ], [λS, T_D λS + C]],  B2 = [−C, −λS]
    [c, p, v]⁺ = A3 [c, p, v] + B3 u,   A3 = [[1, C−1, T_D C + S/λ], [0, A2]],        B3 = [1−C, B2]

(c⁺ = c + p⁺ − p + u).  Every function here is a pure ``jax.numpy`` function whose physical
parameters may be traced, so they jit, vmap and sweep; only ``with_position`` (which selects
the state size) is static.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

GRAVITY = 9.81  # [m/s²]


def _lam(z0, g):
    return jnp.sqrt(g / z0)


def s2s_matrices(z0, t_ssp, t_dsp, g=GRAVITY, with_position: bool = True):
    """S2S matrices ``(A, B)`` of the H-LIP sampled at SSP⁻.

    Args:
      z0: nominal COM height [m].
      t_ssp, t_dsp: single and double support durations [s].
      g: gravity [m/s²].
      with_position: static; ``True`` gives the 3-state ``[c, p, v]`` system (A 3×3, B 3),
        ``False`` the 2-state ``[p, v]`` one (A 2×2, B 2).
    """
    lam = _lam(z0, g)
    C = jnp.cosh(lam * t_ssp)
    S = jnp.sinh(lam * t_ssp)
    a12 = t_dsp * C + S / lam
    a22 = t_dsp * lam * S + C
    if with_position:
        z = jnp.zeros_like(C)
        o = jnp.ones_like(C)
        A = jnp.stack([
            jnp.stack([o, C - 1.0, a12]),
            jnp.stack([z, C, a12]),
            jnp.stack([z, lam * S, a22]),
        ])
        B = jnp.stack([1.0 - C, -C, -lam * S])
    else:
        A = jnp.stack([jnp.stack([C, a12]), jnp.stack([lam * S, a22])])
        B = jnp.stack([-C, -lam * S])
    return A, B


def place_gain_ackermann(A, B):
    """Gain K (shape (n,)) with ``u = K x`` placing every eigenvalue of A + B K at zero.

    Ackermann's formula for the characteristic polynomial zⁿ:
    K = −e_nᵀ 𝒞⁻¹ Aⁿ with the controllability matrix 𝒞 = [B, AB, …, Aⁿ⁻¹B].
    Requires (A, B) controllable.
    """
    n = A.shape[-1]
    cols = [B]
    for _ in range(n - 1):
        cols.append(A @ cols[-1])
    ctrb = jnp.stack(cols, axis=-1)
    An = jnp.linalg.matrix_power(A, n)
    # row vector r with r 𝒞 = e_nᵀ  ⇔  𝒞ᵀ rᵀ = e_n
    e_n = jnp.zeros((n,), A.dtype).at[-1].set(1.0)
    r = jnp.linalg.solve(ctrb.T, e_n)
    return -(r @ An)


def deadbeat_gain(z0, t_ssp, t_dsp, g=GRAVITY, with_position: bool = False):
    """Deadbeat stepping gain K with A + B K nilpotent.

    2-state (closed form): K = [1, T_D + coth(λ T_S)/λ], so (A+BK)² = 0.
    3-state ``[c, p, v]`` (``with_position=True``): Ackermann placement of all three
    eigenvalues at zero, so (A+BK)³ = 0 and the global position error is also removed.
    Returns K of shape (2,) or (3,).
    """
    if with_position:
        A, B = s2s_matrices(z0, t_ssp, t_dsp, g, with_position=True)
        return place_gain_ackermann(A, B)
    lam = _lam(z0, g)
    k2 = t_dsp + 1.0 / (lam * jnp.tanh(lam * t_ssp))
    return jnp.stack([jnp.ones_like(k2), k2])


def solve_dare(A, Q, G, iterations: int = 60):
    """Stabilising solution P of the discrete algebraic Riccati equation
    P = Aᵀ P A − Aᵀ P B (R + Bᵀ P B)⁻¹ Bᵀ P A + Q, given G = B R⁻¹ Bᵀ.

    Structure-preserving doubling (Chu et al. 2004): with A₀ = A, G₀ = G, H₀ = Q,
      W = I + G_k H_k,
      A_{k+1} = A_k W⁻¹ A_k,
      G_{k+1} = G_k + A_k W⁻¹ G_k A_kᵀ,
      H_{k+1} = H_k + A_kᵀ H_k W⁻¹ A_k,
    and H_k → P quadratically.  A fixed iteration count keeps it a static loop (each
    iteration doubles the horizon, so 60 covers any stabilisable case in float64).
    """
    n = A.shape[-1]
    eye = jnp.eye(n, dtype=A.dtype)

    def body(_, carry):
        Ak, Gk, Hk = carry
        W = eye + Gk @ Hk
        WA = jnp.linalg.solve(W, Ak)
        WG = jnp.linalg.solve(W, Gk)
        A1 = Ak @ WA
        G1 = Gk + Ak @ WG @ Ak.T
        H1 = Hk + Ak.T @ Hk @ WA
        return A1, 0.5 * (G1 + G1.T), 0.5 * (H1 + H1.T)

    _, _, P = jax.lax.fori_loop(0, iterations, body, (A, G, Q))
    return P


def lqr_gain(A, B, Q, R):
    """Discrete LQR gain K (``u = K x``, A + B K stable) for x⁺ = A x + B u,
    cost Σ xᵀQx + uᵀRu.  B may be a vector (single input) or an n×m matrix; K then has
    shape (n,) or (m, n).  Q, R are traced, so gain weights can be swept.
    """
    A = jnp.asarray(A)
    A = A.astype(jnp.result_type(A.dtype, float))
    B = jnp.asarray(B, A.dtype)
    Q = jnp.asarray(Q, A.dtype)
    single = B.ndim == 1
    Bm = B[:, None] if single else B
    Rm = jnp.atleast_2d(jnp.asarray(R, A.dtype))
    G = Bm @ jnp.linalg.solve(Rm, Bm.T)
    P = solve_dare(A, Q, G)
    K = -jnp.linalg.solve(Rm + Bm.T @ P @ Bm, Bm.T @ P @ A)
    return K[0] if single else K


class P1Orbit(NamedTuple):
    """Period-1 orbit: pre-impact state (p [m], v [m/s]) and step size u [m]."""
    p: jax.Array
    v: jax.Array
    u: jax.Array


class P2Orbit(NamedTuple):
    """Period-2 orbit.  ``p_left, v_left`` is the pre-impact state from which the step
    ``u_left`` is taken; likewise for the right.  u_left + u_right = 2 v̄ T."""
    p_left: jax.Array
    v_left: jax.Array
    u_left: jax.Array
    p_right: jax.Array
    v_right: jax.Array
    u_right: jax.Array


def p1_orbit(z0, t_ssp, t_dsp, v_avg, g=GRAVITY) -> P1Orbit:
    """Period-1 orbit with average velocity ``v_avg`` [m/s].

    v* = σ₁ p*,  σ₁ = λ coth(λ T_S / 2);  u* = 2 p* + T_D v* = v̄ T.
    """
    lam = _lam(z0, g)
    sigma1 = lam / jnp.tanh(0.5 * lam * t_ssp)
    u = v_avg * (t_ssp + t_dsp)
    p = u / (2.0 + t_dsp * sigma1)
    return P1Orbit(p=p, v=sigma1 * p, u=u)


def p2_orbit(z0, t_ssp, t_dsp, v_avg, u_left, g=GRAVITY) -> P2Orbit:
    """Period-2 orbit with average velocity ``v_avg`` and left step ``u_left`` [m].

    v = σ₂ p + d₂,  σ₂ = λ tanh(λ T_S / 2),
    d₂ = λ² sech²(λ T_S / 2) v̄ T / (λ² T_D + 2 σ₂);
    the state from which step u is taken has p = (u − T_D d₂)/(2 + T_D σ₂), v = σ₂ p + d₂,
    and u_right = 2 v̄ T − u_left.
    """
    lam = _lam(z0, g)
    half = 0.5 * lam * t_ssp
    sigma2 = lam * jnp.tanh(half)
    T = t_ssp + t_dsp
    d2 = lam**2 / jnp.cosh(half) ** 2 * v_avg * T / (lam**2 * t_dsp + 2.0 * sigma2)
    u_right = 2.0 * v_avg * T - u_left

    def state(u):
        p = (u - t_dsp * d2) / (2.0 + t_dsp * sigma2)
        return p, sigma2 * p + d2

    pl, vl = state(u_left)
    pr, vr = state(u_right)
    return P2Orbit(pl, vl, jnp.asarray(u_left) + 0.0 * pl, pr, vr, u_right)


def ssp_trajectory(p0, v0, t, z0, g=GRAVITY):
    """LIP state at time ``t`` [s] after the start of SSP from (p0, v0):
    p(t) = p0 cosh(λt) + v0 sinh(λt)/λ,  v(t) = p0 λ sinh(λt) + v0 cosh(λt).
    Broadcasts over ``t``."""
    lam = _lam(z0, g)
    ch = jnp.cosh(lam * t)
    sh = jnp.sinh(lam * t)
    return p0 * ch + v0 * sh / lam, p0 * lam * sh + v0 * ch


def step_trajectory(p0, v0, t, z0, t_ssp, t_dsp, g=GRAVITY):
    """H-LIP state at time ``t`` in a step that starts at SSP⁺ from (p0, v0): the LIP flow
    for t ≤ T_S, then constant velocity in DSP (p̈ = 0) until T_S + T_D.  The stance foot is
    the same throughout (the step that ends the DSP is not applied).  Broadcasts over ``t``."""
    ts = jnp.minimum(t, t_ssp)
    p, v = ssp_trajectory(p0, v0, ts, z0, g)
    td = jnp.clip(t - t_ssp, 0.0, t_dsp)
    return p + v * td, v
