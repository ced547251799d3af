"""The output-acceleration disturbance observer (hlip_jax.plants.cassie.observer) against
closed forms: a constant disturbance is estimated as d (1 − (1 − α)^k), the gain is the exact
discretisation of a first-order low-pass, and zero bandwidth leaves the controller's desired
accelerations exactly as they are."""

import jax.numpy as jnp
import numpy as np
import pytest

from hlip_jax.plants.cassie import observer, outputs

DT = 1e-3


def _run(d, a_model, gain, ticks):
    """Feed the observer the velocities of a double integrator whose true acceleration is
    ``a_model + d`` (rows 0..3) while the model predicts ``a_model``."""
    obs = observer.zeros(jnp.float64)
    ydot = jnp.zeros(outputs.N_OUT, jnp.float64)
    acc = jnp.zeros(outputs.N_OUT).at[:4].set(a_model + d)
    pred = jnp.zeros(outputs.N_OUT).at[:4].set(a_model)
    history = []
    for _ in range(ticks):
        obs = observer.update(obs, ydot, gain, DT)
        history.append(np.asarray(obs.d_hat))
        obs = observer.record(obs, ydot, pred)
        ydot = ydot + DT * acc
    return np.array(history)


def test_constant_disturbance_closed_form():
    """d̂_k = d (1 − (1 − α)^(k−1)) after k ticks (the first tick only primes it); float64
    differences of velocities 1e-3 apart lose ≈ 1e-13 relative, so 1e-9 holds with margin."""
    d = np.array([0.3, -0.2, 0.05, 2.6])
    a = np.array([1.0, 0.0, -3.0, -0.4])
    gain = observer.alpha(60.0, DT)
    h = _run(d, a, gain, 200)
    k = np.arange(200)
    expect = d[None, :] * (1 - (1 - gain) ** k)[:, None]
    np.testing.assert_allclose(h, expect, atol=1e-9)


def test_gain_is_exact_low_pass():
    """α = 1 − e^(−ω Δt): after t = 1/ω the estimate of a step has reached 1 − 1/e."""
    omega = 50.0
    gain = observer.alpha(omega, DT)
    assert gain == pytest.approx(1 - np.exp(-omega * DT), rel=1e-15)
    steps = int(round(1 / (omega * DT)))
    assert 1 - (1 - gain) ** steps == pytest.approx(1 - np.exp(-1), rel=1e-12)
    with pytest.raises(ValueError, match="dob_bandwidth"):
        observer.alpha(-1.0, DT)


def test_zero_bandwidth_is_inert():
    """ω_d = 0: the estimate stays exactly 0 and the desired accelerations are unchanged bit
    for bit, whatever the mismatch."""
    assert observer.alpha(0.0, DT) == 0.0
    h = _run(np.array([5.0, -5.0, 1.0, 3.0]), np.zeros(4), 0.0, 20)
    assert np.all(h == 0.0)
    des = outputs.Desired(y=jnp.arange(16.0), ydot=jnp.ones(16), yddot=jnp.linspace(-1, 1, 16),
                          R=jnp.eye(3), mask=jnp.ones(16))
    out = observer.compensate(des, observer.zeros(jnp.float64))
    assert np.array_equal(np.asarray(out.yddot), np.asarray(des.yddot))


def test_compensation_acts_on_pelvis_and_height_rows_only():
    des = outputs.Desired(y=jnp.zeros(16), ydot=jnp.zeros(16), yddot=jnp.zeros(16),
                          R=jnp.eye(3), mask=jnp.ones(16))
    obs = observer.zeros(jnp.float64)._replace(d_hat=jnp.array([1.0, 2.0, 3.0, 4.0]))
    out = np.asarray(observer.compensate(des, obs).yddot)
    np.testing.assert_array_equal(out[:4], [-1.0, -2.0, -3.0, -4.0])
    assert np.all(out[4:] == 0.0)
