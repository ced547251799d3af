"""The deadbeat stepping gains a Cassie scenario gets (docs/cassie_validation, "Why the classic
deadbeat gain falls"), against their closed forms.

On Cassie the ``paper`` gait preset sets ``gain.with_position = true`` (for its LQR gain), so a
sweep that sets only ``gain.type = "deadbeat"`` gets the 3-state deadbeat gain on [c, p, v];
the paper's classic H-LIP deadbeat gain on [p, v] needs ``gain.with_position = false``.  The
3-state gain's weight on c grows like 1 / T_SSP² and is 2.4 at the preset's cadence."""

from __future__ import annotations

import numpy as np
import pytest

from hlip_jax.simulation import arrays
from hlip_jax.core import hlip
from hlip_jax.sweepio import sweep
from hlip_jax.plants.cassie import gaits

PRESET = gaits.PRESETS["paper"]
Z0, T_S, T_D = PRESET["hlip.z0"], PRESET["hlip.t_ssp"], PRESET["hlip.t_dsp"]


def _cassie_gain(gain_table: str) -> np.ndarray:
    text = f"""
[base]
plant = "cassie"
duration = 2.0
[base.cassie]
gait = "paper"
[base.gain]
{gain_table}
[[paths]]
shape = "line"
"""
    return arrays.stepping_gain(sweep.parse_sweep(text).scenarios[0])


def _classic(z0, t_s, t_d, g=9.81):
    """Xiong's H-LIP deadbeat gain on [p, v]: K = [1, T_D + coth(λ T_S) / λ]."""
    lam = np.sqrt(g / z0)
    return np.array([1.0, t_d + 1.0 / (lam * np.tanh(lam * t_s))])


def _three_state(z0, t_s, t_d, g=9.81):
    """The deadbeat gain on [c, p, v] (every eigenvalue of A3 + B3 K at zero), by hand: with
    s = c - p the stance foot (s⁺ = s + u) the characteristic polynomial z³ gives
    K = [k, 1, T_D + ((C + 1) - k (C - 1)) / (λ S)],  k = 1 / (2 (C - 1) + T_D λ S)."""
    lam = np.sqrt(g / z0)
    C, S = np.cosh(lam * t_s), np.sinh(lam * t_s)
    k = 1.0 / (2.0 * (C - 1.0) + t_d * lam * S)
    return np.array([k, 1.0, t_d + ((C + 1.0) - k * (C - 1.0)) / (lam * S)])


def test_the_classic_deadbeat_gain_on_cassie_needs_with_position_false():
    K = _cassie_gain('type = "deadbeat"\nwith_position = false')
    want = _classic(Z0, T_S, T_D)
    np.testing.assert_allclose(K, np.tile(np.concatenate([[0.0], want]), (2, 1)), rtol=1e-12)
    np.testing.assert_allclose(want, [1.0, 0.5903009], atol=1e-7)
    A, B = (np.asarray(x) for x in hlip.s2s_matrices(Z0, T_S, T_D, with_position=False))
    Acl = A + np.outer(B, want)
    np.testing.assert_allclose(Acl @ Acl, 0.0, atol=1e-12)


def test_deadbeat_alone_inherits_the_presets_three_state_design():
    K = _cassie_gain('type = "deadbeat"')
    np.testing.assert_allclose(K, np.tile(_three_state(Z0, T_S, T_D), (2, 1)), rtol=1e-9)
    np.testing.assert_allclose(K[0], [2.3750756, 1.0, 0.8635526], atol=1e-6)


@pytest.mark.parametrize("z0,t_s,t_d", [(0.864, 0.175, 0.03), (0.864, 0.4, 0.1),
                                        (0.75, 0.35, 0.05), (1.0, 0.3, 0.0)])
def test_three_state_deadbeat_closed_form(z0, t_s, t_d):
    K = np.asarray(hlip.deadbeat_gain(z0, t_s, t_d, with_position=True))
    want = _three_state(z0, t_s, t_d)
    np.testing.assert_allclose(K, want, rtol=1e-9)
    A, B = (np.asarray(x) for x in hlip.s2s_matrices(z0, t_s, t_d, with_position=True))
    Acl = A + np.outer(B, want)
    np.testing.assert_allclose(np.linalg.matrix_power(Acl, 3), 0.0, atol=1e-9)


def test_the_three_state_weight_on_c_grows_at_a_fast_cadence():
    """At the preset's T_SSP 0.175 s the gain on c is 6.4 times its value at 0.4 s, and a COM
    shift at the start of the SSP moves the step target 2.4 times as far as with the classic
    gain: ∂u/∂c = (K_c + K_p) C + K_v λ S along the LIP flow to SSP⁻."""
    k_fast = _three_state(Z0, T_S, T_D)[0]
    k_slow = _three_state(Z0, 0.4, 0.1)[0]
    assert k_fast / k_slow == pytest.approx(6.44, abs=0.01)
    lam = np.sqrt(9.81 / Z0)
    C, S = np.cosh(lam * T_S), np.sinh(lam * T_S)

    def shift(k):
        return (k[0] + k[1]) * C + k[2] * lam * S

    three, two = _three_state(Z0, T_S, T_D), np.concatenate([[0.0], _classic(Z0, T_S, T_D)])
    assert shift(three) == pytest.approx(5.80, abs=0.01)
    assert shift(two) == pytest.approx(2.42, abs=0.01)
