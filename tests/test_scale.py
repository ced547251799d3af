"""One compile per sweep, and sharding the scenario axis over several devices.

The multi-device test runs in a subprocess with ``--xla_force_host_platform_device_count=4``
(the flag must be set before JAX starts), so it exercises the per-device loops a multi-GPU
machine, or the CLI on a multi-core CPU, runs.
"""

import json
import os
import subprocess
import sys
import textwrap


import jax
import numpy as np
import pytest

from hlip_jax.simulation import execution
from hlip_jax.sweepio import runner, store, sweep
from hlip_jax.simulation.config import PathConfig, ScenarioConfig

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
    before = execution.compiled_loops()
    res = runner.run_sweep(sw, tmp_path / "out", batch=2, progress=False, with_coverage=False)
    assert res.complete and res.chunks_run == 3
    assert execution.compiled_loops() - before == 1


SHARDED = textwrap.dedent("""
    import os, json, sys
    os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=4"
    os.environ["PJRT_NPROC"] = "8"
    import jax
    jax.config.update("jax_enable_x64", True)
    import numpy as np
    from pathlib import Path
    from hlip_jax.runtime import progress, trace_cache
    from hlip_jax.simulation import arrays, execution
    from hlip_jax.simulation.config import PathConfig, ScenarioConfig
    trace_cache.enable(Path(sys.argv[1]))
    cfgs = [ScenarioConfig(duration=3.0, seed=i, path=PathConfig(shape=s, params=dict(peak_speed=v)))
            for i, (s, v) in enumerate([("circle", 0.3), ("line", 0.5), ("square", 0.4),
                                        ("sinusoid", 0.6), ("cardioid", 0.5)])]
    assert len(jax.devices()) == 4
    batch, _ = arrays.build(cfgs + [cfgs[-1]] * 3)
    placed = execution.place(batch, execution.scenario_sharding())
    devs = {d.id for d in placed.x0.sharding.device_set}
    multi = execution.simulate(cfgs)
    with progress.listening(lambda k, n: None):          # the segmented loop
        segmented = execution.simulate(cfgs)
    whole, start, segment = execution._programs(placed.x0.sharding.mesh)
    single = execution.simulate(cfgs, devices=jax.devices()[:1])
    diff = float(np.nanmax(np.abs(multi.x_robot - single.x_robot)))
    print(json.dumps({"devices": sorted(devs), "diff": diff, "S": int(multi.x_robot.shape[0]),
                      "segmented_diff": float(np.nanmax(np.abs(segmented.x_robot
                                                               - multi.x_robot))),
                      "traced": whole._cache_size() + segment._cache_size(),
                      "stored": trace_cache.loaded(whole.__name__)
                                + trace_cache.loaded(segment.__name__),
                      "x": np.nan_to_num(multi.x_robot).tolist()}))
""")


def _sharded_run(cache):
    env = dict(os.environ)
    env.pop("XLA_FLAGS", None)
    out = subprocess.run([sys.executable, "-c", SHARDED, str(cache)], capture_output=True,
                         text=True, env=env, timeout=280)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_sharded_over_four_devices(tmp_path):
    """5 scenarios on 4 (host-platform) devices: padded to 8, 2 per device, each device
    running its own scenarios' loop.  The result equals the single-device run to round-off
    (1e-9: the same float64 loop on a batch of 2 instead of 8), so do the whole-run and
    segmented loops (different programs, the same arithmetic), and a second process runs the programs the trace cache stored
    (bit for bit the same numbers, nothing traced)."""
    first = _sharded_run(tmp_path / "traces")
    assert first["devices"] == [0, 1, 2, 3]
    assert first["S"] == 5
    assert first["diff"] <= 1e-9
    assert first["segmented_diff"] <= 1e-9
    assert first["stored"] == 2
    second = _sharded_run(tmp_path / "traces")
    assert second["traced"] == 0 and second["stored"] == 2
    assert second["x"] == first["x"]


class Other:
    """A CPU device of another process (for the pool check)."""
    platform = "cpu"
    process_index = 1


def test_a_cpu_pool_no_larger_than_the_devices_is_refused(monkeypatch):
    """jaxlib 0.10 with as many CPU devices as pool threads can hang (hlip_jax.runtime.xla_flags):
    the split is refused with the remedy named; one more thread, or jaxlib 0.11, passes."""
    class Mesh:
        size = 2
        devices = np.array([jax.devices("cpu")[0]] * 2)

    class Elsewhere:       # two devices of this process, two of another
        size = 4
        devices = np.array([jax.devices("cpu")[0]] * 2 + [Other()] * 2)
    monkeypatch.setattr(execution, "_jaxlib_version", lambda: (0, 10))
    monkeypatch.delenv("NPROC", raising=False)
    monkeypatch.setenv("PJRT_NPROC", "2")
    with pytest.raises(RuntimeError, match="PJRT_NPROC=4"):
        execution._check_cpu_pool(Mesh())
    with pytest.raises(RuntimeError, match="2 CPU devices of this process"):
        execution._check_cpu_pool(Elsewhere())
    monkeypatch.setenv("PJRT_NPROC", "3")
    execution._check_cpu_pool(Mesh())
    execution._check_cpu_pool(Elsewhere())
    monkeypatch.setenv("PJRT_NPROC", "2")
    monkeypatch.setattr(execution, "_jaxlib_version", lambda: (0, 11))
    execution._check_cpu_pool(Mesh())


DISPATCHED = textwrap.dedent("""
    import json, os, sys
    import jax
    jax.config.update("jax_enable_x64", True)
    if len(sys.argv) > 2:                  # process id and coordinator port of a two-process run
        jax.distributed.initialize(f"localhost:{sys.argv[2]}", 2, int(sys.argv[1]))
    import numpy as np
    from hlip_jax.runtime import progress
    from hlip_jax.simulation import arrays, execution
    from hlip_jax.simulation.config import PathConfig, ScenarioConfig
    cfgs = [ScenarioConfig(duration=3.0, seed=i, path=PathConfig(shape=s, params=dict(peak_speed=v)))
            for i, (s, v) in enumerate([("circle", 0.3), ("line", 0.5), ("square", 0.4)])]
    whole = execution.simulate(cfgs, spread="dispatch")
    with progress.listening(lambda k, n: None):          # the segmented loop
        segmented = execution.simulate(cfgs, spread="dispatch")
    print(json.dumps({"devices": len(jax.devices()), "x": np.nan_to_num(whole.x_robot).tolist(),
                      "x_seg": np.nan_to_num(segmented.x_robot).tolist(),
                      "status": whole.status.tolist()}))
""")


def _dispatched(args: list, xla_flags: str, port=None) -> subprocess.Popen:
    env = dict(os.environ, JAX_PLATFORMS="cpu", XLA_FLAGS=xla_flags, PJRT_NPROC="4")
    return subprocess.Popen([sys.executable, "-c", DISPATCHED, *args], env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def _result(p: subprocess.Popen) -> dict:
    out, err = p.communicate(timeout=280)
    assert p.returncode == 0, err[-3000:]
    return json.loads(out.strip().splitlines()[-1])


def _single_device():
    cfgs = [ScenarioConfig(duration=3.0, seed=i, path=PathConfig(shape=s, params=dict(peak_speed=v)))
            for i, (s, v) in enumerate([("circle", 0.3), ("line", 0.5), ("square", 0.4)])]
    return execution.simulate(cfgs, devices=jax.devices()[:1])


@pytest.mark.timeout(300)
def test_blocks_dispatched_over_two_devices_equal_one_device(float64):
    """The GPUs' way of sharing a batch (execution.spread_of: one block per device, each device
    running the one-device program, dispatched together), on two CPU devices of one process:
    3 H-LIP scenarios padded to 4, two per device; whole-run and segmented loops equal the
    one-device run to 1e-9 (the same float64 loop on a batch of 2 instead of 3)."""
    got = _result(_dispatched([], "--xla_force_host_platform_device_count=2"))
    single = _single_device()
    assert got["devices"] == 2
    for k in ("x", "x_seg"):
        assert np.max(np.abs(np.asarray(got[k]) - np.nan_to_num(single.x_robot))) <= 1e-9, k
    assert got["status"] == single.status.tolist()


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_blocks_dispatched_over_two_processes_equal_one_device(float64):
    """The same over two processes of one CPU device each (jax.distributed on this host):
    each process runs its own block and the blocks are gathered in order; both processes
    return the whole batch, equal to the one-device run to 1e-9."""
    import socket
    with socket.socket() as s:
        s.bind(("localhost", 0))
        port = str(s.getsockname()[1])
    procs = [_dispatched([str(i), port], "--xla_force_host_platform_device_count=1")
             for i in (0, 1)]
    got = [_result(p) for p in procs]
    single = _single_device()
    for g in got:
        assert g["devices"] == 2
        for k in ("x", "x_seg"):
            assert np.max(np.abs(np.asarray(g[k]) - np.nan_to_num(single.x_robot))) <= 1e-9, k
        assert g["status"] == single.status.tolist()
