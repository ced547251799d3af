"""Invariant analysis end to end on the H-LIP plant with bounded box noise of known size.

The plant adds uniform noise δp ∈ [−a, a] (on p, and so on c) and δv ∈ [−b, b] after every
step, so the true W of w = x_{k+1} − A x_k − B u_k is the box [±a, ±a, ±b] per plane.
"""

import numpy as np
import pytest

from hlip_jax.simulation import execution
from hlip_jax.core import invariant
from hlip_jax.simulation.config import DisturbanceConfig, PathConfig, ScenarioConfig

NOISE_P, NOISE_V = 0.004, 0.02


@pytest.fixture(scope="module")
def log():
    cfgs = [ScenarioConfig(seed=i, duration=24.0,
                           path=PathConfig(shape=shape, params=dict(peak_speed=0.5)),
                           disturbance=DisturbanceConfig(noise_p=NOISE_P, noise_v=NOISE_V))
            for i, shape in enumerate(["circle", "sinusoid", "square", "cardioid"] * 4)]
    return execution.simulate(cfgs)


def test_estimated_w_converges_to_the_true_box(log):
    """The min/max box of n uniform samples misses each face by O(1/n): with 16 runs × 60 steps
    the gap must shrink as samples grow and end within 3 % of the half-width."""
    d = invariant.disturbances(log.x_robot, log.u_robot, log.valid, log.A[0], log.B[0])
    w = np.asarray(d.w)
    m = np.asarray(d.mask)
    true = np.array([NOISE_P, NOISE_P, NOISE_V])
    gaps = []
    for n_runs in (1, 4, 16):
        wp = w[:n_runs][m[:n_runs]]                       # (samples, 2, 3)
        box = invariant.estimate_w(wp[:, 0], method="box")
        half = 0.5 * (np.asarray(box.hi) - np.asarray(box.lo))
        assert np.all(half <= true + 1e-12)              # never larger than the truth
        gaps.append(np.max(1.0 - half / true))
    assert gaps[0] > gaps[-1]
    assert gaps[-1] < 0.03, gaps


def test_heldout_coverage(log):
    """W from a seeded 3/4 of the runs; the errors of the other runs lie in E (≥ 0.99)."""
    res = invariant.analyse(log.x_robot, log.u_robot, log.valid, log.e, log.A[0], log.B[0],
                            log.K_gain[0], holdout_fraction=0.25, seed=3)
    assert len(res.test) == 4 and len(res.train) == 12
    for plane in res.planes:
        assert plane.heldout.n > 100
        assert plane.heldout.outer >= 0.99, plane.heldout
        assert plane.coverage.outer == 1.0
    assert res.combined_heldout.outer >= 0.99
