"""Issue 52, tenth round (docs/reliability.md, "Round 10"): a NUL in a path a sweep names, a
child's [analysis] merged key by key, a CPU pool size XLA would stall on, standard output that
cannot be written, long paths in messages, a manifest's config_hash deleted or of the wrong
type, a chunk that is no zip archive, a directory where a file is written, coverage.csv that
is no regular file or whose numbers were edited with its run id kept.

Runs use the fake closed loop of test_store.py (``HLIP_SWEEP_SIMULATE``) and the H-LIP plant.
"""

from __future__ import annotations

import csv
import errno
import json
import sys

import pytest

from hlip_jax.presentation.cli import main
from hlip_jax.runtime import xla_flags
from hlip_jax.sweepio import store, sweep
from test_cli import _one_line_error, _run_ok, cli, fake_loop, tiny_sweep  # noqa: F401 (fixtures)
from test_reliability_round4 import done  # noqa: F401 (fixture: a finished tiny run)

SMALL = 'name = "s"\n[base]\nplant = "hlip"\nduration = 2.0\n{base}\n[[paths]]\nshape = "line"\n'
HULL = "plane,c,p,v\n1,0.01,0.01,0.05\n2,0.01,0.01,0.05\n"


def test_a_nul_in_a_path_the_sweep_names_is_one_line(tmp_path, capsys):
    """T08: `extends = "p\\u0000.toml"` was a ValueError traceback (embedded null byte); T09: a
    NUL in w_hull_file said only "embedded null byte".  Both now name the field and what is
    allowed."""
    child = tmp_path / "c.toml"
    child.write_text('name = "c"\nextends = "p\\u0000.toml"\n')
    line = _one_line_error(*cli(capsys, "show", child)[::2])
    assert "extends" in line and "NUL" in line and "allowed" in line
    tube = tmp_path / "t.toml"
    tube.write_text(SMALL.format(base='[base.mpc]\nrobust = true\nw_shape = "hull"\n'
                                 'w_hull_file = "w\\u0000.csv"'))
    line = _one_line_error(*cli(capsys, "show", tube)[::2])
    assert "mpc.w_hull_file" in line and "NUL" in line and "allowed" in line


def test_a_child_analysis_table_is_merged_key_by_key(tmp_path):
    """T07 (round 9's S07): a child's [analysis] with only `warmup` replaced its parent's
    whole table, so the parent's `q` was lost silently; it is now merged key by key."""
    (tmp_path / "p.toml").write_text(SMALL.format(base="") + "[analysis]\nq = 0.8\nwarmup = 3\n")
    child = tmp_path / "c.toml"
    child.write_text('name = "c"\nextends = "p.toml"\n[analysis]\nwarmup = 2\n')
    got = sweep.load_sweep(child).analysis
    assert (got.q, got.warmup) == (0.8, 2)


def test_a_pool_size_xla_would_stall_on_is_refused(capsys, monkeypatch):
    """T59: `NPROC=100000 hlip-sweep run` ran 300 s in XLA's thread start-up without a word;
    a pool size above MAX_POOL_THREADS is refused before JAX starts its backend."""
    assert xla_flags.pool_problem({"NPROC": "4096"}) is None
    assert xla_flags.pool_problem({"NPROC": "²"}) is None          # counts as unset (round 3)
    monkeypatch.setenv("NPROC", "100000")
    line = _one_line_error(*cli(capsys, "list")[::2])
    assert "NPROC='100000'" in line and "allowed: an integer from 1 to 4096" in line


class FullStream:
    """A text stream that takes nothing: every write or flush fails as /dev/full does."""

    def write(self, text):
        raise OSError(errno.ENOSPC, "No space left on device")

    def flush(self):
        raise OSError(errno.ENOSPC, "No space left on device")


def test_a_stdout_that_cannot_be_written_is_named(capsys, monkeypatch, tmp_path):
    """T35 (round 8's C09), T36: `list > /dev/full` and `show > /dev/full` said only "No space
    left on device"; `report`/`wbox` blamed the results directory.  The line now names
    standard output."""
    sw = tmp_path / "s.toml"
    sw.write_text(SMALL.format(base=""))
    for args in (["list"], ["show", str(sw)]):
        capsys.readouterr()
        monkeypatch.setattr(sys, "stdout", FullStream())
        code = main(args)
        monkeypatch.undo()
        line = _one_line_error(code, capsys.readouterr().err)
        assert "standard output" in line and "No space left on device" in line, args


def test_long_paths_are_cut_in_messages(tmp_path, tiny_sweep, capsys, fake_loop, monkeypatch):
    """T12, T43, T60: a 5,000-character w_hull_file said "file not found" (the name was too
    long) in a line of 5 kB; a 5,000-character --out likewise; HLIP_JAX_CACHE_DIR of 5,000
    characters failed the run (exit 1).  Paths are cut to 200 characters, the real reason
    given, and an unusable cache directory only turns the cache off."""
    tube = tmp_path / "t.toml"
    tube.write_text(SMALL.format(base='[base.mpc]\nrobust = true\nw_shape = "hull"\n'
                                 f'w_hull_file = "{"w" * 5000}.csv"'))
    line = _one_line_error(*cli(capsys, "show", tube)[::2])
    assert "File name too long" in line and "characters)" in line and len(line) < 600
    line = _one_line_error(*cli(capsys, "run", tiny_sweep, "--out", tmp_path / ("o" * 5000),
                                "--quiet")[::2])
    assert "--out" in line and "File name too long" in line and len(line) < 600
    monkeypatch.setenv("HLIP_JAX_CACHE_DIR", str(tmp_path / ("c" * 5000)))
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", tmp_path / "o", "--quiet",
                       "--no-report")
    assert code == 0, err
    assert "compilation cache off" in err and "File name too long" in err and len(err) < 600


def _edit_manifest(d, fn):
    p = d / "manifest.json"
    man = json.loads(p.read_text())
    fn(man)
    p.write_text(json.dumps(man))


def test_a_config_hash_deleted_or_not_a_string_is_checked(done, capsys):
    """T52: a manifest with `config_hash = 123` was read without its identity check; one with
    config_hash deleted and a scenario renamed relabelled the results (exit 0).  The first is
    refused as damaged, the second checked against the run id its chunks record."""
    (done / "summary.csv").unlink()
    _edit_manifest(done, lambda m: m.__setitem__("config_hash", 123))
    line = _one_line_error(*cli(capsys, "report", done)[::2])
    assert "manifest.json" in line and "'config_hash' is 123" in line
    run_id = store.chunks_run_id(done, {"n_scenarios": 4, "batch": 1})

    def renamed(m):
        del m["config_hash"]
        m["configs"][0]["name"] = "zzz"
    _edit_manifest(done, renamed)
    line = _one_line_error(*cli(capsys, "report", done)[::2])
    assert "do not match the run id its chunks record" in line
    assert not (done / "summary.csv").exists()

    def restored(m):
        m["configs"][0]["name"] = "circle/mpc.alpha=0.01"
    _edit_manifest(done, restored)              # the true name, no config_hash: reads as before
    assert store.read_manifest(done)["configs"][0]["name"] == "circle/mpc.alpha=0.01"
    assert isinstance(run_id, str)


def test_a_chunk_that_is_no_zip_archive_is_named_as_such(done, capsys):
    """T50: a chunk overwritten with NULs was read by np.load as a pickle, and the message
    advised `allow_pickle`; it now says the file is no .npz and how to simulate it again."""
    ch = store.chunk_path(done, 0)
    ch.write_bytes(b"\0" * ch.stat().st_size)
    line = _one_line_error(*cli(capsys, "report", done)[::2])
    assert "chunk_00000.npz" in line and "not an .npz file" in line and "--resume" in line
    assert "pickle" not in line


def test_a_directory_where_a_file_is_written_is_named(tmp_path):
    """T56: a directory in place of a figure made `report` name its temporary file
    (`.circle_steps.png.XXXX.tmp: Is a directory`); the error now names the file itself."""
    target = tmp_path / "figures" / "circle_steps.png"
    target.mkdir(parents=True)
    with pytest.raises(IsADirectoryError) as err:
        store.write_atomic(target, b"png")
    assert err.value.filename == str(target) and "remove it" in err.value.strerror
    assert [p.name for p in target.parent.iterdir()] == ["circle_steps.png"]   # no temp left


def test_a_coverage_table_that_is_no_regular_file_is_named(done, capsys):
    """T47: coverage.csv a link to /dev/zero: `wbox` said "no coverage.csv"; it now says the
    file is not a regular file and how to rewrite it (the advice given once, T49)."""
    cov = done / "coverage.csv"
    cov.unlink()
    cov.symlink_to("/dev/zero")
    line = _one_line_error(*cli(capsys, "wbox", done)[::2])
    assert "coverage.csv: not a regular file" in line
    assert line.count("hlip-sweep coverage") == 1


def test_an_edited_coverage_row_is_refused_by_wbox_and_rewritten_by_report(done, capsys):
    """Round 9's R06: coverage.csv's numbers edited by hand with its run_id kept were printed
    by `wbox`.  Each row's run cell now records a check of its cells: `wbox` refuses the
    edited line, `report` rewrites the table from the chunks and says so."""
    cov = done / "coverage.csv"
    own = cov.read_bytes()
    rows = list(csv.reader(cov.open(newline="")))
    k = rows[0].index("w_hi")
    line_no = next(i for i, r in enumerate(rows) if i and r[k]) + 1
    rows[line_no - 1][k] = "0.5 0.5 0.5"
    with cov.open("w", newline="") as fh:
        csv.writer(fh, lineterminator="\n").writerows(rows)
    line = _one_line_error(*cli(capsys, "wbox", done)[::2])
    assert f"coverage.csv: line {line_no}: its cells do not match the check" in line
    assert f"hlip-sweep coverage {done}" in line
    code, _, err = cli(capsys, "report", done)
    assert code == 0, err
    assert "do not match the check" in err and "rewritten" in err
    assert cov.read_bytes() == own


def test_a_damaged_analysis_entry_names_the_manifest_once(done, capsys):
    """T54: manifest `analysis = {"q": "x"}` gave `manifest.json: manifest.json analysis.q:
    ...` (the file named twice, no advice); it now reads as a damaged manifest with what to
    do, and removing the entry gives the defaults."""
    _edit_manifest(done, lambda m: m.__setitem__("analysis", {"q": "x"}))
    line = _one_line_error(*cli(capsys, "coverage", done)[::2])
    assert line.count("manifest.json") == 1 and "damaged manifest: analysis.q" in line
    assert "remove its 'analysis' entry" in line
    _edit_manifest(done, lambda m: m.pop("analysis"))
    code, _, err = cli(capsys, "coverage", done)
    assert code == 0, err
