"""Tests for hlip_jax.core.hlip: S2S matrices, gains and orbits.

Every closed form in hlip.py is checked against something independent of it: a numerical
integration of the hybrid dynamics (scipy's DOP853), scipy's Riccati solver, the defining
fixed-point equations, or the figures quoted in DESIGN.md.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg
from scipy.integrate import solve_ivp

from hlip_jax.core import hlip

G = hlip.GRAVITY
CASES = [  # (z0 [m], t_ssp [s], t_dsp [s])
    (0.75, 0.35, 0.05),
    (1.0, 0.30, 0.10),
    (0.85, 0.40, 0.0),
    (0.6, 0.25, 0.08),
]
# DOP853 at rtol = atol = 1e-12 integrates these sub-second flows to ~1e-11 relative, so
# 1e-9 leaves two orders of margin while still catching any wrong coefficient.
INT_TOL = 1e-9


# ---------------------------------------------------------------------------------------
# independent reference: integrate the hybrid H-LIP
# ---------------------------------------------------------------------------------------
def _flow(x, duration, lam2):
    """Integrate [c, p, v] with ċ = v, ṗ = v, v̇ = lam2·p for ``duration`` seconds."""
    if duration == 0.0:
        return np.asarray(x, float)

    def f(_, y):
        return [y[2], y[2], lam2 * y[1]]

    sol = solve_ivp(f, (0.0, duration), np.asarray(x, float), method="DOP853",
                    rtol=1e-12, atol=1e-12)
    return sol.y[:, -1]


def _s2s_integrated(x, u, z0, t_ssp, t_dsp):
    """One H-LIP step from SSP⁻ state [c, p, v]: DSP flow (p̈ = 0), the step u moves the
    stance foot (p ← p − u, c unchanged), then the SSP flow (p̈ = λ² p)."""
    lam2 = G / z0
    x = _flow(x, t_dsp, 0.0)
    x = x - np.array([0.0, u, 0.0])
    return _flow(x, t_ssp, lam2)


def _matrices_integrated(z0, t_ssp, t_dsp):
    """A, B of the (linear) S2S map from its action on basis states and a unit step."""
    zero = _s2s_integrated(np.zeros(3), 0.0, z0, t_ssp, t_dsp)
    A = np.stack([_s2s_integrated(e, 0.0, z0, t_ssp, t_dsp) - zero for e in np.eye(3)], axis=1)
    B = _s2s_integrated(np.zeros(3), 1.0, z0, t_ssp, t_dsp) - zero
    return A, B


# ---------------------------------------------------------------------------------------
# S2S matrices
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("z0,t_ssp,t_dsp", CASES)
def test_s2s_matrices_match_integration(z0, t_ssp, t_dsp):
    A_ref, B_ref = _matrices_integrated(z0, t_ssp, t_dsp)
    A3, B3 = hlip.s2s_matrices(z0, t_ssp, t_dsp, with_position=True)
    A2, B2 = hlip.s2s_matrices(z0, t_ssp, t_dsp, with_position=False)
    np.testing.assert_allclose(A3, A_ref, rtol=INT_TOL, atol=INT_TOL)
    np.testing.assert_allclose(B3, B_ref, rtol=INT_TOL, atol=INT_TOL)
    # the 2-state system is the [p, v] block (c does not feed back)
    np.testing.assert_allclose(A2, A_ref[1:, 1:], rtol=INT_TOL, atol=INT_TOL)
    np.testing.assert_allclose(B2, B_ref[1:], rtol=INT_TOL, atol=INT_TOL)


def test_design_example_figures():
    """DESIGN.md: z0 = 0.75, T_S = 0.35, T_D = 0.05 → λ = 3.6166,
    A = [[1.914, 0.5469], [5.9023, 2.2091]], K_deadbeat = [1, 0.3743]."""
    z0, ts, td = 0.75, 0.35, 0.05
    lam = float(jnp.sqrt(G / z0))
    A, _ = hlip.s2s_matrices(z0, ts, td, with_position=False)
    K = hlip.deadbeat_gain(z0, ts, td)
    # The figures are quoted rounded to their last printed digit: half a unit there.
    assert abs(lam - 3.6166) <= 0.5e-4
    assert abs(A[0, 0] - 1.914) <= 0.5e-3
    assert abs(A[0, 1] - 0.5469) <= 0.5e-4
    assert abs(A[1, 0] - 5.9023) <= 0.5e-4
    assert abs(A[1, 1] - 2.2091) <= 0.5e-4
    assert abs(K[0] - 1.0) <= 0.5e-4 and abs(K[1] - 0.3743) <= 0.5e-4


# ---------------------------------------------------------------------------------------
# gains
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("z0,t_ssp,t_dsp", CASES)
def test_deadbeat_nilpotent(z0, t_ssp, t_dsp):
    # Entries of A are O(1..10), so products of exact nilpotents carry ~1e-14 rounding;
    # 1e-10 is far below any structural error.
    A2, B2 = hlip.s2s_matrices(z0, t_ssp, t_dsp, with_position=False)
    K2 = hlip.deadbeat_gain(z0, t_ssp, t_dsp)
    Acl2 = np.asarray(A2 + jnp.outer(B2, K2))
    assert np.linalg.norm(Acl2 @ Acl2) < 1e-10
    assert np.linalg.norm(Acl2) > 1e-3  # nilpotent, not zero: E = W ⊕ A_cl W is not trivial

    A3, B3 = hlip.s2s_matrices(z0, t_ssp, t_dsp, with_position=True)
    K3 = hlip.deadbeat_gain(z0, t_ssp, t_dsp, with_position=True)
    Acl3 = np.asarray(A3 + jnp.outer(B3, K3))
    assert np.linalg.norm(np.linalg.matrix_power(Acl3, 3)) < 1e-10


@pytest.mark.parametrize("z0,t_ssp,t_dsp", CASES)
def test_deadbeat_through_integrated_dynamics(z0, t_ssp, t_dsp):
    """Applying u = K x on the *integrated* hybrid flow zeroes the state in 2 steps (2-state
    [p, v]) and in 3 steps ([c, p, v])."""
    K2 = np.asarray(hlip.deadbeat_gain(z0, t_ssp, t_dsp))
    K3 = np.asarray(hlip.deadbeat_gain(z0, t_ssp, t_dsp, with_position=True))
    x = np.array([0.3, 0.05, -0.2])
    y = x.copy()
    for _ in range(2):
        y = _s2s_integrated(y, float(K2 @ y[1:]), z0, t_ssp, t_dsp)
    assert np.max(np.abs(y[1:])) < 1e-8  # integrator tolerance × gain magnitudes
    for _ in range(3):
        x = _s2s_integrated(x, float(K3 @ x), z0, t_ssp, t_dsp)
    assert np.max(np.abs(x)) < 1e-8


@pytest.mark.parametrize("z0,t_ssp,t_dsp", CASES)
def test_ackermann_equals_closed_form_deadbeat(z0, t_ssp, t_dsp):
    A, B = hlip.s2s_matrices(z0, t_ssp, t_dsp, with_position=False)
    # both are exact formulas; a 2×2 solve in float64 agrees to ~1e-14
    np.testing.assert_allclose(hlip.place_gain_ackermann(A, B),
                               hlip.deadbeat_gain(z0, t_ssp, t_dsp), rtol=1e-10, atol=1e-12)


def _scipy_lqr(A, B, Q, R):
    A = np.asarray(A)
    Bm = np.asarray(B)[:, None]
    Rm = np.atleast_2d(R)
    P = scipy.linalg.solve_discrete_are(A, Bm, Q, Rm)
    return -np.linalg.solve(Rm + Bm.T @ P @ Bm, Bm.T @ P @ A)[0]


@pytest.mark.parametrize("with_position", [False, True])
@pytest.mark.parametrize("z0,t_ssp,t_dsp", CASES[:3])
@pytest.mark.parametrize("q_diag,r", [((1.0, 1.0, 1.0), 1.0), ((10.0, 1.0, 0.1), 0.5),
                                       ((0.1, 5.0, 2.0), 10.0), ((1.0, 0.01, 0.01), 0.01)])
def test_lqr_matches_scipy(with_position, z0, t_ssp, t_dsp, q_diag, r):
    A, B = hlip.s2s_matrices(z0, t_ssp, t_dsp, with_position=with_position)
    n = A.shape[0]
    Q = np.diag(q_diag[-n:])
    K = hlip.lqr_gain(A, B, jnp.asarray(Q), jnp.asarray(r))
    K_ref = _scipy_lqr(A, B, Q, r)
    # scipy's Schur-based DARE and the doubling iteration both reach ~1e-12 relative here.
    np.testing.assert_allclose(K, K_ref, rtol=1e-8, atol=1e-10)
    # and the closed loop is stable
    assert np.max(np.abs(np.linalg.eigvals(np.asarray(A + jnp.outer(B, K))))) < 1.0


def test_lqr_matrix_input_shape():
    A, B = hlip.s2s_matrices(0.75, 0.35, 0.05, with_position=False)
    K = hlip.lqr_gain(A, B[:, None], jnp.eye(2), jnp.eye(1))
    assert K.shape == (1, 2)
    np.testing.assert_allclose(K[0], _scipy_lqr(A, B, np.eye(2), 1.0), rtol=1e-8, atol=1e-10)


def test_lqr_jit_vmap_over_q_weights():
    A, B = hlip.s2s_matrices(0.75, 0.35, 0.05, with_position=True)
    weights = jnp.array([[1.0, 1.0, 1.0], [5.0, 1.0, 0.1], [0.2, 3.0, 3.0], [1.0, 0.1, 10.0]])

    @jax.jit
    def gains(w, r):
        return jax.vmap(lambda wi: hlip.lqr_gain(A, B, jnp.diag(wi), r))(w)

    K = gains(weights, jnp.asarray(0.5))
    assert K.shape == (4, 3)
    for wi, Ki in zip(np.asarray(weights), np.asarray(K)):
        np.testing.assert_allclose(Ki, _scipy_lqr(A, B, np.diag(wi), 0.5), rtol=1e-8, atol=1e-10)


# ---------------------------------------------------------------------------------------
# orbits
# ---------------------------------------------------------------------------------------
def _mean_velocity_over_step(p, v, u, z0, t_ssp, t_dsp):
    """Mean COM velocity over one integrated step from SSP⁻: c displacement / T."""
    x1 = _s2s_integrated(np.array([0.0, p, v]), u, z0, t_ssp, t_dsp)
    return x1[0] / (t_ssp + t_dsp)


@pytest.mark.parametrize("z0,t_ssp,t_dsp", CASES)
@pytest.mark.parametrize("v_avg", [-0.4, 0.0, 0.5, 1.2])
def test_p1_orbit_fixed_point(z0, t_ssp, t_dsp, v_avg):
    orb = hlip.p1_orbit(z0, t_ssp, t_dsp, v_avg)
    A, B = hlip.s2s_matrices(z0, t_ssp, t_dsp, with_position=False)
    x = jnp.stack([orb.p, orb.v])
    # fixed point of the closed-form map: exact up to rounding
    assert np.max(np.abs(A @ x + B * orb.u - x)) < 1e-10
    # and of the integrated hybrid flow (integrator tolerance)
    x1 = _s2s_integrated(np.array([0.0, orb.p, orb.v]), float(orb.u), z0, t_ssp, t_dsp)
    np.testing.assert_allclose(x1[1:], np.asarray(x), atol=INT_TOL)
    assert abs(float(orb.u) / (t_ssp + t_dsp) - v_avg) < 1e-12
    assert abs(_mean_velocity_over_step(orb.p, orb.v, orb.u, z0, t_ssp, t_dsp) - v_avg) < INT_TOL


@pytest.mark.parametrize("z0,t_ssp,t_dsp", CASES)
@pytest.mark.parametrize("v_avg,u_left", [(0.0, 0.15), (0.5, 0.3), (-0.3, 0.1), (0.8, 0.2)])
def test_p2_orbit_fixed_point(z0, t_ssp, t_dsp, v_avg, u_left):
    orb = hlip.p2_orbit(z0, t_ssp, t_dsp, v_avg, u_left)
    A, B = hlip.s2s_matrices(z0, t_ssp, t_dsp, with_position=False)
    xl = jnp.stack([orb.p_left, orb.v_left])
    xr = jnp.stack([orb.p_right, orb.v_right])
    assert np.max(np.abs(A @ xl + B * orb.u_left - xr)) < 1e-10
    assert np.max(np.abs(A @ xr + B * orb.u_right - xl)) < 1e-10
    T = t_ssp + t_dsp
    assert abs(float(orb.u_left + orb.u_right) / (2 * T) - v_avg) < 1e-12
    # average speed over the two integrated steps
    vl = _mean_velocity_over_step(orb.p_left, orb.v_left, orb.u_left, z0, t_ssp, t_dsp)
    vr = _mean_velocity_over_step(orb.p_right, orb.v_right, orb.u_right, z0, t_ssp, t_dsp)
    assert abs(0.5 * (vl + vr) - v_avg) < INT_TOL


def test_p2_orbit_with_symmetric_steps_is_p1():
    z0, ts, td, v = 0.75, 0.35, 0.05, 0.6
    p1 = hlip.p1_orbit(z0, ts, td, v)
    p2 = hlip.p2_orbit(z0, ts, td, v, p1.u)
    np.testing.assert_allclose([p2.p_left, p2.v_left, p2.p_right, p2.v_right],
                               [p1.p, p1.v, p1.p, p1.v], rtol=1e-12, atol=1e-12)


# ---------------------------------------------------------------------------------------
# continuous-time trajectories
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("z0,t_ssp,t_dsp", CASES)
def test_ssp_and_step_trajectory_match_integrator(z0, t_ssp, t_dsp):
    p0, v0 = -0.12, 0.45
    lam2 = G / z0
    T = t_ssp + t_dsp
    ts = np.linspace(0.0, T, 23)

    sol = solve_ivp(lambda _, y: [y[1], lam2 * y[0]], (0.0, t_ssp), [p0, v0], method="DOP853",
                    rtol=1e-12, atol=1e-12, dense_output=True)
    t_in = ts[ts <= t_ssp]
    p, v = hlip.ssp_trajectory(p0, v0, jnp.asarray(t_in), z0)
    ref = sol.sol(t_in)
    np.testing.assert_allclose(p, ref[0], atol=INT_TOL)
    np.testing.assert_allclose(v, ref[1], atol=INT_TOL)

    # step: SSP then DSP at constant velocity
    end = sol.y[:, -1]
    ref_p = np.where(ts <= t_ssp, sol.sol(np.minimum(ts, t_ssp))[0],
                     end[0] + end[1] * (ts - t_ssp))
    ref_v = np.where(ts <= t_ssp, sol.sol(np.minimum(ts, t_ssp))[1], end[1])
    p, v = hlip.step_trajectory(p0, v0, jnp.asarray(ts), z0, t_ssp, t_dsp)
    np.testing.assert_allclose(p, ref_p, atol=INT_TOL)
    np.testing.assert_allclose(v, ref_v, atol=INT_TOL)

    # the end of the step followed by the foot switch reproduces the S2S map from SSP⁺
    A, B = hlip.s2s_matrices(z0, t_ssp, t_dsp, with_position=False)
    pT, vT = hlip.step_trajectory(p0, v0, T, z0, t_ssp, t_dsp)
    x_pre = np.array([end[0], end[1]])  # SSP⁻ of this step
    u = 0.3
    nxt = _s2s_integrated(np.array([0.0, *x_pre]), u, z0, t_ssp, t_dsp)[1:]
    np.testing.assert_allclose(A @ x_pre + B * u, nxt, atol=INT_TOL)
    np.testing.assert_allclose([pT, vT], [x_pre[0] + x_pre[1] * t_dsp, x_pre[1]], atol=INT_TOL)


# ---------------------------------------------------------------------------------------
# jit / vmap with traced physical parameters
# ---------------------------------------------------------------------------------------
def test_everything_jit_vmap_with_traced_parameters():
    z0 = jnp.array([0.7, 0.75, 0.9])
    ts = jnp.array([0.3, 0.35, 0.4])
    td = jnp.array([0.0, 0.05, 0.1])
    v = jnp.array([0.2, 0.5, -0.3])

    def all_outputs(z0, ts, td, v):
        A2, B2 = hlip.s2s_matrices(z0, ts, td, with_position=False)
        A3, B3 = hlip.s2s_matrices(z0, ts, td, with_position=True)
        return dict(
            A2=A2, B2=B2, A3=A3, B3=B3,
            K2=hlip.deadbeat_gain(z0, ts, td),
            K3=hlip.deadbeat_gain(z0, ts, td, with_position=True),
            Kack=hlip.place_gain_ackermann(A2, B2),
            Klqr=hlip.lqr_gain(A3, B3, jnp.eye(3), jnp.asarray(1.0)),
            p1=hlip.p1_orbit(z0, ts, td, v),
            p2=hlip.p2_orbit(z0, ts, td, v, 0.1),
            ssp=hlip.ssp_trajectory(0.1, 0.3, ts, z0),
            step=hlip.step_trajectory(0.1, 0.3, ts + td, z0, ts, td),
        )

    batched = jax.jit(jax.vmap(all_outputs))(z0, ts, td, v)
    for i in range(3):
        single = all_outputs(float(z0[i]), float(ts[i]), float(td[i]), float(v[i]))
        jax.tree.map(lambda b, s: np.testing.assert_allclose(b[i], s, rtol=1e-10, atol=1e-12),
                     batched, single)
    assert batched["A3"].shape == (3, 3, 3) and batched["K3"].shape == (3, 3)
