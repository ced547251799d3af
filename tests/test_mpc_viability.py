"""The MPC's viability rows (``mpc.viability``): the divergent component's bounds against
numpy's eigendecomposition and a brute-force scalar simulation, the planned states of the QP
against bounds recomputed here, and the closed loop on the H-LIP plant."""

import textwrap

import jax.numpy as jnp
import numpy as np
import pytest

from hlip_jax.simulation import arrays, execution
from hlip_jax.core import hlip, mpc, qp
from hlip_jax.sweepio import sweep
from tests.test_mpc import _osqp, _params


def _numpy_divergent(A):
    """μ and the left eigenvector of A's [p, v] block for μ > 1, scaled to w_v = 1."""
    vals, vecs = np.linalg.eig(np.asarray(A)[1:, 1:].T)
    k = int(np.argmax(vals.real))
    w = vecs[:, k].real
    return vals[k].real, w / w[1]


@pytest.mark.parametrize("z0, t_ssp, t_dsp", [(0.8, 0.3, 0.1), (1.0, 0.25, 0.0), (0.9, 0.4, 0.05)])
def test_divergent_direction_is_the_unstable_left_eigenvector(z0, t_ssp, t_dsp):
    """Closed form of a 2 × 2 eigenproblem against numpy's; float64 round-off (1e-12)."""
    A, _ = hlip.s2s_matrices(z0, t_ssp, t_dsp)
    mu, w = mpc.divergent_direction(A)
    mu_ref, w_ref = _numpy_divergent(A)
    assert float(mu) > 1.0
    np.testing.assert_allclose(float(mu), mu_ref, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(w), w_ref, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(np.asarray(w) @ np.asarray(A)[1:, 1:], float(mu) * np.asarray(w),
                               atol=1e-12)


def _push(xi, mu, beta, band, up):
    """ξ⁺ = μ ξ + β u with the u of ``band`` that pushes ξ furthest up (or down)."""
    ends = (beta * band[0], beta * band[1])
    return mu * xi + (max(ends) if up else min(ends))


def _centre(xi, mu, beta, band, target):
    """ξ⁺ with the u of ``band`` that brings it closest to ``target``."""
    u = np.clip((target - mu * xi) / beta, min(band), max(band))
    return mu * xi + beta * u


@pytest.mark.parametrize("bands", [[(-0.1, 0.1)], [(-0.05, 0.3)],
                                   [(0.1, 0.4), (-0.4, -0.1)], [(0.15, 0.25), (-0.45, -0.05)]])
def test_bounds_are_the_edge_of_what_bounded_steps_can_hold(bands):
    """From 1e-6 inside [a_j, c_j], steps aimed at the next interval's centre keep ξ inside
    every interval for 40 steps; from 1e-6 outside, even the steps that push back hardest
    leave (the gap grows like μ^k: beyond 1e-3 within 40 steps).  The bands alternate as a
    lateral step band does (two bands) or repeat (one); scalar simulation in float64."""
    A, B = hlip.s2s_matrices(0.8, 0.3, 0.1)
    mu, w = mpc.divergent_direction(A)
    mu, beta = float(mu), float(np.asarray(w) @ np.asarray(B)[1:])
    N, P = 6, len(bands)
    lo = np.array([bands[j % P][0] for j in range(N)])
    hi = np.array([bands[j % P][1] for j in range(N)])
    a, c = (np.asarray(v) for v in mpc.viability_bounds(mu, beta, jnp.asarray(lo), jnp.asarray(hi)))
    assert np.all(a < c)
    for j in range(N):
        for start in (a[j] + 1e-6, c[j] - 1e-6):
            xi = start
            for k in range(40):
                nxt = (j + k + 1) % P
                xi = _centre(xi, mu, beta, bands[(j + k) % P], 0.5 * (a[nxt] + c[nxt]))
                assert a[nxt] - 1e-9 <= xi <= c[nxt] + 1e-9, (j, k, start, xi)
        for start, up in ((a[j] - 1e-6, True), (c[j] + 1e-6, False)):
            xi = start
            for k in range(40):
                xi = _push(xi, mu, beta, bands[(j + k) % P], up)
            assert (xi < a[j] - 1e-3) if up else (xi > c[j] + 1e-3), (j, start, xi)


def test_planned_states_keep_their_divergent_component_inside_the_bounds():
    """A plan from a slow state towards a reference running away faster than ±0.1 m steps can
    hold: without the rows the planned sagittal ξ leaves the bounds (the test can fail); with
    them every planned state is inside to OSQP's accuracy (1e-6) with zero slack.  The bounds
    are recomputed here from numpy's eigenvector: ±β 0.1 / (μ − 1) for the repeated band."""
    N, th = 6, 0.3
    params = _params(length_min=-0.1, length_max=0.1)
    x0 = jnp.array([[0.0, 0.0, 0.1 * np.cos(th)], [0.0, 0.0, 0.1 * np.sin(th)]])
    t = np.arange(1, N + 1) * 0.4
    prev = mpc.Preview(pos=jnp.asarray(np.stack([np.cos(th) * 0.8 * t, np.sin(th) * 0.8 * t], -1)),
                       vel=jnp.asarray(np.tile([0.8 * np.cos(th), 0.8 * np.sin(th)], (N, 1))),
                       heading=jnp.full((N,), th))
    mu, w = _numpy_divergent(params.A)
    bound = abs(float(w @ np.asarray(params.B)[1:])) * 0.1 / (mu - 1.0)
    for viability in (False, True):
        P, q, Aq, l, u = mpc.build_qp(params, x0, prev, 0, prev.pos, viability=viability)
        z = _osqp(P, q, Aq, l, u)
        X = np.asarray(mpc.predict(params, x0, mpc.decode(params, x0, jnp.asarray(z), N)))
        xi = X[:, :, 1] * w[0] + X[:, :, 2] * w[1]                      # (N, 2): x, y planes
        xi_sag = np.cos(th) * xi[:, 0] + np.sin(th) * xi[:, 1]
        outside = np.abs(xi_sag).max() - bound
        if viability:
            assert outside <= 1e-6, outside
            assert abs(z[-1]) <= 1e-6
        else:
            assert outside > 1e-2, outside


def test_admm_solves_the_viability_qp_as_osqp_does():
    """The project's ADMM on the QP with the rows agrees with OSQP (float64, eps 1e-9: 1e-5)."""
    N = 6
    params = _params(np.array([[1.0, 0.2, 0.3]]), length_min=-0.15, length_max=0.15)
    x0 = jnp.array([[0.0, 0.03, 0.4], [0.0, -0.02, 0.1]])
    t = np.arange(1, N + 1) * 0.4
    prev = mpc.Preview(pos=jnp.asarray(np.stack([1.2 * t, 0.1 * t], -1)),
                       vel=jnp.asarray(np.tile([1.2, 0.1], (N, 1))), heading=jnp.full((N,), 0.08))
    prev_c = prev.pos + jnp.array([0.0, 0.5])
    P, q, A, l, u = mpc.build_qp(params, x0, prev, 1, prev_c, viability=True)
    ref = _osqp(P, q, A, l, u)
    plan = mpc.solve(params, x0, prev, 1, prev_c, qp.Settings(eps_abs=1e-9, eps_rel=1e-9,
                                                              max_iter=40000), viability=True)
    assert int(plan.status) == qp.SOLVED
    np.testing.assert_allclose(np.asarray(plan.z), ref, atol=1e-5)
    ws = mpc.shift_warm_start(plan, N, 1)
    assert ws[0].shape == plan.z.shape and ws[1].shape == plan.y.shape


SWEEP = textwrap.dedent("""
    name = "capped"
    [base]
    plant = "hlip"
    duration = 12.0
    [base.mpc]
    step_length_min = -0.1
    step_length_max = 0.1
    [base.path]
    peak_speed = 0.6
    accel = 0.5
    [[paths]]
    name = "line"
    shape = "line"
    length = 20.0
    [grid.product]
    "mpc.viability" = [{value}]
""")


def test_a_capped_plan_keeps_the_hlip_walking_only_with_the_rows(tmp_path):
    """A path at 0.6 m/s with steps capped at ±0.1 m (≈ 0.25 m/s): without the rows the MPC
    speeds the H-LIP up beyond what ±0.1 m steps can brake and the plant falls within a few
    steps; with them it walks the 12 s, its velocity bounded by the band (≤ 0.5 m/s)."""
    out = {}
    for value in ("false", "true"):
        f = tmp_path / f"{value}.toml"
        f.write_text(SWEEP.format(value=value))
        cfgs = sweep.load_sweep(f).scenarios
        log = execution.simulate(cfgs)
        out[value] = (np.asarray(log.valid[0]), np.asarray(log.x_hlip[0]), arrays.n_steps_of(cfgs[0]))
    valid, _, n = out["false"]
    assert valid.sum() < n // 2
    valid, x, n = out["true"]
    assert valid.sum() == n
    assert np.abs(x[valid][:, 0, 2]).max() <= 0.5


@pytest.mark.parametrize("w_min, w_max", [(0.1, 0.645), (0.1, 0.3), (0.25, 0.49), (0.05, 0.5)])
def test_lateral_bands_hold_the_hlip_at_rest_only_below_one_over_mu(w_min, w_max):
    """Closed form of the alternating width bands' interval (mpc's docstring, why the lateral
    plane has no rows): |β| [μ w_min − w_max, μ w_max − w_min] / (μ² − 1), so ξ = 0 (rest) is
    inside iff w_min / w_max ≤ 1 / μ; float64 round-off (1e-12)."""
    A, B = hlip.s2s_matrices(0.8, 0.3, 0.1)
    mu, w = mpc.divergent_direction(A)
    mu, beta = float(mu), float(np.asarray(w) @ np.asarray(B)[1:])
    assert beta < 0
    lo = jnp.array([w_min, -w_max] * 3)
    hi = jnp.array([w_max, -w_min] * 3)
    a, c = (np.asarray(v) for v in mpc.viability_bounds(mu, beta, lo, hi))
    k = abs(beta) / (mu ** 2 - 1.0)
    np.testing.assert_allclose(a[0::2], k * (mu * w_min - w_max), atol=1e-12)
    np.testing.assert_allclose(c[0::2], k * (mu * w_max - w_min), atol=1e-12)
    np.testing.assert_allclose(a[1::2], -c[0::2], atol=1e-12)
    assert (a[0] <= 0.0) == (w_min / w_max <= 1.0 / mu)
