"""One compile per sweep, and sharding the scenario axis over several devices.

The multi-device test runs in a subprocess with ``--xla_force_host_platform_device_count=4``
(the flag must be set before JAX starts), so it exercises the same ``NamedSharding`` path a
multi-GPU machine takes.
"""

import json
import os
import subprocess
import sys
import textwrap


import pytest

from hlip_jax import rollout, runner, store, sweep

SMALL_SWEEP = textwrap.dedent("""
    name = "scale-test"
    [base]
    duration = 3.0
    [base.path]
    peak_speed = 0.4
    [[paths]]
    shape = "circle"
    [[paths]]
    shape = "sinusoid"
    [[paths.overrides.obstacles]]
    x = 1.0
    y = 0.4
    radius = 0.2
    [[paths]]
    shape = "line"
    [paths.overrides]
    duration = 2.0
    [grid.product]
    "gain.type" = ["deadbeat", "lqr"]
""")


def test_one_compile_per_sweep(tmp_path):
    """Chunks with different obstacle counts and durations still share one compiled loop:
    the first chunk compiles, later chunks hit the cache."""
    sw = sweep.parse_sweep(SMALL_SWEEP, source="scale-test.toml")
    assert len(sw.scenarios) == 6
    before = rollout.compiled_loops()
    res = runner.run_sweep(sw, tmp_path / "out", batch=2, progress=False, with_coverage=False)
    assert res.complete and res.chunks_run == 3
    assert rollout.compiled_loops() - before == 1


SHARDED = textwrap.dedent("""
    import os, json, sys
    os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=4"
    import jax
    jax.config.update("jax_enable_x64", True)
    import numpy as np
    from hlip_jax import rollout
    from hlip_jax.config import PathConfig, ScenarioConfig
    cfgs = [ScenarioConfig(duration=3.0, seed=i, path=PathConfig(shape=s, params=dict(peak_speed=v)))
            for i, (s, v) in enumerate([("circle", 0.3), ("line", 0.5), ("square", 0.4),
                                        ("sinusoid", 0.6), ("cardioid", 0.5)])]
    assert len(jax.devices()) == 4
    batch, _ = rollout.build(cfgs + [cfgs[-1]] * 3)
    placed = rollout.place(batch, rollout.scenario_sharding())
    devs = {d.id for d in placed.x0.sharding.device_set}
    multi = rollout.simulate(cfgs)
    single = rollout.simulate(cfgs, devices=jax.devices()[:1])
    diff = float(np.nanmax(np.abs(multi.x_robot - single.x_robot)))
    print(json.dumps({"devices": sorted(devs), "diff": diff, "S": int(multi.x_robot.shape[0])}))
""")


@pytest.mark.timeout(600)
def test_sharded_over_four_devices():
    """5 scenarios on 4 (host-platform) devices: padded to 8, sharded 2 per device, and the
    result equals the single-device run to round-off (1e-9: the same float64 program, only
    partitioned)."""
    env = dict(os.environ)
    env.pop("XLA_FLAGS", None)
    out = subprocess.run([sys.executable, "-c", SHARDED], capture_output=True, text=True,
                         env=env, timeout=580)
    assert out.returncode == 0, out.stderr[-3000:]
    res = json.loads(out.stdout.strip().splitlines()[-1])
    assert res["devices"] == [0, 1, 2, 3]
    assert res["S"] == 5
    assert res["diff"] <= 1e-9
