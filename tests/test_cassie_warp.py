"""The Warp physics backend (``impl.physics = "warp"``, :mod:`hlip_jax.plants.cassie.warp_physics`):
the same robot stepped by MJX's Warp implementation against C MuJoCo, and the closed loop on
it against the closed loop on MJX-JAX.  Runs where warp-lang is installed (the test extra
installs it; Warp runs on the CPU too)."""

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from hlip_jax.simulation import arrays, execution
from hlip_jax.sweepio import bench
from hlip_jax.simulation.config import ImplConfig, ScenarioConfig
from hlip_jax.plants.cassie import control, model, plant, warp_physics
from hlip_jax.plants.cassie.mjx_import import mjx


def test_warp_needs_warp_lang_and_is_static(monkeypatch):
    # a missing warp-lang is a clear error naming the field and the allowed value
    monkeypatch.setattr(warp_physics, "available", lambda: False)
    cfg = ScenarioConfig(plant="cassie", impl=ImplConfig(physics="warp"))
    with pytest.raises(ValueError, match="impl.physics = 'warp' needs the warp-lang package.*'jax'"):
        plant.settings(cfg)
    monkeypatch.undo()
    pytest.importorskip("warp")
    assert plant.settings(cfg).physics == "warp"
    with pytest.raises(ValueError, match="impl.physics"):          # static: one per batch
        arrays.build([cfg, ScenarioConfig(plant="cassie")])


def test_a_warp_sweep_without_warp_lang_is_refused_before_it_runs(tmp_path, capsys, monkeypatch):
    # the sweep validator refuses it (exit 2, one line naming the field and the allowed value)
    # before a results directory exists
    from hlip_jax.presentation import cli
    from hlip_jax import plants
    monkeypatch.setattr(plants, "warp_installed", lambda: False)
    sw = tmp_path / "w.toml"
    sw.write_text('name = "w"\n[base]\nplant = "cassie"\nduration = 1.0\n[impl]\n'
                  'physics = "warp"\n[[paths]]\nshape = "line"\n')
    for argv in (["show", str(sw)], ["run", str(sw), "--out", str(tmp_path / "r")]):
        assert cli.main(argv) == 2
        err = capsys.readouterr().err
        assert "impl.physics: 'warp' needs the warp-lang package" in err and "'jax'" in err
    assert not (tmp_path / "r").exists()


def _stand_and_reference(ticks: int):
    """(Cassie, MJX-JAX float32 data at the stand keyframe, C MuJoCo's data after ``ticks``
    zero-torque control ticks of ``control.SUBSTEPS`` mj_step each)."""
    c = model.load()
    m = c.mj_model
    dm = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, dm, c.index.stand_key)
    mujoco.mj_forward(m, dm)
    d0 = jax.tree.map(lambda a: jnp.asarray(a, jnp.float32) if jnp.issubdtype(jnp.asarray(a).dtype, jnp.floating)
                      else a, mjx.put_data(m, dm, impl="jax"))
    ref = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, ref, c.index.stand_key)
    for _ in range(ticks * control.SUBSTEPS):
        mujoco.mj_step(m, ref)
    return c, d0, ref


def _warp_passive(c, d, ticks: int, robots: int):
    # the benchmark's Warp physics-only reference (hlip-sweep bench's second denominator)
    return control.zero_torque_rollout(c, d, ticks, warp_physics.base_model(c.mj_model),
                                       "warp", robots)


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_warp_physics_matches_c_mujoco():
    # 0.1 s of zero-torque motion from the stand keyframe (100 ticks of 2 substeps): Warp
    # against C MuJoCo's mj_step on the same model.  Measured 3.8e-6 in qpos, 8.4e-5 in qvel
    # (float32 Warp on the CPU; MJX-JAX in float32 is 2.3e-5 / 5.8e-4 off, the same test);
    # 5e-5 and 1e-3 allowed.  The carry stays MJX-JAX data: time and kinematics come back too.
    pytest.importorskip("warp")
    c, d0, ref = _stand_and_reference(100)
    d = jax.jit(lambda d: _warp_passive(c, d, 100, 1))(d0)
    assert np.abs(np.asarray(d.qpos) - ref.qpos).max() < 5e-5
    assert np.abs(np.asarray(d.qvel) - ref.qvel).max() < 1e-3
    assert abs(float(d.time) - ref.time) < 1e-6
    assert np.abs(np.asarray(d.geom_xpos) - ref.geom_xpos).max() < 5e-5


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_warp_batch_keeps_every_robots_contacts():
    # Warp holds one contact buffer for all worlds of a vmapped batch.  A standing Cassie has
    # 4 contacts and a one-world buffer 48, so a batch of 16 overflows it unless the buffer is
    # sized for the batch (tick.Settings.robots).  0.05 s of passive standing, 16 copies: with
    # the buffer sized for 16 every robot stays within 5e-5 of C MuJoCo (as alone, the test
    # above); sized for one robot, some robots lose their feet's contacts and sink (> 1 mm in
    # qpos after 0.05 s), which is what the sizing prevents.
    pytest.importorskip("warp")
    n, ticks = 16, 50
    c, d0, ref = _stand_and_reference(ticks)
    batch = jax.tree.map(lambda a: jnp.broadcast_to(a, (n,) + jnp.shape(a)), d0)
    run = lambda robots: jax.jit(jax.vmap(lambda d: _warp_passive(c, d, ticks, robots)))(batch)
    err = np.abs(np.asarray(run(n).qpos) - ref.qpos[None]).max(axis=1)
    assert err.max() < 5e-5, err
    # the one-robot buffer's failure, asserted so that this test shows what the sizing
    # prevents; it depends on MJWarp dropping the contacts that overflow its buffer (3.17.0)
    err_one = np.abs(np.asarray(run(1).qpos) - ref.qpos[None]).max(axis=1)
    assert err_one.max() > 1e-3, err_one


@pytest.mark.slow
@pytest.mark.timeout(1500)
def test_closed_loop_on_warp_walks_like_on_jax():
    # The shipped controller walking 3 s at 0.4 m/s with the physics stepped by MJX-JAX and
    # by Warp (the suite's float64; Warp steps in float32).  The controller is the same code on
    # both; the two physics solvers differ in their last bits and the closed loop is chaotic,
    # so the runs part slowly (in float32 sweeps: 0.4 mm after one step, 5 cm after ten).  Both
    # must walk all ten steps, stay within 5 mm of each other over the first two steps and
    # within 0.15 m (the path-tracking scale) after ten.
    pytest.importorskip("warp")
    base = bench.configs(3, 3.0)[2]
    logs = {ph: execution.simulate([dataclasses.replace(
        base, impl=dataclasses.replace(base.impl, physics=ph))]) for ph in ("jax", "warp")}
    a, b = logs["jax"], logs["warp"]
    assert int(a.status[0]) == 0 and int(b.status[0]) == 0
    n = int(a.valid[0].sum())
    assert n >= 10 and int(b.valid[0].sum()) == n
    c_a, c_b = a.x_robot[0, :n, :, 0], b.x_robot[0, :n, :, 0]
    assert np.abs(c_a[:3] - c_b[:3]).max() < 5e-3
    assert np.abs(c_a - c_b).max() < 0.15


def test_physics_override_from_the_command_line(tmp_path, capsys, monkeypatch):
    # --physics sets impl.physics of every scenario (run and show), validated like the file:
    # without warp-lang a Warp run is refused naming the field; an unknown value is exit 2
    from hlip_jax.presentation import cli
    from hlip_jax import plants
    from hlip_jax.sweepio import sweep
    monkeypatch.setattr(plants, "warp_installed", lambda: True)    # parsing only: no Warp run
    text = ('name = "o"\n[base]\nplant = "cassie"\nduration = 1.0\n[[paths]]\nshape = "line"\n'
            '[[paths]]\nname = "c"\nshape = "circle"\n[impl]\nphysics = "jax"\n')
    sw = sweep.parse_sweep(text, physics="warp")
    assert {s.impl.physics for s in sw.scenarios} == {"warp"}
    assert {s.impl.physics for s in sweep.parse_sweep(text).scenarios} == {"jax"}
    f = tmp_path / "o.toml"
    f.write_text(text)
    monkeypatch.setattr(plants, "warp_installed", lambda: False)
    assert cli.main(["run", str(f), "--physics", "warp", "--out", str(tmp_path / "r")]) == 2
    assert "impl.physics: 'warp' needs the warp-lang package" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()
    with pytest.raises(SystemExit) as exc:
        cli.main(["show", str(f), "--physics", "cuda"])
    assert exc.value.code == 2 and "--physics: invalid choice: 'cuda'" in capsys.readouterr().err
