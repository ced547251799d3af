"""Issue 52, twelfth round (docs/reliability.md, "Round 12"): `s2s` and `identify` count the
step pairs of all the chosen runs before blaming --skip, `identify` refuses a fit its steps do
not determine, neither `identify -o` nor `whull --out` writes into a run's `chunks/`, `whull`
notes an unfinished run and refuses NaN disturbances, a chunk whose model or gain arrays are
not finite or whose stance is neither foot is named, model files of booleans, complex or huge
numbers are refused, a gain that an identified model makes infinite names the model file, a
sweep file that is not UTF-8 names its encoding or line, `coverage` is refused while a run
writes the directory, and `wbox` of a table without rows names the splits.

Runs use the fake closed loop of test_store.py (``HLIP_SWEEP_SIMULATE``) and the H-LIP plant.
"""

from __future__ import annotations

import numpy as np

from hlip_jax.core import s2s_model
from hlip_jax.sweepio import store
from test_cli import TINY, _one_line_error, cli, fake_loop, tiny_sweep  # noqa: F401
from test_reliability_round4 import done  # noqa: F401 (fixture: a finished tiny run)


def _steps(d) -> list[int]:
    from hlip_jax.core import steplog
    log = store.load_log(d)
    return [int(steplog.alive(v).sum()) for v in log["valid"]]


def _edit_chunk(d, i: int, **fields) -> None:
    p = store.chunk_path(d, i)
    z = dict(np.load(p))
    for k, f in fields.items():
        z[k] = f(z[k])
    np.savez(p, **z)


def test_s2s_counts_the_pairs_of_all_chosen_runs_before_blaming_skip(done, capsys):
    """V01: `s2s DIR` of 3-s runs (8 steps each) said `--skip: 4 leaves no usable step pairs
    ... allowed: fewer than 3` although the fit, which pools the runs, had 12 pairs (and
    `identify` on the same runs fitted them): the check asked for 5 pairs in one run."""
    longest = max(_steps(done))
    skip = longest - 5                      # 4 pairs per run: 16 in all, the fit needs 5
    code, out, err = cli(capsys, "s2s", done, "--skip", skip)
    assert code == 0, err
    assert "4 scenarios, 16 step pairs" in out
    line = _one_line_error(*cli(capsys, "s2s", done, "--skip", longest - 2)[::2])
    assert f"--skip: {longest - 2} leaves only 4 usable step pairs" in line
    assert f"allowed: at most {longest - 3}" in line        # 8 pairs in all


def test_runs_that_fell_are_named_not_skip(tmp_path, capsys, fake_loop):
    """V02: `identify` of runs that all fell after 3 steps advised `--skip: 4 ...; allowed:
    fewer than 2`, with which the fit still had too few pairs; now the runs are named: even
    --skip 0 leaves fewer pairs than the fit needs."""
    sw = tmp_path / "fell.toml"
    sw.write_text('name = "fell"\n[base]\nplant = "hlip"\nduration = 4.0\n'
                  '[[paths]]\nshape = "line"\n[[paths]]\nshape = "circle"\n'
                  '[grid.product]\n"gain.type" = ["lqr"]\n"mpc.alpha" = [0.1]\n')
    out = tmp_path / "o"
    code, _, err = cli(capsys, "run", sw, "--out", out, "--quiet", "--no-report")
    assert code == 0, err
    assert max(_steps(out)) <= 3                    # every run fell
    f = tmp_path / "m.npz"
    line = _one_line_error(*cli(capsys, "identify", out, "-o", f)[::2])
    assert line.startswith("hlip-sweep: error: scenarios: 2 chosen runs with ") and \
        "even with --skip 0" in line and "needs at least 7" in line, line
    assert not f.exists()


def test_identify_refuses_a_fit_its_steps_do_not_determine(done, tmp_path, capsys):
    """V10: every chunk's states and steps damaged to one constant: `identify` wrote a model
    of regressor rank 1 of 7 (least squares' minimum-norm answer, RMS 2e22), exit 0."""
    for i in range(4):
        _edit_chunk(done, i, x_robot=lambda a: np.full_like(a, 1e30),
                    u_robot=lambda a: np.full_like(a, 1e30))
    f = tmp_path / "m.npz"
    line = _one_line_error(*cli(capsys, "identify", done, "-o", f)[::2])
    assert "rank" in line and "of 7" in line and "nothing written" in line
    assert not f.exists()


def test_no_file_is_written_into_a_runs_chunks_folder(done, capsys):
    """V14, V15: `identify DIR -o OTHER/chunks/chunk_00004.npz` wrote the model there; the
    other run's every reader then refused it (`not a chunk of this run`).  `whull --out` into a
    `chunks/` folder is refused the same way."""
    for cmd in (["identify", done, "-o", done / "chunks" / "chunk_00004.npz"],
                ["whull", done, "--out", done / "chunks" / "w.csv"]):
        line = _one_line_error(*cli(capsys, *cmd)[::2])
        assert "inside the chunks folder of the results directory" in line and "allowed:" in line
    assert sorted(p.name for p in (done / "chunks").iterdir()) == [
        f"chunk_0000{i}.npz" for i in range(4)]
    code, _, err = cli(capsys, "report", done)
    assert code == 0, err


def test_whull_refuses_nan_disturbances_and_names_the_chunk(done, tmp_path, capsys):
    """V07: a chunk whose state fields are NaN: `whull` wrote a hull file of `nan` rows, exit
    0 (a sweep reading it then refuses the file, far from the cause)."""
    nan = {k: (lambda a: np.full_like(a, np.nan)) for k in ("x_robot", "u_robot", "w", "e",
                                                             "x_hlip")}
    _edit_chunk(done, 0, **nan)
    f = tmp_path / "w.csv"
    line = _one_line_error(*cli(capsys, "whull", done, "--out", f)[::2])
    assert "chunk_00000.npz" in line and "NaN or infinite" in line and "--resume" in line
    assert not f.exists()


def test_whull_notes_the_scenarios_an_unfinished_run_has_not_stored(done, tmp_path, capsys):
    """V29: `whull` of an unfinished run (or of one still running) printed the hull of the
    stored runs only, with no note, where `s2s` and `identify` note what is missing."""
    store.chunk_path(done, 3).unlink()
    code, out, err = cli(capsys, "whull", done, "--out", tmp_path / "w.csv")
    assert code == 0, err
    assert "note: 1 of the 4 chosen scenarios are not stored yet" in err
    assert "from 3 runs" in out


def test_a_chunk_whose_model_arrays_are_not_finite_is_named(done, tmp_path, capsys):
    """V09: a chunk's `A` and `B` NaN: `identify` printed `H-LIP +nan p +nan v` beside the fit
    and wrote the model, exit 0.  Every reader now names the chunk."""
    _edit_chunk(done, 2, A=lambda a: np.full_like(a, np.nan))
    for cmd in (["identify", done, "-o", tmp_path / "m.npz"], ["s2s", done], ["report", done]):
        line = _one_line_error(*cli(capsys, *cmd)[::2])
        assert "chunk_00002.npz: array 'A' holds NaN or infinite values" in line, line
    assert not (tmp_path / "m.npz").exists()


def test_a_chunk_whose_stance_is_neither_foot_is_named(done, capsys):
    """V11: a chunk's `stance` set to 7 (neither 0, left, nor 1, right): `s2s` fitted without
    its stance constants (regressor rank 3 of 5), exit 0."""
    _edit_chunk(done, 1, stance=lambda a: np.full_like(a, 7))
    line = _one_line_error(*cli(capsys, "s2s", done, "--skip", 0)[::2])
    assert "chunk_00001.npz: array 'stance' holds values other than 0 (left) and 1" in line


def _model_sweep(tmp_path, name: str, **arrays) -> object:
    good = s2s_model.Model(A=np.array([[1.6, 0.5], [4.4, 2.0]]), B=np.array([-1.6, -4.4]),
                           offset=np.zeros((2, 2, 2)), rms=np.zeros(2), n=20, rank=7,
                           cadence=(0.8, 0.3, 0.1))
    f = tmp_path / f"{name}.npz"
    z = dict(np.load(__import__("io").BytesIO(s2s_model.to_bytes(good))))
    z.update(arrays)
    np.savez(f, **z)
    sw = tmp_path / f"{name}.toml"
    sw.write_text(TINY + f'[base.s2s]\nmodel = "identified"\nfile = "{f}"\n')
    return sw


def test_model_files_of_booleans_complex_or_huge_numbers_are_refused(tmp_path, capsys):
    """V17, V19, V20: an `s2s.file` whose A is 1e300 printed numpy's overflow warning and
    blamed the gain's weights (`a larger gain.r`); a boolean A was read as 0/1 (the same
    message); a complex cadence printed two ComplexWarnings and compared its real part."""
    for name, arrays, want in [
            ("huge", {"A": np.full((2, 2), 1e300)}, "A: values beyond"),
            ("bool", {"A": np.ones((2, 2), bool)}, "A: an array of bool"),
            ("cplx", {"cadence": np.array([0.8, 0.3, 0.1j])}, "cadence: an array of complex")]:
        sw = _model_sweep(tmp_path, name, **arrays)
        line = _one_line_error(*cli(capsys, "show", sw)[::2])
        assert f"s2s.file: {tmp_path / name}.npz: {want}" in line and "allowed:" in line, line


def test_an_identified_model_without_a_finite_gain_names_the_model_file(tmp_path, capsys,
                                                                        fake_loop):
    """V21: a model file whose map the deadbeat design cannot invert (B = 0) was refused with
    `gain.type = 'deadbeat' gives no finite stepping gain ...; allowed: ... a larger gain.r or
    smaller gain.q_*`: weights a deadbeat gain does not have.  The model file is named."""
    sw = _model_sweep(tmp_path, "unc", A=np.eye(2), B=np.zeros(2))
    out = tmp_path / "o"
    line = _one_line_error(*cli(capsys, "run", sw, "--out", out, "--quiet")[::2])
    assert f"s2s.file '{tmp_path / 'unc.npz'}'" in line and "gain.r" not in line
    assert not out.exists()


def test_a_sweep_file_not_in_utf8_names_its_encoding_or_line(tmp_path, capsys):
    """V39, V40: a sweep file saved as UTF-16 or Latin-1 said `cannot read the sweep file:
    'utf-8' codec can't decode byte 0xff in position 0: invalid start byte` (a byte offset,
    nothing allowed)."""
    for name, data, want in [
            ("u16", TINY.encode("utf-16"), "a UTF-16 file"),
            ("u32", TINY.encode("utf-32"), "a UTF-32 file"),
            ("l1", (TINY + 'description = "vitesse élevée"\n').encode("latin-1"),
             f"line {TINY.count(chr(10)) + 1}: byte 0xe9 is not UTF-8")]:
        p = tmp_path / f"{name}.toml"
        p.write_bytes(data)
        line = _one_line_error(*cli(capsys, "show", p)[::2])
        assert f"{p}: {want}" in line and "allowed: UTF-8 text" in line, line
        assert "codec" not in line


def test_coverage_is_refused_while_a_run_writes_the_directory(done, capsys):
    """V30: `coverage DIR` started after the first of 200 chunks of `run --batch 1` wrote the
    table of the 12 chunks stored then (the run's own, written at its end, replaced it that
    time); written after the run's, it stands as the finished run's (shown by computing it on
    20 of 200 chunks and putting the others back: `wbox` printed the W of 20 runs, `report`
    showed 10 / 10 runs).  It is refused while a run holds the directory's lock."""
    table = (done / store.COVERAGE).read_bytes()
    with store.results_lock(done):
        line = _one_line_error(*cli(capsys, "coverage", done)[::2])
    assert f"{done}: a run is writing this directory (pid " in line and "after it" in line
    assert (done / store.COVERAGE).read_bytes() == table
    code, _, err = cli(capsys, "coverage", done)       # the lock released: as before
    assert code == 0, err


def test_wbox_of_a_table_without_rows_names_the_splits_not_the_options(tmp_path, capsys,
                                                                        fake_loop):
    """V32: `[analysis] splits = ["speed"]` in a sweep that sweeps no speed: coverage.csv has
    no rows, and `wbox DIR` (no option given) said `--group/--method: method 'box': no
    coverage.csv rows of it`."""
    sw = tmp_path / "s.toml"
    sw.write_text(TINY + '[analysis]\nsplits = ["speed"]\n')
    out = tmp_path / "o"
    code, _, err = cli(capsys, "run", sw, "--out", out, "--quiet", "--no-report")
    assert code == 0, err
    line = _one_line_error(*cli(capsys, "wbox", out)[::2])
    assert f"{out / store.COVERAGE}: holds no rows" in line and "(speed)" in line
    assert "--group/--method" not in line and "--split path" in line
