"""Issue 52, ninth round (docs/reliability.md, "Round 9"): identify's and whull's files
replace a link rather than write through it, --out through a link and '..', a .lock that is a
directory, a SCENARIO that is both an index and a name, a docstring-free step log
(``python -OO``), and the JAX switches and test hook the CLI checks before any work.

Runs use the fake closed loop of test_store.py (``HLIP_SWEEP_SIMULATE``) and the H-LIP plant.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hlip_jax.core import s2s_model
from test_cli import _one_line_error, _run_ok, cli, fake_loop, tiny_sweep  # noqa: F401 (fixtures)
from test_reliability_round4 import done  # noqa: F401 (fixture: a finished tiny run)

ROOT = Path(__file__).resolve().parents[1]


def test_identify_replaces_a_dangling_link_never_writing_its_target(done, tmp_path, capsys):
    """C01: `identify -o x.npz` with x.npz a dangling link wrote the model at the link's
    target (outside); the file is now written beside it and renamed over the link."""
    target = tmp_path / "outside" / "model.npz"
    target.parent.mkdir()
    link = tmp_path / "x.npz"
    link.symlink_to(target)
    code, _, err = cli(capsys, "identify", done, "-o", link)
    assert code == 0, err
    assert not target.exists() and not link.is_symlink() and link.is_file()
    s2s_model.read(link)                    # a model file
    assert not list(tmp_path.glob(".x.npz.*"))      # no temporary file left


def test_whull_replaces_a_link_at_out(done, tmp_path, capsys):
    """C02: `whull --out w.csv` with w.csv a dangling link wrote through it (and in place);
    it is now written to a temporary file and renamed over the link."""
    target = tmp_path / "outside" / "w.csv"
    target.parent.mkdir()
    link = tmp_path / "w.csv"
    link.symlink_to(target)
    code, text, err = cli(capsys, "whull", done, "--out", link)
    assert code == 0, err
    assert not target.exists() and not link.is_symlink()
    assert link.read_text().startswith("plane,c,p,v")
    assert f'w_hull_file = "{link.resolve()}"' in text


def test_out_through_a_link_and_dotdot_writes_one_real_folder(tmp_path, tiny_sweep, capsys,
                                                              fake_loop, monkeypatch):
    """X02: `--out lnk/../o` (lnk a link to a deeper folder) created deep/o, then failed on
    cwd/o; --out is resolved once, so every file lands in deep's parent/o."""
    (tmp_path / "a" / "b").mkdir(parents=True)
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    (cwd / "lnk").symlink_to(tmp_path / "a" / "b", target_is_directory=True)
    monkeypatch.chdir(cwd)
    code, text, err = cli(capsys, "run", tiny_sweep, "--out", "lnk/../o", "--quiet",
                          "--no-report")
    assert code == 0, err
    real = tmp_path / "a" / "o"
    assert (real / "manifest.json").is_file() and (real / "summary.csv").is_file()
    assert not (cwd / "o").exists()


def test_a_lock_that_is_a_directory_is_named(done, tiny_sweep, capsys, fake_loop):
    """R20: a stray `mkdir DIR/.lock` gave "Is a directory; the directory must be writable";
    the message names .lock and what to do, and the results stay."""
    (done / ".lock").unlink(missing_ok=True)
    (done / ".lock").mkdir()
    before = sorted(p.name for p in (done / "chunks").iterdir())
    line = _one_line_error(*cli(capsys, "run", tiny_sweep, "--out", done, "--resume",
                                "--quiet")[::2])
    assert ".lock is a directory" in line and "remove it" in line
    assert sorted(p.name for p in (done / "chunks").iterdir()) == before


def _named_0_and_1(tmp_path, capsys) -> Path:
    p = tmp_path / "s.toml"
    p.write_text('name = "c14"\n[base]\nplant = "hlip"\nduration = 2.0\n'
                 '[[paths]]\nname = "1"\nshape = "line"\n'
                 '[[paths]]\nname = "0"\nshape = "circle"\n')
    out = tmp_path / "o"
    _run_ok(capsys, p, out)
    return out


def test_a_scenario_both_index_and_name_is_ambiguous(tmp_path, capsys, fake_loop):
    """C14: with scenarios named "1" and "0", `ticks DIR 0` took the one NAMED "0" (index 1)
    without a word; it is refused as ambiguous, and name:0 / index:0 choose."""
    from hlip_jax.presentation import cli as cli_mod
    from hlip_jax.sweepio import store
    out = _named_0_and_1(tmp_path, capsys)
    for cmd in ("ticks", "render"):
        line = _one_line_error(*cli(capsys, cmd, out, "0")[::2])
        assert "ambiguous" in line and "name:0" in line and "index:0" in line
    man = store.read_manifest(out)
    pick = cli_mod._scenario_index       # noqa: SLF001 (the one parser of SCENARIO)
    assert pick(out, man, "name:0") == 1 and pick(out, man, "index:0") == 0
    assert pick(out, man, "index:1") == 1 and pick(out, man, "name:1") == 0
    for bad in ("index:2", "name:2", "2"):
        with pytest.raises(cli_mod.UserError, match="SCENARIO"):
            pick(out, man, bad)
    code, text, _ = cli(capsys, "ticks", "--help")
    assert "index:N" in " ".join(text.split())


def test_the_step_log_needs_no_docstrings():
    """E05: under PYTHONOPTIMIZE=2 (docstrings removed) steplog parsed its own docstring:
    AttributeError on every command.  The field list is a constant."""
    env = dict(os.environ, PYTHONOPTIMIZE="2")
    r = subprocess.run([sys.executable, "-c", "from hlip_jax.core import steplog as s; "
                        "print(len(s.LAYOUT), s.LAYOUT['w'], s.zeros(2, 3)['stance'].dtype)"],
                       cwd=ROOT, env=env, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split()[0] == "25" and "int32" in r.stdout


@pytest.mark.parametrize("var, value, allowed", [
    ("JAX_NUMPY_RANK_PROMOTION", "raise", "allow or warn"),
    ("JAX_DISABLE_JIT", "1", "0, false, no or off"),
])
def test_jax_switches_the_loop_cannot_run_with(tmp_path, tiny_sweep, var, value, allowed):
    """E03, E04: JAX_NUMPY_RANK_PROMOTION=raise gave a traceback; JAX_DISABLE_JIT=1 ran for
    hours without a word.  Both are refused before any work, naming the variable."""
    env = dict(os.environ, **{var: value})
    out = tmp_path / "o"
    r = subprocess.run([sys.executable, "-m", "hlip_jax.presentation.cli", "run", str(tiny_sweep),
                        "--out", str(out), "--quiet", "--no-report"], cwd=ROOT, env=env,
                       capture_output=True, text=True, timeout=120)
    line = _one_line_error(r.returncode, r.stderr)
    assert line.startswith(f"hlip-sweep: error: {var}=") and allowed in line
    assert not out.exists()


@pytest.mark.parametrize("spec, says", [
    ("json:loads", "the call failed"),      # a real function that cannot take configs
    ("json:JSONDecodeError.msg", "cannot load"),
    ("json:__name__", "not a function"),
    ("json", "allowed: module:function"),
])
def test_a_stray_simulate_hook_is_named(tmp_path, tiny_sweep, capsys, monkeypatch, spec, says):
    """E06: HLIP_SWEEP_SIMULATE=json:loads gave a TypeError traceback; the test hook is
    checked (importable, callable) and a call that fails on its arguments is named."""
    monkeypatch.setenv("HLIP_SWEEP_SIMULATE", spec)
    line = _one_line_error(*cli(capsys, "run", tiny_sweep, "--out", tmp_path / "o", "--quiet",
                                "--no-report")[::2])
    assert line.startswith(f"hlip-sweep: error: HLIP_SWEEP_SIMULATE={spec}: ") and says in line


def test_a_simulate_hook_returning_no_log_is_named(tmp_path, tiny_sweep, capsys, monkeypatch):
    """E06: a hook that returns something other than a step log is named too."""
    monkeypatch.setenv("HLIP_SWEEP_SIMULATE", "builtins:len")
    line = _one_line_error(*cli(capsys, "run", tiny_sweep, "--out", tmp_path / "o", "--quiet",
                                "--no-report")[::2])
    assert "HLIP_SWEEP_SIMULATE=builtins:len: returned a value of type int, not a step log" in line
    assert json.loads((tmp_path / "o" / "manifest.json").read_text())["status"] == "incomplete"
    np.testing.assert_equal(len(list((tmp_path / "o" / "chunks").glob("*.npz"))), 0)
