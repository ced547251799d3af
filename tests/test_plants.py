"""The plant registry (hlip_jax.plants): names, errors, and each record's interface."""

import dataclasses

import pytest

from hlip_jax import config as C
from hlip_jax import plants


def test_unknown_plant_names_the_registered_ones():
    with pytest.raises(ValueError) as ei:
        plants.load("atlas")
    assert "'atlas'" in str(ei.value)
    for name in plants.NAMES:
        assert repr(name) in str(ei.value)


def test_config_choices_are_the_registry():
    assert C.field_spec(C.ScenarioConfig, "plant")["choices"] == plants.NAMES


def test_hlip_record_is_complete_and_named():
    p = plants.load("hlip")
    assert isinstance(p, plants.Plant) and p.name == "hlip"
    cfg = C.ScenarioConfig()
    assert p.step_span(cfg) == pytest.approx(cfg.hlip.t_ssp + cfg.hlip.t_dsp)
    assert p.settings(cfg) is None and p.step_with_log is None
    params = p.make_params(cfg, 1, 0.0)
    assert params.noise.shape == (2,)


def test_cassie_check_rejects_hlip_only_disturbances():
    cfg = C.ScenarioConfig(plant="cassie",
                           disturbance=dataclasses.replace(C.DisturbanceConfig(), noise_p=0.01))
    msg = plants.check(cfg)
    assert msg and msg.startswith("disturbance.noise_p") and "plant = 'cassie'" in msg
    assert plants.check(C.ScenarioConfig(plant="cassie")) is None
    assert plants.check(dataclasses.replace(cfg, plant="hlip")) is None
