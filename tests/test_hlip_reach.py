"""The H-LIP plant with a legged robot's reach (``disturbance.step_limits``) and Cassie sweeps
run on the H-LIP plant with their gait preset (a like-for-like comparison)."""

import dataclasses

import numpy as np
import pytest

from hlip_jax.simulation import execution
from hlip_jax.core import steplog
from hlip_jax.sweepio import sweep
from hlip_jax.simulation import config as C

LINE = C.PathConfig(shape="line", params=dict(peak_speed=0.5, length=10.0))


def _cfg(limits: bool, cassie=C.CassieConfig(), pushes=()):
    return C.ScenarioConfig(path=LINE, duration=12.0, cassie=cassie,
                            disturbance=C.DisturbanceConfig(step_limits=limits, pushes=pushes))


def _width(log, i):
    """Executed step widths across the heading, signed towards the swing foot's side [m], from
    step 1 on (step 0 is the plan's first step, placed before the plant's law acts)."""
    v = log.valid[i].copy()
    v[0] = False
    u, th = log.u_robot[i], log.ref_heading[i]
    across = -np.sin(th) * u[:, 0] + np.cos(th) * u[:, 1]
    swing = 1 - log.stance[i]            # the foot placed at SSP-_k swung in the step before
    return (np.where(swing == 0, 1.0, -1.0) * across)[v]


def test_limits_that_never_bind_change_nothing():
    """Limits wider than every step leave the closed loop bit for bit as without them: the clip
    picks the swing side right (a wrong side would fold every lateral step over)."""
    wide = dataclasses.replace(C.CassieConfig(), step_width_min=0.0, step_width_max=1.0,
                               step_length_max=1.0)
    log = execution.simulate([_cfg(False), _cfg(True, wide)])
    assert log.status.tolist() == [steplog.STATUS_OK] * 2
    np.testing.assert_array_equal(log.u_robot[0], log.u_robot[1])
    np.testing.assert_array_equal(log.x_robot[0], log.x_robot[1])


def test_a_push_towards_the_stance_side_meets_the_width_bounds():
    """A 200 N push across the path: without limits the law asks for steps outside Cassie's
    swing-target bounds (a crossing or an over-wide step); with them every executed step lies
    in [width_min, width_max] (exact: the clip is the last thing applied) and some step sits on
    a bound."""
    push = (C.PushConfig(time=5.0, duration=0.1, force=200.0, direction=-90.0),)
    c = C.CassieConfig()
    log = execution.simulate([_cfg(False, c, push), _cfg(True, c, push)])
    free, held = _width(log, 0), _width(log, 1)
    assert free.min() < c.step_width_min or free.max() > c.step_width_max
    assert held.min() >= c.step_width_min - 1e-12 and held.max() <= c.step_width_max + 1e-12
    on_bound = np.isclose(held, c.step_width_min) | np.isclose(held, c.step_width_max)
    assert on_bound.any()


def test_cassie_rejects_the_hlip_reach_flag():
    from hlip_jax import plants
    cfg = C.ScenarioConfig(plant="cassie", disturbance=C.DisturbanceConfig(step_limits=True))
    msg = plants.check(cfg)
    assert msg.startswith("disturbance.step_limits: true acts on the H-LIP plant only")


GAIT_SWEEP = """
name = "g"
[base]
plant = "cassie"
duration = 4.0
[base.cassie]
gait = "paper"
[[paths]]
name = "line"
shape = "line"
"""


@pytest.mark.parametrize("plant", [None, "hlip"])
def test_a_named_gait_fills_the_hlip_plant_too(plant):
    """``--plant hlip`` on a Cassie sweep keeps the gait's H-LIP timing, COM height and gain, so
    the two plants are compared under one planner; a sweep that names no gait is unchanged."""
    from hlip_jax.plants.cassie import gaits
    cfg = sweep.parse_sweep(GAIT_SWEEP, plant=plant).scenarios[0]
    preset = gaits.preset("paper")
    assert cfg.hlip.z0 == preset["hlip.z0"] and cfg.hlip.t_ssp == preset["hlip.t_ssp"]
    assert cfg.gain.type == preset["gain.type"] and cfg.gain.r == preset["gain.r"]
    plain = sweep.parse_sweep(GAIT_SWEEP.replace('[base.cassie]\ngait = "paper"\n', "")
                              .replace('plant = "cassie"', 'plant = "hlip"')).scenarios[0]
    assert plain.hlip == C.HLIPConfig() and plain.gain == C.GainConfig()
