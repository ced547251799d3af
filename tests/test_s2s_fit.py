"""hlip_jax.core.s2s_fit: the least-squares S2S map against the exact H-LIP plant, whose map is
known in closed form (hlip.s2s_matrices at the plant's own z0, T_SSP, T_DSP)."""

import numpy as np
import pytest

from hlip_jax.simulation import execution
from hlip_jax.core import hlip, s2s_fit
from hlip_jax.simulation.config import DisturbanceConfig, PathConfig, ScenarioConfig


def _log(dist: DisturbanceConfig, seeds=(1, 2, 3)):
    cfgs = [ScenarioConfig(plant="hlip", seed=s, duration=15.0, disturbance=dist,
                           path=PathConfig(shape="line", params=dict(peak_speed=0.4, length=8.0)))
            for s in seeds]
    return cfgs, execution.simulate(cfgs)._asdict()


def test_fit_recovers_the_plants_own_map_exactly(float64):
    # a plant whose LIP is taller and slower than the planner's (mismatch) and whose steps land
    # off target (placement error: the excitation): x_{k+1} = A_r x_k + B_r u_k holds exactly
    # with the executed steps, so the fit returns A_r, B_r to rounding (1e-8 allowed: float64
    # closed-form integration and a least-squares solve of a few hundred rows) and zero offsets
    dist = DisturbanceConfig(step_error=0.05, z0=0.95, t_ssp=0.33, t_dsp=0.08)
    cfgs, log = _log(dist)
    f = s2s_fit.fit(log)
    A_r, B_r = (np.asarray(a) for a in hlip.s2s_matrices(0.95, 0.33, 0.08, with_position=False))
    assert f.n > 80 and np.all(f.rank == 5)
    for j in range(2):
        np.testing.assert_allclose(f.A[j], A_r, atol=1e-8)
        np.testing.assert_allclose(f.B[j], B_r, atol=1e-8)
        np.testing.assert_allclose(f.offset[j], 0.0, atol=1e-8)
    assert np.all(f.rms < 1e-9)
    # and it differs from the planner's H-LIP (z0 0.8, T 0.3 / 0.1 by default), which the
    # step log's A, B are: the fit sees the mismatch
    A_h, B_h = s2s_fit.hlip_rows(log["A"][0], log["B"][0])
    assert np.abs(f.B[1, 1] - B_h[1]) > 0.1 and np.abs(f.A[0] - A_h).max() > 0.05


def test_held_out_residuals_vanish_under_the_fit_and_not_under_the_hlip(float64):
    """The mismatched plant fitted on two seeds: a third seed's residuals under the fit are
    rounding (1e-8), under the planner's H-LIP they are the mismatch (above 1e-3 m/s RMS)."""
    dist = DisturbanceConfig(step_error=0.05, z0=0.95, t_ssp=0.33, t_dsp=0.08)
    _, log = _log(dist)
    model = s2s_fit.fit(log, [0, 1])
    r_fit = s2s_fit.residuals(log, [2], model)
    r_h = s2s_fit.residuals(log, [2], None, hlip=s2s_fit.hlip_rows(log["A"][0], log["B"][0]))
    assert r_fit.shape == r_h.shape and r_fit.shape[0] > 20
    assert np.abs(r_fit).max() < 1e-8
    assert np.sqrt(np.mean(r_h[:, :, 1] ** 2)) > 1e-3


def test_fit_with_additive_noise_stays_within_its_sampling_error(float64):
    # uniform S2S noise of half-width 0.01 m / 0.05 m/s on top: least squares is unbiased, so
    # every coefficient lies within 4 of its own standard errors of the truth (σ² from the
    # residuals, (XᵀX)⁻¹ from the regressors: OLS's textbook error), and the residual RMS is
    # the noise's own, half-width / √3 (±30 %)
    dist = DisturbanceConfig(step_error=0.05, noise_p=0.01, noise_v=0.05)
    cfgs, log = _log(dist, seeds=(4, 5, 6, 7))
    f = s2s_fit.fit(log)
    X, _ = s2s_fit.pairs(log, range(len(cfgs)))
    A_h, B_h = s2s_fit.hlip_rows(log["A"][0], log["B"][0])      # plant = planner here
    for j in range(2):
        cov = np.linalg.inv(X[:, j].T @ X[:, j])
        for r in range(2):                                      # rows p+, v+
            se = np.sqrt(np.diag(cov)[:3]) * f.rms[j, r]
            err = np.r_[f.A[j, r] - A_h[r], f.B[j, r] - B_h[r]]
            assert np.all(np.abs(err) < 4 * se), (j, r, err, se)
        np.testing.assert_allclose(f.rms[j], np.array([0.01, 0.05]) / np.sqrt(3), rtol=0.3)


def test_too_few_steps_is_a_clear_error():
    log = {"valid": np.zeros((1, 6), bool), "x_robot": np.zeros((1, 6, 2, 3)),
           "u_robot": np.zeros((1, 6, 2)), "ref_heading": np.zeros((1, 6)),
           "stance": np.zeros((1, 6), np.int32)}
    with pytest.raises(ValueError, match="scenarios: 0 usable step pairs"):
        s2s_fit.fit(log)
