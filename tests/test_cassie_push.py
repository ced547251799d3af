"""CPU regression of push recovery on Cassie (slow tier): the paper's lateral push on its
straight line, simulated in float32 (the product's precision) through the MPC, the stepping law
and the CLF-QP; the robot must survive and come back within 0.15 m of the path.

Bound: at most 14 steps back (issue 51's worst-case acceptance; measured 13 with the paper
preset on the 2-core CPU: peak 0.43 m from the path, back in 13 steps; the median target of
10 is not met yet: docs/cassie_validation)."""

import dataclasses

import numpy as np
import pytest

from hlip_jax.simulation import execution
from hlip_jax.analysis import metrics
from hlip_jax.core import steplog
from hlip_jax.sweepio import store, sweep


@pytest.mark.slow
@pytest.mark.timeout(1200)
def test_the_paper_push_is_survived_and_recovered():
    sw = sweep.load_sweep("sweeps/paper.toml")
    cfg = next(c for c in sw.scenarios if c.name.startswith("line-push"))
    push = cfg.disturbance.pushes[0]
    assert (push.force, push.direction, push.time) == (200.0, 90.0, 10.0)
    cfg = dataclasses.replace(cfg, duration=15.0)            # 5 s after the push
    log = store.log_to_arrays(execution.simulate([cfg]), 1)
    assert int(log["status"][0]) == steplog.STATUS_OK
    m = metrics.scenario_metrics(log, 0, False, metrics.push_windows(cfg))
    assert m["push_peak_err"] > 0.15                         # the push did move it off the path
    assert np.isfinite(m["push_recovery_steps"]) and m["push_recovery_steps"] <= 14, m
