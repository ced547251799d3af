"""The ``hlip-sweep`` command line (hlip_jax.cli), run as a subprocess like a user would.

User errors must exit non-zero with one clear line naming the field and no traceback.  Runs
use the fake closed loop of test_store.py (``HLIP_SWEEP_SIMULATE``) except one end-to-end
run of the real H-LIP closed loop on a two-scenario, 2-second sweep (marked slow: compile).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from hlip_jax.cli import main

ROOT = Path(__file__).resolve().parent.parent
TESTS = Path(__file__).resolve().parent
BROKEN = TESTS / "sweeps_broken"


def hs(*args, cwd=None, fake=True, timeout=300):
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(TESTS), env.get("PYTHONPATH", "")])
    env["MPLBACKEND"] = "Agg"
    if fake:
        env["HLIP_SWEEP_SIMULATE"] = "test_store:fake_simulate"
    else:
        env.pop("HLIP_SWEEP_SIMULATE", None)
    return subprocess.run([sys.executable, "-m", "hlip_jax.cli", *map(str, args)], cwd=cwd or ROOT,
                          env=env, capture_output=True, text=True, timeout=timeout)


def cli(capsys, *args):
    """In-process ``hlip-sweep``: (exit code, stdout, stderr)."""
    try:
        code = main([str(a) for a in args])
    except SystemExit as ex:   # argparse: --help and usage errors
        code = ex.code
    cap = capsys.readouterr()
    return code, cap.out, cap.err


@pytest.fixture
def fake_loop(monkeypatch):
    monkeypatch.setenv("HLIP_SWEEP_SIMULATE", "test_store:fake_simulate")


def test_console_script_installed():
    script = Path(sys.executable).parent / "hlip-sweep"
    assert script.exists(), "pip install -e . declares hlip-sweep"


def test_help_subprocess():
    r = hs("--help")
    assert r.returncode == 0 and "usage: hlip-sweep" in r.stdout and "run" in r.stdout


@pytest.mark.parametrize("sub", [["run"], ["report"], ["list"], ["show"]])
def test_help_everywhere(sub, capsys):
    code, out, _ = cli(capsys, *sub, "--help")
    assert code == 0 and "usage: hlip-sweep" in out


def test_list_and_show(capsys):
    code, out, _ = cli(capsys, "list")
    assert code == 0
    for name in ("paper", "paper_hlip", "gains", "speeds", "disturbances"):
        assert name in out
    code, out, _ = cli(capsys, "show", "paper_hlip")
    assert code == 0 and "= 20" in out and "gain.type" in out
    code, out, _ = cli(capsys, "show", ROOT / "sweeps" / "speeds.toml", "--limit", "5",
                       "--scenarios")
    assert code == 0 and "limited to 5" in out and "path.turn_rate" in out


@pytest.mark.parametrize("name,field", [
    ("typo_mpc_key", "base.mpc.alhpa"),
    ("nan_alpha", "base.mpc.alpha"),
    ("zip_unequal", "grid.zip.0"),
])
def test_broken_sweeps_via_cli_subprocess(name, field, tmp_path):
    r = hs("run", BROKEN / f"{name}.toml", "--out", tmp_path / "o")
    assert r.returncode == 2, r.stderr
    assert field in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists(), "nothing is written for an invalid sweep"


@pytest.mark.parametrize("name,field", [
    ("unknown_shape", "paths.0.shape"),
    ("negative_duration", "base.duration"),
    ("grid_field_typo", "mpc.alhpa"),
    ("grid_push_index_missing", "disturbance.pushes"),
    ("empty_grid_axis", "mpc.alpha"),
])
def test_broken_sweeps_via_cli(name, field, tmp_path, capsys):
    for cmd in ("show", "run"):
        code, _, err = cli(capsys, cmd, BROKEN / f"{name}.toml",
                           *(["--out", tmp_path / "o"] if cmd == "run" else []))
        assert code == 2 and field in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_user_errors(tmp_path, capsys):
    code, _, err = cli(capsys, "report", tmp_path / "nope")
    assert code == 2 and "not found" in err
    code, _, err = cli(capsys, "run", tmp_path / "nope.toml")
    assert code == 2 and "not found" in err
    code, _, err = cli(capsys, "run", "paper", "--duration", "-3", "--out", tmp_path / "x")
    assert code == 2 and "base.duration" in err
    code, _, err = cli(capsys, "run", "paper", "--batch", "0")
    assert code == 2 and "--batch" in err
    code, _, err = cli(capsys, "run", "paper", "--plant", "atlas")
    assert code == 2 and "--plant" in err
    # bench: bad sizes are refused before anything is built or compiled
    code, _, err = cli(capsys, "bench", "--duration", "-1")
    assert code == 2 and "--duration must be > 0" in err
    code, _, err = cli(capsys, "bench", "--batch", "0")
    assert code == 2 and "--batch" in err


TINY = """
name = "clitiny"
[base]
duration = 4.0
[[paths]]
shape = "circle"
[[paths]]
shape = "line"
[grid.product]
"mpc.alpha" = [0.01, 0.1]
"""


def test_run_interrupt_resume_report(tmp_path, capsys, monkeypatch, fake_loop):
    monkeypatch.chdir(tmp_path)
    sw = tmp_path / "clitiny.toml"
    sw.write_text(TINY)
    # default --out is results/<sweep name> under the working directory
    code, _, err = cli(capsys, "run", sw, "--batch", "2", "--max-chunks", "1")
    assert code == 1 and "--resume" in err, err
    out = tmp_path / "results" / "clitiny"
    assert len(list((out / "chunks").glob("*.npz"))) == 1
    assert "scenarios" in err and "ETA" in err          # progress text
    code, _, err = cli(capsys, "run", sw)
    assert code == 2 and "already holds a run" in err
    code, stdout, err = cli(capsys, "run", sw, "--resume", "--no-report")
    assert code == 0, err
    assert "results: " in stdout and (out / "summary.csv").is_file()
    man = json.loads((out / "manifest.json").read_text())
    assert man["status"] == "complete" and man["batch"] == 2 and man["resumed_at"]
    sw.write_text(TINY.replace("0.01, 0.1", "0.01, 0.3"))
    # the refusal through a real process: one line, no traceback
    r = hs("run", sw, "--resume", cwd=tmp_path)
    assert r.returncode == 2 and "refusing to resume" in r.stderr and "Traceback" not in r.stderr
    code, stdout, _ = cli(capsys, "report", out)
    assert code == 0 and str(out / "report.html") in stdout and (out / "report.html").is_file()


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_real_closed_loop_end_to_end(tmp_path):
    """The real H-LIP closed loop through the CLI: 2 scenarios, 2 s each."""
    sw = tmp_path / "real.toml"
    sw.write_text("""
[base]
duration = 2.0
[[paths]]
shape = "line"
[grid.product]
"gain.type" = ["deadbeat", "lqr"]
""")
    r = hs("run", sw, "--out", tmp_path / "o", fake=False, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "report: " in r.stdout and str(tmp_path / "o" / "report.html") in r.stdout
    rows = (tmp_path / "o" / "summary.csv").read_text().splitlines()
    assert len(rows) == 3 and all(",ok," in row for row in rows[1:])
    assert (tmp_path / "o" / "figures" / "line_xy.png").is_file()
