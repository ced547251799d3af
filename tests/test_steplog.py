"""The step-log vocabulary (hlip_jax.core.steplog): fields, the alive mask, the S2S residual and the
heading-frame rotation, each against an independent construction."""

import numpy as np

from hlip_jax.core import hlip, steplog


def test_fields_and_step_fields():
    assert steplog.FIELDS == steplog.Log._fields
    assert steplog.STEP_FIELDS[0] == "t" and steplog.STEP_FIELDS[-1] == "valid"
    assert not set(steplog.STEP_FIELDS) & {"status", "fail_step", "A", "B", "K_gain"}
    assert set(steplog.STATUS_NAMES.values()) == {"ok", "fell", "nonfinite", "qp_failed"}
    # every field is documented once in FIELD_DOC as "name: ..." (not the module doc: -OO)
    for f in steplog.FIELDS:
        assert steplog.FIELD_DOC.count(f"\n    {f}: ") == 1, f


def test_zeros_follow_the_documented_layout():
    """The doc's "(shape) dtype" of every field, and nothing else, builds the zero log."""
    assert set(steplog.LAYOUT) == set(steplog.FIELDS)
    z = steplog.zeros(3, 7)
    assert set(z) == set(steplog.FIELDS)
    assert z["x_robot"].shape == (3, 7, 2, 3) and z["x_robot"].dtype == np.float64
    assert z["u_hlip"].shape == (3, 7, 2) and z["t_plant"].shape == (3, 7)
    assert z["valid"].dtype == bool and z["stance"].dtype == np.int32
    assert z["status"].shape == (3,) and z["A"].shape == (3, 3, 3) and z["K_gain"].shape == (3, 2, 3)
    assert steplog.STEP_FIELDS == steplog.FIELDS[:steplog.FIELDS.index("valid") + 1]


def test_alive_stops_at_the_first_invalid_step():
    v = np.array([[1, 1, 0, 1], [1, 1, 1, 1], [0, 1, 1, 1]], bool)
    np.testing.assert_array_equal(steplog.alive(v), [[1, 1, 0, 0], [1, 1, 1, 1], [0, 0, 0, 0]])


def test_s2s_residual_recovers_the_injected_w():
    """Roll x_{k+1} = A x_k + B u_k + w_k with the closed-form H-LIP A, B and known w; the
    residual returns w to float64 rounding (1e-12 on O(1) numbers)."""
    A, B = (np.asarray(m) for m in hlip.s2s_matrices(0.8, 0.3, 0.1))
    rng = np.random.default_rng(0)
    K = 12
    u = rng.normal(0, 0.2, (K, 2))
    w = rng.normal(0, 0.02, (K - 1, 2, 3))
    x = np.zeros((K, 2, 3))
    for k in range(K - 1):
        for p in range(2):
            x[k + 1, p] = A @ x[k, p] + B * u[k, p] + w[k, p]
    np.testing.assert_allclose(steplog.s2s_residual(A, B, x, u), w, atol=1e-12)


def test_heading_frame_rotation():
    """Explicit 2x2 rotations R(−θ) per sample; states (..., 2, n) and steps (..., 2) alike;
    rotating back by −θ gives the input (1e-12)."""
    rng = np.random.default_rng(1)
    th = rng.uniform(-np.pi, np.pi, 7)
    v = rng.normal(size=(7, 2, 3))
    u = rng.normal(size=(7, 2))
    R = np.stack([np.array([[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]]) for a in th])
    np.testing.assert_allclose(steplog.to_heading_frame(v, th), np.einsum("kij,kjn->kin", R, v),
                               atol=1e-12)
    np.testing.assert_allclose(steplog.to_heading_frame(u, th), np.einsum("kij,kj->ki", R, u),
                               atol=1e-12)
    back = steplog.to_heading_frame(steplog.to_heading_frame(v, th), -th)
    np.testing.assert_allclose(back, v, atol=1e-12)
