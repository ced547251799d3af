"""The plant registry (hlip_jax.plants): names, errors, and each record's interface."""

import dataclasses

import pytest

from hlip_jax.simulation import config as C
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


def test_every_registered_plant_validates_through_its_own_check():
    """plants.check dispatches to the check(cfg) of the plant's CHECKS module; the Cassie
    plant's is a light module of its own, not its MJX plant module."""
    import importlib
    assert set(plants.CHECKS) == set(plants.REGISTRY)
    for name, module in plants.CHECKS.items():
        assert callable(importlib.import_module(module).check), name
        assert plants.check(C.ScenarioConfig(plant=name)) is None
    assert plants.CHECKS["cassie"] != plants.REGISTRY["cassie"]


def test_cassie_check_rejects_hlip_only_disturbances():
    cfg = C.ScenarioConfig(plant="cassie",
                           disturbance=dataclasses.replace(C.DisturbanceConfig(), noise_p=0.01))
    msg = plants.check(cfg)
    assert msg and msg.startswith("disturbance.noise_p") and "plant = 'cassie'" in msg
    assert plants.check(C.ScenarioConfig(plant="cassie")) is None
    assert plants.check(dataclasses.replace(cfg, plant="hlip")) is None


def test_cassie_check_rejects_the_fused_kernel_without_the_inverse():
    im = C.ImplConfig(qp_kernel="fused")
    msg = plants.check(C.ScenarioConfig(plant="cassie", impl=im))
    assert msg and msg.startswith("impl.qp_kernel") and "qp_linsys = 'inverse'" in msg
    ok = dataclasses.replace(im, qp_linsys="inverse")
    assert plants.check(C.ScenarioConfig(plant="cassie", impl=ok)) is None


def test_cassie_step_span_is_computed_once_per_gait():
    """Building a sweep asks every scenario for its step span; the swing profile's landing
    fraction behind it is a compiled bisection, so it must be computed once per (clearance,
    strike) and not once per scenario (1024 scenarios used to take minutes). The cached float
    is the traced function's value exactly."""
    from hlip_jax.plants.cassie import outputs
    from hlip_jax.plants.cassie import plant as cassie_plant

    cassie_plant.landing_fraction.cache_clear()
    cfgs = [C.ScenarioConfig(plant="cassie", seed=i) for i in range(40)]
    spans = {plants.load("cassie").step_span(c) for c in cfgs}
    info = cassie_plant.landing_fraction.cache_info()
    assert len(spans) == 1
    assert (info.misses, info.hits) == (1, 39)
    cc = C.CassieConfig()
    assert cassie_plant.landing_fraction(cc.clearance, cc.strike) == \
        float(outputs.landing_fraction(cc.clearance, cc.strike))
