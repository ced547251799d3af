"""Issue 52, eleventh round (docs/reliability.md, "Round 11"): a file written into a read-only
folder named as itself (not its temporary), LQR weights whose gain is not finite refused before
the run, a resume whose sweep changed its [analysis] refused, `wbox` checking the chunks against
a manifest copied in with its coverage table from another run.

Runs use the fake closed loop of test_store.py (``HLIP_SWEEP_SIMULATE``) and the H-LIP plant.
"""

from __future__ import annotations

import errno
import os
import shutil
import tempfile

from hlip_jax.sweepio import store
from test_cli import TINY, _one_line_error, _run_ok, cli, fake_loop, tiny_sweep  # noqa: F401
from test_reliability_round4 import done  # noqa: F401 (fixture: a finished tiny run)


def test_a_file_written_into_a_read_only_folder_is_named_as_itself(done, capsys, monkeypatch):
    """U18, U19, U21: `report`, `coverage` and `run --resume` on a read-only results directory
    (a read-only mount: root too gets EROFS) named the temporary file that could not be
    created (`.coverage.csv.te0i7vps.tmp: Read-only file system`); the error now names the file
    written and says its folder must be writable."""
    real = tempfile.mkstemp

    def read_only(*args, dir=None, prefix="", suffix="", **kw):
        if dir is not None and str(dir).startswith(str(done)):
            raise OSError(errno.EROFS, os.strerror(errno.EROFS),
                          os.path.join(str(dir), f"{prefix}te0i7vps{suffix}"))
        return real(*args, dir=dir, prefix=prefix, suffix=suffix, **kw)
    monkeypatch.setattr(store.tempfile, "mkstemp", read_only)
    before = sorted(p.name for p in done.iterdir())
    line = _one_line_error(*cli(capsys, "coverage", done)[::2])
    assert f"{done / 'coverage.csv'}: Read-only file system" in line, line
    assert ".tmp" not in line and "must be writable" in line
    assert sorted(p.name for p in done.iterdir()) == before


def test_lqr_weights_without_a_finite_gain_are_refused_before_the_run(tmp_path, capsys,
                                                                      fake_loop):
    """U37: `gain.type = "lqr"` with `r = 1e-9` and `q_* = 1e6` (each inside its range) gave
    a NaN stepping gain; the run simulated on it and ended in a LinAlgError traceback from the
    analysis.  It is now refused in one line before anything is written."""
    sw = tmp_path / "lqr.toml"
    sw.write_text('name = "lqr"\n[base]\nplant = "hlip"\nduration = 2.0\n[base.gain]\n'
                  'type = "lqr"\nr = 1e-9\nq_c = 1e6\nq_p = 1e6\nq_v = 1e6\n'
                  '[[paths]]\nshape = "line"\n')
    out = tmp_path / "o"
    line = _one_line_error(*cli(capsys, "run", sw, "--out", out, "--quiet")[::2])
    assert str(sw) in line and "scenario 'line'" in line and "r = 1e-09" in line
    assert "no finite stepping gain" in line and "allowed:" in line
    assert not out.exists()


def test_a_resume_whose_sweep_changed_its_analysis_is_refused(done, tmp_path, capsys,
                                                                fake_loop):
    """U05: `--resume` after the sweep's [analysis] changed (`warmup = 1`) ran the missing
    chunk's coverage columns with the new warm-up beside chunks of the old one, while the
    manifest kept the old: two analyses in one summary, exit 0.  It is now refused, naming the
    setting, and the stored chunks are left as they were."""
    store.chunk_path(done, 3).unlink()
    (done / store.SUMMARY).unlink()
    kept = {p.name: p.read_bytes() for p in (done / store.CHUNK_DIR).iterdir()}
    changed = tmp_path / "changed.toml"
    changed.write_text(TINY + "[analysis]\nwarmup = 1\n")
    line = _one_line_error(*cli(capsys, "run", changed, "--out", done, "--resume", "--quiet",
                                "--no-report")[::2])
    assert f"refusing to resume {done}" in line and "[analysis]" in line
    assert "warmup: 4 in manifest.json, 1 now" in line and "--overwrite" in line
    assert {p.name: p.read_bytes() for p in (done / store.CHUNK_DIR).iterdir()} == kept


def test_wbox_checks_the_chunks_against_a_manifest_copied_with_its_table(done, tmp_path,
                                                                          tiny_sweep, capsys,
                                                                          fake_loop):
    """U11: `manifest.json` and `coverage.csv` copied in together from another valid run (one
    of another duration): `wbox` printed the other run's W as this directory's (the table
    matched the manifest; the chunks were never looked at) while `report` refused the
    directory.  `wbox` now checks the chunks against the manifest first."""
    other = tmp_path / "other"
    _run_ok(capsys, tiny_sweep, other, "--duration", "5")
    cli(capsys, "coverage", other)
    code, out, err = cli(capsys, "wbox", done)
    assert code == 0, err                            # its own table: read as before
    for name in (store.MANIFEST, store.COVERAGE):
        shutil.copyfile(other / name, done / name)
    line = _one_line_error(*cli(capsys, "wbox", done)[::2])
    assert "chunk_00000.npz: was written by another run" in line and "--resume" in line
