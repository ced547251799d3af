"""Issue 52, fourth round (docs/reliability.md): results bound to the run that made them, chunk
files that are regular files, XLA flags XLA would abort on refused before JAX starts, read-only
results directories, and the fourth hostile round's cases.

Runs use the fake closed loop of test_store.py (``HLIP_SWEEP_SIMULATE``): these tests check the
command line and the store, not the dynamics.
"""

from __future__ import annotations

import csv
import os
from pathlib import Path

import numpy as np
import pytest

from hlip_jax.core import fields
from hlip_jax.sweepio import store
from hlip_jax.runtime import xla_flags
from test_cli import TINY, _one_line_error, _run_ok, cli, fake_loop, tiny_sweep  # noqa: F401 (fixtures)


@pytest.fixture
def done(tmp_path, tiny_sweep, capsys, fake_loop):
    """A finished run of the tiny sweep (4 scenarios, one chunk each), with its summary."""
    out = tmp_path / "o"
    _run_ok(capsys, tiny_sweep, out)
    return out


def _edit_cell(p: Path, line: int, column: str, value: str) -> str:
    """Set ``column`` of CSV line ``line`` (2 = the first row) to ``value``; the old cell."""
    rows = list(csv.reader(p.open(newline="")))
    k = rows[0].index(column)
    old, rows[line - 1][k] = rows[line - 1][k], value
    with p.open("w", newline="") as fh:
        csv.writer(fh, lineterminator="\n").writerows(rows)
    return old


# ------------------------------------------------------------------------------------------
# XLA_FLAGS


@pytest.mark.parametrize("value", ["abc", "²", "0", "-1", "+2", "2.0", "", "5000",
                                   "99999999999999999999"])
def test_a_device_count_xla_would_abort_on_is_refused(value):
    """`XLA_FLAGS=--xla_force_host_platform_device_count=²` (or abc, 0, ...) let JAX start and
    XLA then aborted with its whole flag listing (or the CPU backend failed to start): the
    flag is now refused before, in one line naming XLA_FLAGS and what is allowed."""
    flags = f"--xla_dump_to=/tmp/x {xla_flags.DEVICES_FLAG}={value}"
    why = xla_flags.problem(flags)
    assert why is not None and why.startswith("XLA_FLAGS: ") and "allowed: an integer" in why
    assert "\n" not in why and "\x1b" not in why
    env = {"XLA_FLAGS": flags}
    with pytest.raises(xla_flags.FlagsError) as ex:   # the CLI: one line, exit 2
        xla_flags.apply(env, cores=2)
    assert str(ex.value) == why and env == {"XLA_FLAGS": flags}     # nothing set


def test_good_xla_flags_pass_and_a_bad_boolean_is_refused():
    d, f = xla_flags.DEVICES_FLAG, xla_flags.FLAG
    for ok in ("", f"{d}=1", f"{d}=007", f"{d}=4096", f"{f}=false", f"{f}=TRUE", f,
               "--xla_dump_to=/tmp/x"):
        assert xla_flags.problem(ok) is None, ok
    assert "allowed" in xla_flags.problem(f"{f}=maybe")
    assert "allowed" in xla_flags.problem(f"{d}=2 {d}=x")       # every occurrence is checked


def test_the_cli_refuses_a_bad_device_count_in_one_line(monkeypatch, capsys):
    """xla_flags.apply printed its error and raised SystemExit(2) itself, before main's error
    handling: it now raises the CLI's usage error, which main reports (one line, exit 2)."""
    monkeypatch.setenv("XLA_FLAGS", f"{xla_flags.DEVICES_FLAG}=\x1b[31mabc")
    code, out, err = cli(capsys, "list")
    line = _one_line_error(code, err)
    assert "XLA_FLAGS" in line and "allowed" in line and "\x1b" not in line and out == ""
    assert err.count("hlip-sweep: error: ") == 1
    from hlip_jax.presentation import cli as cli_mod
    assert cli_mod.main(["list"]) == 2        # returned by main, not raised as SystemExit


# ------------------------------------------------------------------------------------------
# summary.csv bound to the chunks


@pytest.mark.parametrize("column,value", [("status", "fell"), ("final_pos_err", "0.001"),
                                          ("fail_step", "7"), ("steps", "99"),
                                          ("status", "ok\x1b[2J")])
def test_a_summary_with_edited_result_cells_is_refused(done, capsys, column, value):
    """A hand-edited status or metric cell of summary.csv was reported as written: the report
    now checks every result cell against the chunks and refuses a summary that differs, naming
    the file, the line and the column; deleted, the summary is rewritten from the chunks."""
    p = done / "summary.csv"
    good = p.read_bytes()
    old = _edit_cell(p, 3, column, value)
    assert old != value
    code, _, err = cli(capsys, "report", done)
    line = _one_line_error(code, err)
    assert f"summary.csv: line 3: column {column!r} of scenario 1 is" in line
    assert "the chunks say" in line and "delete it" in line and "\x1b" not in line
    assert not (done / "report.md").exists()
    p.unlink()
    code, _, err = cli(capsys, "report", done)
    assert code == 0, err
    assert p.read_bytes() == good


def test_a_summary_missing_a_result_column_is_refused(done, capsys):
    p = done / "summary.csv"
    rows = list(csv.reader(p.open(newline="")))
    k = rows[0].index("status")
    with p.open("w", newline="") as fh:
        csv.writer(fh, lineterminator="\n").writerows([r[:k] + r[k + 1:] for r in rows])
    code, _, err = cli(capsys, "report", done)
    assert "column 'status' is missing" in _one_line_error(code, err)


def test_an_equal_number_written_otherwise_is_accepted(done):
    p = done / "summary.csv"
    old = _edit_cell(p, 2, "final_pos_err", "x")
    _edit_cell(p, 2, "final_pos_err", f"{float(old):.17e}")     # the same float, other digits
    assert len(store.read_summary(done)) == 4


# ------------------------------------------------------------------------------------------
# chunk files are regular files


def test_a_symlinked_chunk_is_refused_by_report_and_replaced_on_resume(tmp_path, done, tiny_sweep,
                                                                        capsys):
    """A chunk that is a symbolic link to the same chunk of another run of the same identity
    was accepted (every other check passes): `report` now names it, exit 2; `--resume`
    names it and simulates the chunk again as a regular file, the link's target untouched."""
    other = tmp_path / "other"
    _run_ok(capsys, tiny_sweep, other)
    c0 = store.chunk_path(done, 0)
    target = store.chunk_path(other, 0)
    before = target.read_bytes()
    c0.unlink()
    c0.symlink_to(target)
    (done / "summary.csv").unlink()
    code, _, err = cli(capsys, "report", done)
    line = _one_line_error(code, err)
    assert "chunk_00000.npz" in line and "symbolic link" in line
    with pytest.raises(store.StoreError, match="symbolic link"):
        store.load_chunk(c0)
    assert "symbolic link" in store.chunk_problem(c0, 0, 1)
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", done, "--batch", "1", "--no-report",
                       "--resume")
    assert code == 0, err
    assert "chunk_00000.npz: a symbolic link" in err
    assert not c0.is_symlink() and c0.is_file() and target.read_bytes() == before
    assert store.chunk_problem(c0, 0, 1) is None


def test_a_fifo_or_a_directory_as_a_chunk_is_one_line(done, capsys):
    """A FIFO as a chunk blocked the reader; a directory was named only by the error of
    opening it: both are 'not a regular file', named, exit 2, without opening the FIFO."""
    c1 = store.chunk_path(done, 1)
    c1.unlink()
    os.mkfifo(c1)
    code, _, err = cli(capsys, "report", done)
    line = _one_line_error(code, err)
    assert "chunk_00001.npz: not a regular file" in line
    with pytest.raises(store.StoreError, match="not a regular file"):
        store.load_chunk(c1)
    c1.unlink()
    c1.mkdir()
    code, _, err = cli(capsys, "report", done)
    assert "chunk_00001.npz: not a regular file" in _one_line_error(code, err)


# ------------------------------------------------------------------------------------------
# read-only results directories


def _read_only(monkeypatch, root: Path) -> None:
    """Make every file and folder under ``root`` read-only for this process, as ``chmod -R
    a-w`` does for a user other than root (the tests may run as root, which writes through
    permissions): creating, opening for writing, renaming, replacing and removing anything
    under ``root`` raise PermissionError naming the path."""
    import builtins
    import errno
    import io
    import tempfile
    root = Path(os.path.abspath(root))

    def under(p) -> bool:
        return isinstance(p, (str, bytes, os.PathLike)) and \
            Path(os.path.abspath(os.fsdecode(p))).is_relative_to(root)

    def deny(p):
        raise PermissionError(errno.EACCES, "Permission denied", os.fsdecode(p))

    real = {"open": builtins.open, "os_open": os.open, "mkstemp": tempfile.mkstemp,
            "mkdir": os.mkdir, "replace": os.replace, "rename": os.rename,
            "unlink": os.unlink, "rmdir": os.rmdir}

    def open_(file, mode="r", *a, **kw):
        if under(file) and any(c in mode for c in "wax+"):
            deny(file)
        return real["open"](file, mode, *a, **kw)

    def os_open(path, flags, *a, **kw):
        if under(path) and flags & (os.O_WRONLY | os.O_RDWR | os.O_CREAT | os.O_TRUNC):
            deny(path)
        return real["os_open"](path, flags, *a, **kw)

    def mkstemp(*a, dir=None, **kw):
        if dir is not None and under(dir):
            deny(dir)
        return real["mkstemp"](*a, dir=dir, **kw)

    def one(name):
        def f(p, *a, **kw):
            if under(p) or (a and under(a[0])):
                deny(p)
            return real[name](p, *a, **kw)
        return f

    monkeypatch.setattr(builtins, "open", open_)
    monkeypatch.setattr(io, "open", open_)
    monkeypatch.setattr(os, "open", os_open)
    monkeypatch.setattr(tempfile, "mkstemp", mkstemp)
    for name in ("mkdir", "replace", "rename", "unlink", "rmdir"):
        monkeypatch.setattr(os, name, one(name))


def _files(root: Path) -> dict:
    return {p.relative_to(root): (p.read_bytes() if p.is_file() else None)
            for p in sorted(root.rglob("*"))}


@pytest.mark.parametrize("cmd", ["report", "coverage"])
def test_a_read_only_results_directory_is_one_line_and_left_as_it_was(done, capsys, monkeypatch,
                                                                      cmd):
    (done / "summary.csv").unlink()          # the report has to write it: the first write fails
    (done / "coverage.csv").unlink()
    before = _files(done)
    _read_only(monkeypatch, done)
    code, _, err = cli(capsys, cmd, done)
    line = _one_line_error(code, err)
    assert str(done) in line and "Permission denied" in line
    monkeypatch.undo()
    assert _files(done) == before


def test_a_run_into_a_read_only_directory_loses_nothing(tmp_path, tiny_sweep, capsys, fake_loop,
                                                         monkeypatch):
    """--resume into a read-only results directory: exit 2 naming --out and its lock file,
    nothing changed; a directory that turns read-only during the run: exit 1 (the run is
    incomplete) naming the path, the finished chunks kept, and --resume, once it is writable,
    ends with the chunks of an uninterrupted run."""
    ref = tmp_path / "ref"
    _run_ok(capsys, tiny_sweep, ref)
    out = tmp_path / "o"
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", out, "--batch", "1", "--no-report",
                       "--quiet", "--max-chunks", "2")
    assert code == 1, err
    before = _files(out)
    with monkeypatch.context() as m:
        _read_only(m, out)
        code, _, err = cli(capsys, "run", tiny_sweep, "--out", out, "--batch", "1",
                           "--no-report", "--quiet", "--resume")
    line = _one_line_error(code, err)
    assert f"--out {out}" in line and ".lock" in line and "Permission denied" in line
    assert _files(out) == before
    from hlip_jax.sweepio import runner
    real_verify = runner._verify_stored

    def turn_read_only(*a, **kw):            # after the stored chunks are verified
        good = real_verify(*a, **kw)
        _read_only(monkeypatch, out / "chunks")
        return good
    monkeypatch.setattr(runner, "_verify_stored", turn_read_only)
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", out, "--batch", "1", "--no-report",
                       "--quiet", "--resume")
    line = _one_line_error(code, err, expect_code=1)
    assert "Permission denied" in line and str(out / "chunks") in line and "--resume" in line
    monkeypatch.undo()
    for i in (0, 1):
        assert store.chunk_path(out, i).read_bytes() == before[Path("chunks") / f"chunk_0000{i}.npz"]
    monkeypatch.setenv("HLIP_SWEEP_SIMULATE", "test_store:fake_simulate")
    _run_ok(capsys, tiny_sweep, out, "--resume")
    for i in range(4):
        assert store.chunk_path(out, i).read_bytes() == store.chunk_path(ref, i).read_bytes()


# ------------------------------------------------------------------------------------------
# the fourth hostile round


def test_a_file_named_like_a_chunk_that_is_none_of_the_runs_is_refused(tmp_path, done, tiny_sweep,
                                                                       capsys):
    """A copy of a chunk as chunks/chunk_00099.npz (or a chunk renamed chunk_1.npz) was read
    by every reader of chunks/: the report showed its scenarios, and a chunk of another run
    holding scenario 0 replaced scenario 0's summary row.  report, the summary and the end of
    a --resume now name the stray file and say to remove it."""
    stray = done / "chunks" / "chunk_00099.npz"
    stray.write_bytes(store.chunk_path(done, 0).read_bytes())
    (done / "summary.csv").unlink()
    code, _, err = cli(capsys, "report", done)
    line = _one_line_error(code, err)
    assert "chunk_00099.npz: not a chunk of this run (4 chunks" in line and "remove it" in line
    with pytest.raises(store.StoreError, match="chunk_00099.npz: not a chunk"):
        store.write_summary(done)
    store.chunk_path(done, 3).unlink()
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", done, "--batch", "1", "--no-report",
                       "--quiet", "--resume")
    assert "chunk_00099.npz: not a chunk of this run" in _one_line_error(code, err)
    assert not (done / "summary.csv").exists()
    stray.rename(done / "chunks" / "chunk_1.npz")
    code, _, err = cli(capsys, "coverage", done)
    assert "chunk_1.npz: not a chunk of this run" in _one_line_error(code, err)
    (done / "chunks" / "chunk_1.npz").unlink()
    code, _, err = cli(capsys, "report", done)
    assert code == 0, err


def test_a_chunks_folder_that_is_a_link_is_refused(tmp_path, done, tiny_sweep, capsys):
    """chunks/ a symbolic link to another run's chunks/: --resume wrote its new chunk into the
    other run's directory (a write outside --out) and report read the other run's chunks; both
    now refuse the link in one line, the other directory untouched."""
    other = tmp_path / "other"
    _run_ok(capsys, tiny_sweep, other)
    store.chunk_path(other, 3).unlink()
    before = _files(other)
    import shutil
    shutil.rmtree(done / "chunks")
    (done / "chunks").symlink_to(other / "chunks")
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", done, "--batch", "1", "--no-report",
                       "--quiet", "--resume")
    line = _one_line_error(code, err)
    assert "chunks: a symbolic link inside the results directory" in line
    code, _, err = cli(capsys, "report", done)
    assert "chunks: a symbolic link" in _one_line_error(code, err)
    assert _files(other) == before
    (done / "chunks").unlink()
    shutil.copytree(other / "chunks", done / "chunks")
    (done / "ticks").symlink_to(other, target_is_directory=True)   # per-tick logs go there
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", done, "--batch", "1", "--no-report",
                       "--quiet", "--resume")
    assert "ticks: a symbolic link" in _one_line_error(code, err)
    assert _files(other) == before


def test_a_manifest_without_a_run_id_does_not_mix_runs(tmp_path, done, capsys):
    """With config_hash deleted from the manifest, a chunk of another run (another duration)
    was reported with the others, exit 0; the chunks are now checked against the first
    chunk's run id."""
    import json
    other = tmp_path / "other"
    sw = tmp_path / "longer.toml"
    sw.write_text(TINY.replace("duration = 4.0", "duration = 5.0"))
    _run_ok(capsys, sw, other)
    man = json.loads((done / "manifest.json").read_text())
    del man["config_hash"]
    (done / "manifest.json").write_text(json.dumps(man))
    (done / "summary.csv").unlink()
    code, _, err = cli(capsys, "report", done)                  # one run: accepted
    assert code == 0, err
    (done / "summary.csv").unlink()
    store.chunk_path(done, 2).write_bytes(store.chunk_path(other, 2).read_bytes())
    code, _, err = cli(capsys, "report", done)
    assert "chunk_00002.npz: was written by another run" in _one_line_error(code, err)


@pytest.mark.parametrize("damage,expect", [
    (lambda t: t + b"\xff\xfe", "unreadable ('utf-8' codec"),                   # not UTF-8
    (lambda t: t.split(b"\n", 1)[0] + b"," + b"y" * 200_000 + b"\n" + t.split(b"\n", 1)[1],
     "unreadable (field larger than field limit"),
    (lambda t: t.replace(b"\n", b",notes\n", 1), "line 1: column 'notes' is not a summary column"),
    (lambda t: t.replace(b"\n", b",extra,cells\n", 2).replace(b",extra,cells\n", b"\n", 1),
     "line 2: 41 cells for the header's 39 columns"),
    (lambda t: t + b"0,short\n", "line 6: 2 cells for the header's 39 columns"),
])
def test_a_damaged_summary_is_one_line(done, capsys, damage, expect):
    """summary.csv not UTF-8, with a field over the csv module's limit, a row with more or
    fewer cells than the header, or a column the summary does not have: tracebacks
    (UnicodeDecodeError, csv.Error, TypeError) or a user's column shown as a result; now one
    line naming the file and what is wrong, and saying to delete it."""
    p = done / "summary.csv"
    p.write_bytes(damage(p.read_bytes()))
    code, _, err = cli(capsys, "report", done)
    line = _one_line_error(code, err)
    assert "summary.csv: " in line and expect in line and "delete it" in line, line


def test_a_summary_saved_with_a_byte_order_mark_reads_as_written(done, capsys):
    p = done / "summary.csv"
    p.write_bytes(b"\xef\xbb\xbf" + p.read_bytes())
    assert [r["index"] for r in store.read_summary(done)] == [0, 1, 2, 3]


def test_a_manifest_that_is_not_a_regular_file_is_named_as_such(done, capsys):
    """A FIFO as manifest.json was reported as 'no manifest.json'."""
    (done / "manifest.json").unlink()
    os.mkfifo(done / "manifest.json")
    code, _, err = cli(capsys, "report", done)
    assert "manifest.json: not a manifest (a regular file" in _one_line_error(code, err)


# ------------------------------------------------------------------------------------------
# the fourth round's open cases


@pytest.mark.parametrize("kind", ["fifo", "dev_zero"])
def test_a_sweep_file_that_is_not_a_regular_file_is_named_as_such(tmp_path, capsys, kind):
    """`extends` naming a FIFO, or a sweep file that is a link to /dev/zero, said 'sweep file
    not found': it now says 'not a regular file', one line, exit 2, without opening it."""
    if kind == "fifo":
        os.mkfifo(tmp_path / "parent.toml")
        p = tmp_path / "child.toml"
        p.write_text('name = "child"\nextends = "parent"\n')
        want = "extends 'parent': not a regular file"
    else:
        p = tmp_path / "zero.toml"
        p.symlink_to("/dev/zero")
        want = f"{p}: not a regular file"
    code, out, err = cli(capsys, "show", p)       # a FIFO opened would block here
    line = _one_line_error(code, err)
    assert want in line and "not found" not in line, line
    (tmp_path / "gone.toml").symlink_to(tmp_path / "missing.toml")
    code, _, err = cli(capsys, "show", tmp_path / "gone.toml")
    assert "sweep file not found" in _one_line_error(code, err)


def test_a_huge_value_is_shown_short(tmp_path, capsys):
    """A polyline of 300,000 waypoints out of range gave a one-line error of 5 MB (the list
    repeated): the value shown is cut to a few hundred characters."""
    from hlip_jax.core import paths
    from hlip_jax.sweepio import sweep
    pts = [[2e4, float(i)] for i in range(300_000)]
    with pytest.raises(ValueError) as ex:
        paths.make_path("polyline", waypoints=pts)
    msg = str(ex.value)
    assert "'waypoints'" in msg and "allowed" in msg and len(msg) < 1000, len(msg)
    with pytest.raises(ValueError) as ex:
        paths.make_path("polyline", waypoints=np.full((300_000, 2), 2e4))
    assert len(str(ex.value)) < 1000
    assert len(fields.show_value("x" * 10**6)) <= fields.FMT_MAX_CHARS
    p = tmp_path / "big.toml"
    p.write_text('name = "big"\n[base]\nduration = 1.0\n[[paths]]\nshape = "polyline"\n'
                 "waypoints = [" + ", ".join(f"[{x:g}, {y:g}]" for x, y in pts) + "]\n")
    code, _, err = cli(capsys, "show", p)
    line = _one_line_error(code, err)
    assert "waypoints" in line and len(line) < 2000, len(line)
    p.write_text('name = "big"\n[base]\nplant = "' + "h" * 100_000 + '"\n[[paths]]\n'
                 'shape = "line"\n')
    code, _, err = cli(capsys, "show", p)
    assert len(_one_line_error(code, err)) < 2000


def test_a_chunks_file_is_named_on_resume(done, tiny_sweep, capsys):
    """`chunks` a regular file, `run --resume`: 'cannot write the results directory: File
    exists' did not say which file; the message now names it."""
    import shutil
    shutil.rmtree(done / "chunks")
    (done / "chunks").write_text("not a folder")
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", done, "--batch", "1", "--no-report",
                       "--quiet", "--resume")
    line = _one_line_error(code, err)
    assert "cannot write the results directory" in line and str(done / "chunks") in line, line


def test_a_fifo_manifest_is_named_by_run(done, tiny_sweep, capsys):
    """`manifest.json` a FIFO, `run --out DIR`: 'not a results directory (no manifest.json)';
    run now names it as report does, without opening the FIFO."""
    (done / "manifest.json").unlink()
    os.mkfifo(done / "manifest.json")
    for extra in ((), ("--resume",)):
        code, _, err = cli(capsys, "run", tiny_sweep, "--out", done, "--batch", "1",
                           "--no-report", "--quiet", *extra)
        line = _one_line_error(code, err)
        assert "manifest.json: not a manifest (a regular file" in line, line


def test_empty_paths_and_a_file_for_a_directory_are_named(tmp_path, capsys):
    # fifth round #35 and #38: `report FILE` said "results directory not found" for a file
    # that exists, `show ''` named '.'
    from hlip_jax.presentation import cli
    f = tmp_path / "manifest.json"
    f.write_text("{}")
    assert cli.main(["report", str(f)]) == 2
    err = capsys.readouterr().err
    assert "not a directory" in err and str(tmp_path) in err and err.count("\n") == 1
    assert cli.main(["show", ""]) == 2
    err = capsys.readouterr().err
    assert "SWEEP: empty" in err and err.count("\n") == 1
    assert cli.main(["report", ""]) == 2
    assert "DIR: empty" in capsys.readouterr().err


def test_a_grid_field_written_with_base_is_pointed_to_its_name():
    # fifth round #11: "base.duration" as a grid field suggested 'cassie'
    from hlip_jax.sweepio import sweep
    with pytest.raises(sweep.SweepError, match="without 'base.'; did you mean 'duration'"):
        sweep.parse_sweep('[[paths]]\nshape = "line"\n[grid.product]\n"base.duration" = [1.0, 2.0]\n')


# ---- sixth round (docs/reliability.md) ----------------------------------------------------

_ONE_PATH = 'name = "r6"\n[base]\nplant = "hlip"\nduration = 2.0\n'


@pytest.mark.parametrize("tail", ['[[paths]]\nshape = "line"\n[grid.product]\n'
                                  '"disturbance.noise_p" = [0.0, -0.0]\n',
                                  '[[paths]]\nshape = "circle"\n[grid.product]\n'
                                  '"path.radius" = [1, 1.0]\n'])
def test_equal_numbers_are_one_grid_point(tmp_path, capsys, tail):
    p = tmp_path / "r6.toml"
    p.write_text(_ONE_PATH + tail)
    line = _one_line_error(*cli(capsys, "show", p)[::2])
    assert "repeated grid point" in line


def test_a_list_field_of_too_many_entries_is_refused(tmp_path, capsys):
    obs = ", ".join(f"{{x = {10 + i * 0.01:.2f}, y = 5.0, radius = 0.1}}" for i in range(257))
    p = tmp_path / "r6.toml"
    p.write_text(_ONE_PATH + f"obstacles = [{obs}]\n[[paths]]\nshape = \"line\"\n")
    line = _one_line_error(*cli(capsys, "show", p)[::2])
    assert "base.obstacles: 257 entries; allowed: at most 256" in line


def test_a_duration_option_out_of_range_names_the_option(tiny_sweep, tmp_path, capsys):
    line = _one_line_error(*cli(capsys, "run", tiny_sweep, "--out", tmp_path / "o",
                                "--duration", "0")[::2])
    assert "--duration: 0 is out of range" in line and "base.duration" not in line
    assert not (tmp_path / "o").exists()


def test_an_empty_compile_cache_is_refused(tiny_sweep, tmp_path, capsys):
    line = _one_line_error(*cli(capsys, "run", tiny_sweep, "--out", tmp_path / "o",
                                "--compile-cache", "")[::2])
    assert "--compile-cache: an empty path" in line


@pytest.mark.parametrize("env", [{"XDG_CACHE_HOME": "relcache"}, {"HOME": ""}])
def test_no_default_cache_in_the_working_directory(tiny_sweep, tmp_path, capsys, fake_loop,
                                                    monkeypatch, env):
    monkeypatch.delenv("HLIP_JAX_CACHE_DIR", raising=False)
    monkeypatch.delenv("XDG_CACHE_HOME", raising=False)
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", tmp_path / "o", "--batch", "2",
                       "--no-report", "--quiet", "--limit", "2")
    assert code == 0, err
    assert "compilation cache off" in err and not list(work.iterdir())


def test_bad_mujoco_gl_and_jax_platforms_are_one_line(done, capsys, monkeypatch):
    import jax
    monkeypatch.setenv("MUJOCO_GL", "garbage")
    line = _one_line_error(*cli(capsys, "render", done, "0")[::2])
    assert "MUJOCO_GL='garbage': allowed: egl, osmesa" in line
    monkeypatch.delenv("MUJOCO_GL")
    monkeypatch.setenv("JAX_PLATFORMS", "nosuch")

    def no_backend():
        raise RuntimeError("Unable to initialize backend 'nosuch'")
    monkeypatch.setattr(jax, "devices", no_backend)
    line = _one_line_error(*cli(capsys, "report", done)[::2])
    assert "JAX_PLATFORMS='nosuch': Unable to initialize backend" in line


def test_a_bad_jax_switch_is_one_line():
    import subprocess
    import sys
    r = subprocess.run([sys.executable, "-c", "import sys; from hlip_jax.presentation.cli import main; "
                        "sys.exit(main(['list']))"], capture_output=True, text=True,
                       env={**os.environ, "JAX_ENABLE_X64": "maybe"}, timeout=60)
    line = _one_line_error(r.returncode, r.stderr)
    assert "'JAX_ENABLE_X64'" in line and "allowed: 1, true" in line


def test_a_deeply_nested_manifest_or_tick_record_names_the_file(done, capsys):
    deep = "[" * 100_000 + "]" * 100_000
    (done / "ticks").mkdir()
    (done / "ticks" / "0.json").write_text(deep)
    saved = (done / "manifest.json").read_text()
    (done / "manifest.json").write_text(deep)
    line = _one_line_error(*cli(capsys, "report", done)[::2])
    assert "manifest.json: unreadable manifest: arrays or objects nested too deeply" in line
    (done / "manifest.json").write_text(saved)
    line = _one_line_error(*cli(capsys, "report", done)[::2])
    assert "0.json: not a per-tick record" in line


@pytest.mark.parametrize("fmt", [0, 99, None, True])
def test_a_manifest_of_another_format_is_refused(done, capsys, fmt, tiny_sweep):
    import json
    p = done / "manifest.json"
    man = json.loads(p.read_text())
    man["format"] = fmt
    p.write_text(json.dumps(man))
    line = _one_line_error(*cli(capsys, "report", done)[::2])
    if fmt in (0, 99):      # another version's results: read them with it; never --overwrite
        which = "a newer" if fmt == 99 else "an older"
        assert f"results of {which} version of hlip_jax (manifest format {fmt}" in line
        assert "--overwrite" not in line
        def files():        # (the run's lock is taken and let go: its time changes)
            return sorted((q.name, q.stat().st_mtime_ns) for q in done.rglob("*") if q.name != ".lock")
        before = files()
        code, _, err = cli(capsys, "run", tiny_sweep, "--out", done, "--resume")
        assert code == 2 and "Traceback" not in err
        assert f"results of {which} version" in err and "--overwrite" not in err
        assert files() == before
    else:                   # not a format at all: a damaged manifest
        assert f"'format' is {fmt!r}; this version reads format 1" in line


def test_a_stored_value_out_of_range_names_the_manifest(done, capsys):
    import json
    p = done / "manifest.json"
    man = json.loads(p.read_text())
    man["configs"][0]["duration"] = float("nan")
    p.write_text(json.dumps(man))
    line = _one_line_error(*cli(capsys, "render", done, "0")[::2])
    assert "manifest.json: damaged manifest: configs[0]:" in line and "duration" in line


def test_s2s_of_an_unfinished_run_reads_each_scenario_by_its_index(done, capsys):
    (done / "chunks" / "chunk_00000.npz").unlink()
    code, out, err = cli(capsys, "s2s", done)
    assert "Traceback" not in err and "1 of the 4 chosen scenarios are not stored yet" in err
    assert code == 0 and out.startswith("3 scenarios"), err


# ---- seventh round (docs/reliability.md) --------------------------------------------------

@pytest.mark.parametrize("regex, why", [("a{4294967296}", "repetition number is too large"),
                                        ("(" * 2000 + ")" * 2000, "nested too deeply")])
def test_a_regex_python_cannot_compile_is_named(done, capsys, regex, why):
    # #24 (traceback: OverflowError) and #29 (a recursion message naming no option)
    line = _one_line_error(*cli(capsys, "s2s", done, "--scenarios", regex)[::2])
    assert line.startswith("hlip-sweep: error: --scenarios: ") and why in line
    assert len(line) < 300


def test_a_path_far_from_the_origin_is_refused(tmp_path, capsys):
    # #12: at x0 = y0 = 10,000 m (the parameter's range) the same path tracked differently
    for params in ("x0 = 10000.0", "y0 = -1000.5", "waypoints = [[0, 0], [2000, 0]]"):
        shape = "polyline" if "waypoints" in params else "circle"
        p = tmp_path / "far.toml"
        p.write_text(_ONE_PATH + f'[[paths]]\nshape = "{shape}"\n{params}\n')
        line = _one_line_error(*cli(capsys, "show", p)[::2])
        assert "m from the origin; allowed: within ±1000 m" in line
    p.write_text(_ONE_PATH + '[[paths]]\nshape = "circle"\nx0 = 1000.0\ny0 = -1000.0\n')
    assert cli(capsys, "show", p)[0] == 0


@pytest.mark.parametrize("name", ["é" * 3, "e\u0301", "\u0661\u0662", "\ufb01le"])
def test_a_non_ascii_name_is_refused_as_not_ascii(tmp_path, capsys, name):
    # #14-17: the message allowed "letters, digits" and refused these letters and digits
    p = tmp_path / "u.toml"
    p.write_text(_ONE_PATH + f'[[paths]]\nshape = "line"\nname = "{name}"\n', encoding="utf-8")
    line = _one_line_error(*cli(capsys, "show", p)[::2])
    assert "allowed: 1-64 ASCII letters, digits" in line
    assert "not allowed in a file name ('\\" in line      # the characters shown escaped


def test_extends_of_a_missing_file_says_where_it_looked(tmp_path, capsys):
    # #21: `extends = "paper"` (a shipped sweep's name) said only "sweep file not found"
    p = tmp_path / "child.toml"
    p.write_text('name = "child"\nextends = "paper"\n')
    line = _one_line_error(*cli(capsys, "show", p)[::2])
    assert f"looked for '{tmp_path / 'paper.toml'}': a path relative to this file" in line


def test_a_folder_named_like_a_shipped_sweep_does_not_hide_it(tmp_path, capsys, monkeypatch):
    # #47: a folder `paper_hlip` in the working directory: "sweep file not found (a directory)"
    monkeypatch.chdir(tmp_path)
    (tmp_path / "paper_hlip").mkdir()
    code, out, err = cli(capsys, "show", "paper_hlip")
    assert code == 0 and "sweeps/paper_hlip.toml" in out, err


@pytest.mark.parametrize("value", ["path=line,nosuch", "path=line=circle", "mpc.alpha=0.5"])
def test_a_train_on_value_no_scenario_takes_is_refused(done, capsys, value):
    # #33, #35: a typo in a value trained on the others without a word
    before = (done / "coverage.csv").read_bytes() if (done / "coverage.csv").exists() else None
    line = _one_line_error(*cli(capsys, "coverage", done, "--train-on", value)[::2])
    assert "is none of the run's values of" in line and "allowed: " in line
    after = (done / "coverage.csv").read_bytes() if (done / "coverage.csv").exists() else None
    assert before == after


def test_coverage_of_an_unfinished_run_says_so(done, capsys):
    # #38: coverage of 3 of 4 scenarios said nothing of the missing one
    (done / "chunks" / "chunk_00001.npz").unlink()
    code, _, err = cli(capsys, "coverage", done)
    assert code == 0 and "note: 3 of the 4 scenarios are stored" in err, err


def test_resume_with_another_limit_names_the_scenario_count(tmp_path, tiny_sweep, capsys,
                                                             fake_loop):
    # #51: "the expanded sweep config differs" did not say that --limit did
    out = tmp_path / "o"
    _run_ok(capsys, tiny_sweep, out, "--limit", "2")
    line = _one_line_error(*cli(capsys, "run", tiny_sweep, "--out", out, "--resume",
                                "--quiet")[::2])
    assert "the scenario count differs (manifest 2, now 4" in line and "--limit" in line


def test_a_compile_cache_link_in_a_loop_says_so(tiny_sweep, tmp_path, capsys):
    # #54, #58: a link loop as the cache directory was reported as "File exists"
    (tmp_path / "a").symlink_to(tmp_path / "b")
    (tmp_path / "b").symlink_to(tmp_path / "a")
    line = _one_line_error(*cli(capsys, "run", tiny_sweep, "--out", tmp_path / "o",
                                "--compile-cache", tmp_path / "a")[::2])
    assert "a symbolic link that leads nowhere" in line and not (tmp_path / "o").exists()


def test_a_full_disk_names_the_results_directory(done, capsys, monkeypatch):
    # #65, #66: "No space left on device" named no file or directory
    import errno
    from hlip_jax.presentation import report

    def full(*a, **k):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    monkeypatch.setattr(report, "write_report", full)
    line = _one_line_error(*cli(capsys, "report", done)[::2])
    assert line == f"hlip-sweep: error: {done}: No space left on device"
