"""hlip_jax.sweepio.bench: the ADMM-share estimate from two budgets (closed form)."""

import pytest

from hlip_jax.sweepio import bench


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
    assert [(x.impl.qp_loop, x.impl.physics, x.cassie.qp_max_iter) for x in c] == [("fixed", "warp", 25)] * 2
    assert bench.configs(1, 0.6)[0].impl.physics == "jax"
    assert bench.configs(1, 0.6, qp_linsys="inverse")[0].impl.qp_linsys == "inverse"
    assert bench.configs(1, 0.6)[0].impl.qp_linsys == "cholesky"
    assert bench.configs(1, 0.6, qp_kernel="fused")[0].impl.qp_kernel == "fused"
    assert bench.configs(1, 0.6)[0].impl.qp_kernel == "xla"
    # variants: every combination, the fused kernel with the inverse solve only
    v = bench._variants(["jax"], ["while"], ["cholesky", "inverse"], ["xla", "fused"], ["previous"])
    assert [(x["qp_linsys"], x["qp_kernel"]) for x in v] == [
        ("cholesky", "xla"), ("inverse", "xla"), ("inverse", "fused")]
    # the CLF-QP's starting step size: the preset's (the previous tick's) unless asked
    assert bench.configs(1, 0.6)[0].cassie.qp_rho_start == "previous"
    assert bench.configs(1, 0.6, qp_rho_start="default")[0].cassie.qp_rho_start == "default"


def test_a_cut_off_bench_keeps_what_it_measured(monkeypatch, tmp_path):
    # the timed run says when the compile and the timed run start (a run killed by a time
    # limit shows which was under way), and --json is rewritten after every row, so the rows
    # measured before a limit survive it.  The simulation is faked; the tables are real.
    import json

    import numpy as np

    from hlip_jax.presentation import cli
    from hlip_jax.simulation import execution

    heard = []
    monkeypatch.setattr(execution, "run", lambda batch, static: {"status": np.zeros(2)})
    bench.timed_run(None, None, heard.append, "b")
    assert heard[0] == "b: compile + first run started"
    assert heard[1].startswith("b: compile + first run took ") and heard[1].endswith("timed run started")

    out = tmp_path / "rows.json"
    seen = []

    def device_runs(batch, static, B, steps, devices, emit, label):
        if seen:                        # the second variant: the row of the first is on disk
            assert [r["physics"] for r in json.loads(out.read_text())] == ["jax"]
        seen.append(static.plant_settings.physics)
        return [(1, 1.0, 2.0, np.zeros(B, int), None)]

    monkeypatch.setattr(bench, "_device_runs", device_runs)
    monkeypatch.setattr(bench, "_physics_only_rate",
                        lambda B, ticks, steps, physics: {"jax": 1000.0, "warp": 500.0}[physics])
    monkeypatch.setattr(bench, "_peak_bytes", lambda devices: None)
    monkeypatch.setattr("hlip_jax.plants.cassie.warp_physics.require", lambda: None)
    assert cli.main(["bench", "--batch", "2", "--duration", "0.3", "--physics", "jax", "warp",
                     "--json", str(out)]) == 0
    assert seen == ["jax", "warp"]
    rows = json.loads(out.read_text())
    assert [r["physics"] for r in rows] == ["jax", "warp"]
    # both denominators measured in the same process; the Warp one because Warp is benchmarked
    for r in rows:
        assert r["ratio"] == pytest.approx(r["physics_steps_per_s"] / 1000.0, rel=1e-12)
        assert r["ratio_warp"] == pytest.approx(r["physics_steps_per_s"] / 500.0, rel=1e-12)
