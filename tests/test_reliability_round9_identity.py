"""Issue 52, ninth round (docs/reliability.md, "Round 9"), the run's identity: a manifest whose
``run_identity`` was removed or nulled is checked as an older run's (R04, R05), the sweep's
axes and paths that label the results are part of it (R02, R03), and so are the process
settings that change the numbers, XLA's flags and JAX's random numbers (E11, E13).

Runs use the fake closed loop of test_store.py (``HLIP_SWEEP_SIMULATE``) and the H-LIP plant.
"""

from __future__ import annotations

import json

import pytest

from hlip_jax.sweepio import runner
from test_cli import _one_line_error, cli, fake_loop, tiny_sweep  # noqa: F401 (fixtures)
from test_reliability_round4 import done  # noqa: F401 (fixture: a finished tiny run)


def _edit(done, change) -> None:
    p = done / "manifest.json"
    man = json.loads(p.read_text())
    change(man)
    p.write_text(json.dumps(man))


@pytest.mark.parametrize("identity", ["deleted", None])
def test_a_renamed_scenario_is_found_without_the_run_identity(done, capsys, identity):
    """R04, R05: with run_identity removed (or null) a renamed config was not checked; the
    manifest is now checked against the identity every run records (chunk size, precision)."""
    def change(man):
        if identity == "deleted":
            del man["run_identity"]
        else:
            man["run_identity"] = None
        man["configs"][0]["name"] = "zzz"
    _edit(done, change)
    (done / "summary.csv").unlink()
    line = _one_line_error(*cli(capsys, "report", done)[::2])
    assert "manifest.json: damaged manifest: its configs do not match its config_hash" in line


@pytest.mark.parametrize("field", ["axes", "paths"])
def test_edited_axes_or_paths_are_refused(done, capsys, field):
    """R02, R03: a manifest's axes or paths edited by hand regrouped or relabelled the report
    (a heat-map row no scenario ran, a path none walked); they are part of the identity."""
    def change(man):
        if field == "axes":
            man["axes"][0]["values"] = [[0.01], [0.5]]
        else:
            man["paths"] = ["line", "zzz"]
    _edit(done, change)
    line = _one_line_error(*cli(capsys, "report", done)[::2])
    assert "manifest.json: damaged manifest: its axes or paths do not match" in line


def _interrupted(tmp_path, tiny_sweep, capsys):
    out = tmp_path / "r"
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", out, "--batch", "1",
                       "--max-chunks", "2", "--no-report")
    assert code == 1, err
    return out


def test_a_resume_under_other_xla_flags_is_refused(tmp_path, tiny_sweep, capsys, fake_loop,
                                                   monkeypatch):
    """E13: a run resumed under XLA_FLAGS that change the numbers (fast math) mixed chunks of
    both; the user's XLA flags are part of the identity and the resume names XLA_FLAGS."""
    out = _interrupted(tmp_path, tiny_sweep, capsys)
    before = sorted(p.name for p in (out / "chunks").iterdir())
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_enable_fast_math=true")
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", out, "--resume", "--no-report")
    assert code == 2 and "XLA_FLAGS differs" in err and "fast_math" in err, err
    assert sorted(p.name for p in (out / "chunks").iterdir()) == before


def test_a_resume_with_other_random_numbers_is_refused(tmp_path, tiny_sweep, capsys, fake_loop,
                                                       monkeypatch):
    """E11: a noisy run resumed under JAX_DEFAULT_PRNG_IMPL=rbg drew its noise from another
    stream; JAX's random-number settings are part of the identity."""
    out = _interrupted(tmp_path, tiny_sweep, capsys)
    now = runner.numerics()
    monkeypatch.setattr(runner, "numerics", lambda: dict(now, prng="rbg"))
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", out, "--resume", "--no-report")
    assert code == 2 and "JAX_DEFAULT_PRNG_IMPL" in err and "rbg" in err, err
    monkeypatch.setattr(runner, "numerics", lambda: now)
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", out, "--resume", "--no-report")
    assert code == 0, err


def test_numerics_leave_out_the_device_count():
    """The CPU device count the CLI sets per machine is not a numerics setting (a run resumed
    on a machine with other cores is the same run)."""
    import os
    from hlip_jax.runtime import xla_flags
    old = os.environ.get("XLA_FLAGS")
    try:
        os.environ["XLA_FLAGS"] = f"{xla_flags.DEVICES_FLAG}=7 --xla_foo=1"
        assert runner.numerics()["xla_flags"] == ["--xla_foo=1"]
    finally:
        if old is None:
            os.environ.pop("XLA_FLAGS")
        else:
            os.environ["XLA_FLAGS"] = old


def test_an_edited_batch_is_named_and_no_chunk_is_blamed(done, capsys):
    """R01: the manifest's batch edited by hand made `report` call a good chunk "not a chunk of
    this run; remove it" (following that advice deletes a result); the batch is checked against
    the run's identity and the manifest named."""
    _edit(done, lambda man: man.update(batch=2))
    chunks = sorted(p.name for p in (done / "chunks").iterdir())
    line = _one_line_error(*cli(capsys, "report", done)[::2])
    assert "manifest.json: damaged manifest: its batch 2 is not the run's chunk size" in line
    assert "remove" not in line.replace("nothing was removed", "")
    assert sorted(p.name for p in (done / "chunks").iterdir()) == chunks
