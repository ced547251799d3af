"""Issue 52, eighth round (docs/reliability.md, "Round 8"): a run's identity covers the data
files its configs name, scenario names and seeds that do not depend on where the sweep lies,
figures written over links rather than through them, coverage.csv bound to its run, a manifest
whose configs were edited, and the round's misleading messages.

Runs use the fake closed loop of test_store.py (``HLIP_SWEEP_SIMULATE``) and the H-LIP plant.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from hlip_jax.sweepio import store, sweep
from test_cli import TINY, _one_line_error, _run_ok, cli, fake_loop, tiny_sweep  # noqa: F401 (fixtures)
from test_reliability_round4 import done  # noqa: F401 (fixture: a finished tiny run)

HULL = "".join(f"{pl},{c},{p},{v}\n" for pl in (1, 2)
               for c, p, v in ((0.01, 0.01, 0.05), (-0.01, 0.01, 0.05), (0.01, -0.01, 0.05),
                               (0.01, 0.01, -0.05)))
TUBE = """name = "tube8"
[base]
plant = "hlip"
duration = 4.0
[base.mpc]
robust = true
w_frame = "world"
w_shape = "hull"
{hull}
[base.disturbance]
noise_p = 0.01
noise_v = 0.05
[[paths]]
shape = "line"
[[paths]]
shape = "circle"
{grid}"""


def _tube(folder: Path, hull='w_hull_file = "w.csv"', grid="") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for name in ("w.csv", "w1.csv", "w2.csv"):
        (folder / name).write_text("plane,c,p,v\n" + HULL)
    p = folder / "s.toml"
    p.write_text(TUBE.format(hull=hull, grid=grid))
    return p


def test_a_data_file_edited_before_resume_is_refused(tmp_path, capsys, fake_loop):
    """A09: a hull W file edited between an interrupted run and its --resume was not noticed
    (the identity held its path): the chunks to come would use another W.  Its SHA-256 is
    now part of the run's identity; the resume is refused naming the field and the file."""
    sw = _tube(tmp_path / "s")
    out = tmp_path / "o"
    code, _, err = cli(capsys, "run", sw, "--out", out, "--batch", "1", "--max-chunks", "1",
                       "--no-report", "--quiet")
    assert code == 1, err
    man = json.loads((out / "manifest.json").read_text())
    hull = str(tmp_path / "s" / "w.csv")
    assert man["run_identity"]["files"] == {hull: sweep.file_digest(hull)}
    chunks = sorted(p.read_bytes() for p in (out / "chunks").iterdir())
    (tmp_path / "s" / "w.csv").write_text("plane,c,p,v\n" + HULL.replace("0.05", "0.052"))
    line = _one_line_error(*cli(capsys, "run", sw, "--out", out, "--resume", "--quiet")[::2])
    assert f"mpc.w_hull_file {hull} changed since the run" in line and "manifest.json" in line
    assert sorted(p.read_bytes() for p in (out / "chunks").iterdir()) == chunks
    code, _, err = cli(capsys, "report", out)       # the stored results, with a note
    assert f"note: {hull} changed since the run" in err, err
    (tmp_path / "s" / "w.csv").write_text("plane,c,p,v\n" + HULL)       # restored: resumes
    _run_ok(capsys, sw, out, "--resume")


def test_names_and_seeds_of_a_file_axis_do_not_depend_on_the_folder(tmp_path):
    """A25: a grid axis over mpc.w_hull_file named (and so seeded) each scenario by the
    file's absolute path: the same sweep in another folder got other seeds and results."""
    grid = '[grid.product]\n"mpc.w_hull_file" = ["w1.csv", "w2.csv"]\n'
    a = sweep.load_sweep(_tube(tmp_path / "x", hull="", grid=grid)).scenarios
    b = sweep.load_sweep(_tube(tmp_path / "y" / "deeper", hull="", grid=grid)).scenarios
    assert [c.name for c in a] == [c.name for c in b]
    assert [c.seed for c in a] == [c.seed for c in b]
    assert a[0].name == "line/mpc.w_hull_file=w1.csv" and a[0].swept["mpc.w_hull_file"] == "w1.csv"
    assert a[1].mpc.w_hull_file == str(tmp_path / "x" / "w2.csv")      # the file read
    assert type(a[1].mpc.w_hull_file) is str


def test_a_figure_that_is_a_link_is_replaced_not_written_through(done, tmp_path, capsys):
    """B05: a symbolic link inside figures/ made `report` write the link's target outside
    --out.  Every figure is written to a temporary file and renamed over the link."""
    code, _, err = cli(capsys, "report", done)
    assert code == 0, err
    fig = sorted((done / "figures").glob("*.png"))[0]
    victim = tmp_path / "victim.png"
    victim.write_text("precious")
    fig.unlink()
    fig.symlink_to(victim)
    code, _, err = cli(capsys, "report", done)
    assert code == 0, err
    assert victim.read_text() == "precious"
    assert not fig.is_symlink() and fig.read_bytes().startswith(b"\x89PNG")


def test_a_coverage_table_of_another_run_is_refused_or_rewritten(done, tmp_path, capsys,
                                                                 fake_loop):
    """B06/B07: a coverage.csv copied from another run was read by `wbox` and `report` as this
    run's.  Each row now names its run (the manifest's config_hash): `wbox` refuses it in one
    line naming the command that rewrites it; `report` rewrites it from this run and says so."""
    other_sweep = tmp_path / "longer.toml"
    other_sweep.write_text(TINY.replace("duration = 4.0", "duration = 5.0"))
    other = tmp_path / "other"
    _run_ok(capsys, other_sweep, other)
    own = (done / "coverage.csv").read_bytes()
    assert b"sha256:" + store.read_manifest(done)["config_hash"].encode() in own
    (done / "coverage.csv").write_bytes((other / "coverage.csv").read_bytes())
    line = _one_line_error(*cli(capsys, "wbox", done)[::2])
    assert "coverage.csv: written by another run" in line
    assert f"hlip-sweep coverage {done}" in line
    code, _, err = cli(capsys, "report", done)
    assert code == 0, err
    assert "coverage.csv: written by another run" in err and "rewritten" in err
    assert (done / "coverage.csv").read_bytes() == own


def test_a_scenario_renamed_in_the_manifest_is_refused(done, capsys):
    """D05: a configs[i].name edited in manifest.json (summary.csv deleted) relabelled the
    stored results.  The manifest's configs are checked against its config_hash."""
    p = done / "manifest.json"
    man = json.loads(p.read_text())
    man["configs"][0]["name"] = "renamed"
    p.write_text(json.dumps(man))
    (done / "summary.csv").unlink()
    line = _one_line_error(*cli(capsys, "report", done)[::2])
    assert "manifest.json: damaged manifest: its configs do not match its config_hash" in line
    assert not (done / "summary.csv").exists()


def test_an_unencodable_path_is_printed_escaped(tmp_path):
    """C07: with PYTHONIOENCODING=ascii, printing a path holding 'ü' raised
    UnicodeEncodeError (after the results were written); it is now printed escaped."""
    folder = tmp_path / "oü"
    folder.mkdir()
    (folder / "s.toml").write_text(TINY)
    env = dict(os.environ, PYTHONIOENCODING="ascii")
    r = subprocess.run([sys.executable, "-m", "hlip_jax", "show", str(folder / "s.toml")],
                       capture_output=True, env=env, timeout=120)
    assert r.returncode == 0, r.stderr
    assert b"Traceback" not in r.stderr and b"o\\xfc" in r.stdout


def test_a_look_alike_letter_in_a_grid_field_is_shown_escaped(tmp_path, capsys):
    """A18: 'mpc.аlpha' (Cyrillic а) was printed as itself: "unknown grid field
    'mpc.alpha'; did you mean 'mpc.alpha'?".  What is not ASCII is now escaped."""
    p = tmp_path / "s.toml"
    p.write_text(TINY.replace('"mpc.alpha"', '"mpc.\u0430lpha"'))
    line = _one_line_error(*cli(capsys, "show", p)[::2])
    assert "'mpc.\\u0430lpha'" in line and "not ASCII" in line and "did you mean 'mpc.alpha'" in line
    assert "\u0430" not in line


def test_a_skip_past_every_step_names_the_option(done, capsys):
    """B12: `s2s --skip 1000000` said "scenarios: 0 usable step pairs"; it names --skip."""
    for cmd in (["s2s", done], ["identify", done, "-o", done.parent / "m.npz"]):
        line = _one_line_error(*cli(capsys, *cmd, "--skip", "1000000")[::2])
        assert line.startswith("hlip-sweep: error: --skip: 1000000 leaves no usable step pairs")
        assert "steps" in line


def test_wbox_of_runs_without_samples_names_the_warmup(tmp_path, capsys, fake_loop):
    """B19: `wbox` of runs whose every step is warm-up advised gain.with_position = true
    (already set); it now says there are no samples after the warm-up."""
    p = tmp_path / "s.toml"
    p.write_text(TINY + "\n[analysis]\nwarmup = 1000\n")
    out = tmp_path / "o"
    _run_ok(capsys, p, out)
    line = _one_line_error(*cli(capsys, "wbox", out)[::2])
    assert "no disturbance samples after the warm-up" in line and "the warm-up is 1000" in line
    assert "with_position" not in line


def test_a_cache_inside_out_is_refused_before_anything_is_made(tmp_path, tiny_sweep, capsys,
                                                               fake_loop, monkeypatch):
    """C04: HLIP_JAX_CACHE_DIR=OUT/cache made the run create the cache, then refuse --out for
    holding it.  It is refused first, naming the variable; nothing is created."""
    out = tmp_path / "o"
    monkeypatch.setenv("HLIP_JAX_CACHE_DIR", str(out / "cache"))
    line = _one_line_error(*cli(capsys, "run", tiny_sweep, "--out", out, "--quiet")[::2])
    assert f"HLIP_JAX_CACHE_DIR={out / 'cache'} lies inside --out {out}" in line
    assert not out.exists()
    line = _one_line_error(*cli(capsys, "run", tiny_sweep, "--out", out, "--compile-cache",
                                out / "c", "--quiet")[::2])
    assert "--compile-cache" in line and not out.exists()


def test_bench_checks_its_json_destination_first(tmp_path, capsys, monkeypatch):
    """B16: `bench --json /missing/dir/b.json` benchmarked first and failed when writing."""
    from hlip_jax.sweepio import bench

    def never(*a, **k):
        raise AssertionError("the benchmark ran")

    monkeypatch.setattr(bench, "closed_loop", never)
    target = tmp_path / "missing" / "b.json"
    line = _one_line_error(*cli(capsys, "bench", "--json", target)[::2])
    assert f"--json {target}: the folder {target.parent} does not exist" in line
    line = _one_line_error(*cli(capsys, "bench", "--json", tmp_path)[::2])
    assert "a directory" in line


def test_a_keep_out_disc_over_the_start_is_refused():
    """A13: an obstacle whose radius misses the path's start but whose radius + margin (the
    disc the MPC keeps the COM out of) covers it is refused, naming the obstacle and the margin
    (it ran with status qp_failed before); the same disc with a smaller margin is accepted."""
    text = ('name = "a13"\n[base]\nplant = "hlip"\nduration = 2.0\n[[paths]]\nshape = "line"\n'
            '[[paths.overrides.obstacles]]\nx = 0.0\ny = 0.5\nradius = 0.3\nmargin = {m}\n')
    with pytest.raises(sweep.SweepError) as err:
        sweep.parse_sweep(text.format(m=0.3))
    assert "obstacles.0" in str(err.value) and "margin 0.3 m" in str(err.value)
    assert len(sweep.parse_sweep(text.format(m=0.1)).scenarios) == 1


def test_identify_checks_its_output_folder_before_fitting(done, capsys, monkeypatch):
    """B09: `identify -o MISSING/m.npz` fitted first and failed writing; the folder is now
    checked before any work (the fit is replaced by one that fails if called)."""
    from hlip_jax.core import s2s_model

    def no_fit(*a, **k):
        raise AssertionError("the fit ran")
    monkeypatch.setattr(s2s_model, "fit", no_fit)
    line = _one_line_error(*cli(capsys, "identify", done, "-o", done.parent / "no" / "m.npz")[::2])
    assert "-o" in line and "does not exist" in line
