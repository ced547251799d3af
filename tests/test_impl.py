"""Implementation profiles (hlip_jax.runtime.impl): which settings a profile fills on which backend,
that a sweep's own settings win, and that a run records what it used."""

from __future__ import annotations

import re

import pytest

from hlip_jax.runtime import impl
from hlip_jax.sweepio import runner, store, sweep

CASSIE = '[base]\nplant = "cassie"\nduration = 1.0\n[[paths]]\nshape = "line"\n'


def test_auto_is_the_gpu_profile_on_a_gpu_and_the_sweeps_own_elsewhere():
    none = frozenset()
    assert impl.resolve("auto", "cpu", none, True) == ("cpu", "cpu", {})
    gpu = impl.resolve("auto", "gpu", none, True)
    assert gpu.profile == "gpu" and gpu.settings == impl.GPU
    assert "physics" not in impl.resolve("auto", "gpu", none, False).settings
    assert impl.resolve("sweep", "gpu", none, True).settings == {}
    with pytest.raises(ValueError, match="needs a GPU backend"):
        impl.resolve("gpu", "cpu", none, True)
    with pytest.raises(ValueError, match="allowed: auto, cpu, gpu, sweep"):
        impl.resolve("fast", "gpu", none, True)


def test_fields_the_sweep_sets_win_and_the_fused_kernel_needs_the_inverse():
    sw = sweep.parse_sweep(CASSIE + '[impl]\nqp_linsys = "cholesky"\nterms = "mjx"\n')
    assert sw.impl_explicit == {"qp_linsys", "terms"}
    r = impl.resolve(sw.impl_profile, "gpu", sw.impl_explicit, True)
    c = impl.apply(list(sw.scenarios), r.settings)[0].impl
    assert (c.qp_linsys, c.qp_kernel, c.terms, c.condense, c.physics) == (
        "cholesky", "xla", "mjx", "deflated", "warp")
    hlip = sweep.parse_sweep('[[paths]]\nshape = "line"\n').scenarios
    assert impl.apply(hlip, r.settings) == list(hlip)          # no Cassie, nothing to fill
    assert sweep.parse_sweep(CASSIE, physics="warp").impl_explicit == {"physics"}


@pytest.mark.parametrize("text,frag", [
    ('[base.cassie]\nphysics = "warp"\n', "base.cassie.physics: an implementation setting; "
     "write it in the sweep's [impl] table"),
    ('[paths.overrides.cassie]\nterms = "dense"\n', "paths.0.overrides.cassie.terms: an "
     "implementation setting"),
    ('[base.impl]\ncondense = "deflated"\n', "base.impl: implementation settings belong in "
     "the sweep's [impl] table"),
    ('[grid.product]\n"impl.condense" = ["eigen", "deflated"]\n', "cannot be swept"),
    ('[grid.product]\n"cassie.condense" = ["eigen"]\n', "cannot be swept"),
    ('[impl]\ncondense = "fast"\n', "impl.condense"),
])
def test_implementation_settings_live_in_the_impl_table_only(text, frag):
    # one value per sweep, in one place: elsewhere a one-line error that says where they go
    with pytest.raises(sweep.SweepError, match=re.escape(frag)):
        sweep.parse_sweep(CASSIE + text)


def test_results_written_with_the_settings_in_cassie_still_read():
    # manifests written before the [impl] table kept the implementation fields in "cassie"
    cfg = sweep.parse_sweep(CASSIE + '[impl]\nterms = "dense"\n').scenarios[0]
    old = sweep.config_to_dict(cfg)
    old["cassie"].update(old.pop("impl"))
    assert sweep.config_from_dict(old) == cfg


@pytest.mark.parametrize("table,frag", [('[impl]\nprofile = "fast"\n', "impl.profile"),
                                        ('[impl]\nspeed = 1\n', "impl")])
def test_a_bad_impl_table_is_one_line(table, frag):
    with pytest.raises(sweep.SweepError, match=frag):
        sweep.parse_sweep(CASSIE + table)


def test_the_manifest_records_the_profile_and_gpu_is_refused_on_a_cpu(tmp_path):
    """On the CPU backend (CI's) the auto profile fills nothing and says so in the manifest;
    a sweep that asks for the GPU profile there is refused before anything runs."""
    from test_store import fake_simulate
    runner.run_sweep(sweep.parse_sweep(CASSIE), tmp_path / "a", progress=False,
                     simulate=fake_simulate)
    assert store.read_manifest(tmp_path / "a")["impl"] == {
        "profile": "cpu", "backend": "cpu", "settings": {}}
    with pytest.raises(store.StoreError, match="needs a GPU backend"):
        runner.run_sweep(sweep.parse_sweep(CASSIE + '[impl]\nprofile = "gpu"\n'),
                         tmp_path / "b", progress=False, simulate=fake_simulate)
    assert not (tmp_path / "b").exists()


def test_an_implementation_setting_on_the_hlip_plant_is_refused():
    # it would do nothing there (and change the run's identity): one line naming the field
    with pytest.raises(sweep.SweepError, match=re.escape("impl.physics: 'warp' chooses how the "
                                                         "Cassie robot is computed")):
        sweep.parse_sweep('[[paths]]\nshape = "line"\n[impl]\nphysics = "warp"\n')
    with pytest.raises(sweep.SweepError, match="impl.physics"):
        sweep.parse_sweep('[[paths]]\nshape = "line"\n', physics="warp")


def test_grid_values_that_print_alike_get_different_names():
    sw = sweep.parse_sweep('[[paths]]\nshape = "line"\n[grid.product]\n'
                           '"mpc.alpha" = [0.01, 0.01000000000000001, 0.25]\n')
    names = [c.name for c in sw.scenarios]
    assert len(set(names)) == 3 and names[0].endswith("mpc.alpha=0.01")
    assert names[2].endswith("mpc.alpha=0.25")
