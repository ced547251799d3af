"""hlip_jax.bench: the ADMM-share estimate from two budgets (closed form)."""

import pytest

from hlip_jax import bench


@pytest.mark.parametrize("setup, per_iter", [(1.0, 0.01), (0.2, 0.05), (5.0, 1e-4)])
def test_admm_share_recovers_iteration_cost(setup, per_iter):
    # a tick that costs setup + n · per_iter: two budgets give back n · per_iter / t exactly
    t150, t25 = setup + 150 * per_iter, setup + 25 * per_iter
    share = bench.admm_share(t150, t25, 150, 25)
    assert share == pytest.approx(150 * per_iter / t150, rel=1e-12)
    assert 0 < share < 1


def test_bench_configs_carry_the_admm_budget():
    cfgs = bench.configs(4, 0.6, qp_max_iter=25)
    assert [c.cassie.qp_max_iter for c in cfgs] == [25] * 4
    assert bench.configs(1, 0.6)[0].cassie.qp_max_iter == 150
    # the CLF-QP loop and the physics implementation of a bench variant reach the configs
    c = bench.configs(2, 0.6, qp_max_iter=25, qp_loop="fixed", physics="warp")
    assert [(x.cassie.qp_loop, x.cassie.physics, x.cassie.qp_max_iter) for x in c] == [("fixed", "warp", 25)] * 2
    assert bench.configs(1, 0.6)[0].cassie.physics == "jax"
