"""The ``hlip-sweep`` command line (hlip_jax.presentation.cli), run as a subprocess like a user would.

User errors must exit non-zero with one clear line naming the field and no traceback.  Runs
use the fake closed loop of test_store.py (``HLIP_SWEEP_SIMULATE``) except one end-to-end
run of the real H-LIP closed loop on a two-scenario, 2-second sweep (marked slow: compile).

Issue 22's corpus: every file of tests/sweeps_broken/ through ``show`` (exit 2, one line
naming the file and its ``# expect:`` fragments), plus the inputs only a run meets: an
unusable ``--out``, a full disk, a second run into a busy directory, damaged chunks (``report``
names them, ``--resume`` repairs them byte for byte), SIGTERM, the umask.
"""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

from hlip_jax.sweepio import store
from hlip_jax.presentation.cli import main

ROOT = Path(__file__).resolve().parent.parent
TESTS = Path(__file__).resolve().parent
BROKEN = TESTS / "sweeps_broken"


def hs(*args, cwd=None, fake=True, timeout=300, env=None):
    env = dict(os.environ, **(env or {}))
    env["PYTHONPATH"] = os.pathsep.join([str(TESTS), env.get("PYTHONPATH", "")])
    env["MPLBACKEND"] = "Agg"
    if fake:
        env["HLIP_SWEEP_SIMULATE"] = "test_store:fake_simulate"
    else:
        env.pop("HLIP_SWEEP_SIMULATE", None)
    return subprocess.run([sys.executable, "-m", "hlip_jax.presentation.cli", *map(str, args)], cwd=cwd or ROOT,
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


@pytest.mark.parametrize("sub", [["run"], ["report"], ["list"], ["show"], ["s2s"], ["ticks"], ["wbox"]])
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
    assert code == 2 and "--duration: -3 is out of range" in err
    code, _, err = cli(capsys, "run", "paper", "--batch", "0")
    assert code == 2 and "--batch" in err
    code, _, err = cli(capsys, "run", "paper", "--plant", "atlas")
    assert code == 2 and "--plant" in err
    # bench: bad sizes are refused before anything is built or compiled
    code, _, err = cli(capsys, "bench", "--duration", "-1")
    assert code == 2 and "--duration must be > 0" in err
    code, _, err = cli(capsys, "bench", "--batch", "0")
    assert code == 2 and "--batch" in err
    code, _, err = cli(capsys, "bench", "--qp-kernel", "fused")
    assert code == 2 and "--qp-kernel" in err and "--qp-linsys inverse" in err


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
    cache = tmp_path / "cache"
    r = hs("run", sw, "--out", tmp_path / "o", "--compile-cache", cache, fake=False, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "report: " in r.stdout and str(tmp_path / "o" / "report.html") in r.stdout
    rows = (tmp_path / "o" / "summary.csv").read_text().splitlines()
    assert len(rows) == 3 and all(",ok," in row for row in rows[1:])
    assert (tmp_path / "o" / "figures" / "line_xy.png").is_file()
    # the compiled closed loop went to the cache, and a second run that reads it back
    # simulates the same scenarios to the same numbers
    assert any(cache.iterdir())
    r2 = hs("run", sw, "--out", tmp_path / "o2", "--compile-cache", cache, "--no-report",
            fake=False, timeout=600)
    assert r2.returncode == 0, r2.stderr
    assert (tmp_path / "o2" / "summary.csv").read_text() == "\n".join(rows) + "\n"


def test_unusable_compile_cache_is_a_user_error(tmp_path, tiny_sweep, capsys, fake_loop):
    (tmp_path / "file").write_text("x")
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", tmp_path / "o",
                       "--compile-cache", tmp_path / "file")
    line = _one_line_error(code, err)
    assert "--compile-cache" in line and "writable directory" in line
    assert not (tmp_path / "o").exists()


# --------------------------------------------------------------------------------------------
# issue 22: every broken input a one-line error with exit 2 (or 1 where documented)

BROKEN_FILES = sorted(BROKEN.glob("*.toml"))


def _one_line_error(code, err, expect_code=2):
    assert code == expect_code, err
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("hlip-sweep: error: "), err
    return lines[0]


@pytest.mark.parametrize("path", BROKEN_FILES, ids=lambda p: p.stem)
def test_every_broken_file_is_rejected_by_show(path, capsys):
    """`show` rejects what `run` would: exit 2, one line naming the file and its fields."""
    code, out, err = cli(capsys, "show", path)
    line = _one_line_error(code, err)
    assert str(path) in line and out == ""
    for frag in [ln.split("# expect:", 1)[1].strip()
                 for ln in path.read_text(encoding="utf-8-sig").splitlines()
                 if ln.startswith("# expect:")]:
        assert frag in line, (frag, line)


@pytest.mark.parametrize("name,field", [
    ("nested_arrays_5000", "nested too deeply"),
    ("grid_exactly_the_limit", "fewer than 10000000"),
    ("static_horizon_swept", "mpc.horizon"),
    ("name_dotdot", "name"),
])
def test_heavy_broken_inputs_in_a_process(name, field, tmp_path):
    """Deep nesting and a grid of exactly the limit: exit 2 within 60 s and under 2 GiB of
    resident memory (the child's own peak; importing JAX alone takes a few hundred MiB),
    nothing written."""
    code, _, err, peak_kib = _hs_measured("run", BROKEN / f"{name}.toml", "--out", tmp_path / "o",
                                          timeout=60)
    line = _one_line_error(code, err)
    assert field in line
    assert not (tmp_path / "o").exists()
    assert peak_kib < 2 * 2 ** 20, f"peak RSS {peak_kib / 2 ** 20:.2f} GiB"


_MEASURED_MAIN = """
import atexit, os, sys
from hlip_jax.presentation.cli import main

def _peak():
    with open("/proc/self/status") as f:
        hwm = [ln for ln in f if ln.startswith("VmHWM:")][0]
    with open(os.environ["HLIP_TEST_PEAK_FILE"], "w") as f:
        f.write(hwm.split()[1])

atexit.register(_peak)
sys.exit(main(sys.argv[1:]))
"""


def _hs_measured(*args, timeout):
    """``hlip-sweep ARGS`` in a subprocess (fake closed loop, ``timeout`` s): (exit code, stdout,
    stderr, the child's own peak resident memory [KiB]).  The peak is VmHWM of the child's
    address space, read by the child at exit: getrusage's ru_maxrss would also count the
    forking test process's memory."""
    peak_file = Path(tempfile.mkstemp(prefix="hlip_peak_")[1])
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")]),
               MPLBACKEND="Agg", HLIP_SWEEP_SIMULATE="test_store:fake_simulate",
               HLIP_TEST_PEAK_FILE=str(peak_file))
    try:
        r = subprocess.run([sys.executable, "-c", _MEASURED_MAIN, *map(str, args)], cwd=ROOT,
                           env=env, capture_output=True, text=True, timeout=timeout)
        return r.returncode, r.stdout, r.stderr, int(peak_file.read_text())
    finally:
        peak_file.unlink()


def test_show_of_a_million_scenarios_is_fast(tmp_path, capsys):
    sw = tmp_path / "million.toml"
    sw.write_text('[[paths]]\nshape = "circle"\n[grid.product]\n"seed" = [%s]\n'
                  '"mpc.alpha" = [%s]\n' % (", ".join(map(str, range(1000))),
                                            ", ".join(f"{i / 1000:g}" for i in range(1000))))
    import time
    t0 = time.monotonic()
    code, out, _ = cli(capsys, "show", sw)
    assert code == 0 and "= 1000000" in out and "more)" in out
    assert time.monotonic() - t0 < 10


def _run_ok(capsys, sw, out, *extra):
    code, _, err = cli(capsys, "run", sw, "--out", out, "--batch", "1", "--no-report",
                       "--quiet", *extra)
    assert code == 0, err


@pytest.fixture
def tiny_sweep(tmp_path):
    p = tmp_path / "clitiny.toml"
    p.write_text(TINY)
    return p


def test_out_under_a_file(tmp_path, tiny_sweep, capsys, fake_loop):
    (tmp_path / "afile").write_text("x")
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", tmp_path / "afile" / "sub", "--quiet")
    assert "--out" in _one_line_error(code, err)
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", tmp_path / "afile", "--quiet")
    assert "not a directory" in _one_line_error(code, err)


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes through permissions")
def test_out_read_only(tmp_path, tiny_sweep, capsys, fake_loop):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", ro / "x", "--quiet")
    assert "--out" in _one_line_error(code, err)


def test_links_in_out_and_an_empty_out_are_refused(tmp_path, tiny_sweep, capsys, fake_loop):
    """A `.lock` or `figures/` that is a symbolic link out of --out: exit 2 naming it, and the
    file or folder it points to untouched; `--out ''` exits 2 instead of writing elsewhere."""
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    out = tmp_path / "o"
    out.mkdir()
    (out / ".lock").symlink_to(victim)
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", out, "--quiet")
    assert "symbolic link" in _one_line_error(code, err) and ".lock" in err
    assert victim.read_text() == "keep me"
    (out / ".lock").unlink()
    _run_ok(capsys, tiny_sweep, out)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (out / "figures").symlink_to(elsewhere, target_is_directory=True)
    code, _, err = cli(capsys, "report", out)
    assert "symbolic link" in _one_line_error(code, err) and "figures" in err
    assert list(elsewhere.iterdir()) == []
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", "", "--quiet")
    assert "--out" in _one_line_error(code, err)


def test_out_too_long_a_name(tmp_path, tiny_sweep, capsys, fake_loop):
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", tmp_path / ("d" * 300), "--quiet")
    assert "--out" in _one_line_error(code, err) and "too long" in err


def test_disk_full_while_writing_chunks(tmp_path, tiny_sweep, capsys, fake_loop, monkeypatch):
    """A file-system error mid-run: exit 1 (incomplete), one line, the manifest says so."""
    from hlip_jax.sweepio import store
    real, calls = store.save_npz_atomic, []

    def full(path, arrays):
        calls.append(path)
        if len(calls) > 1:
            raise OSError(28, "No space left on device", str(path))
        real(path, arrays)

    monkeypatch.setattr(store, "save_npz_atomic", full)
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", tmp_path / "o", "--batch", "1",
                       "--quiet")
    line = _one_line_error(code, err, expect_code=1)
    assert "No space left on device" in line and "--resume" in line and "chunk_00001" in line
    assert json.loads((tmp_path / "o" / "manifest.json").read_text())["status"] == "incomplete"
    monkeypatch.setattr(store, "save_npz_atomic", real)
    _run_ok(capsys, tiny_sweep, tmp_path / "o", "--resume")


def test_disk_full_at_the_start(tmp_path, tiny_sweep, capsys, fake_loop, monkeypatch):
    from hlip_jax.sweepio import store

    def full(out_dir, man):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(store, "write_manifest", full)
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", tmp_path / "o", "--quiet")
    assert "No space left" in _one_line_error(code, err)


def test_second_concurrent_run_is_refused(tmp_path, tiny_sweep, capsys, fake_loop):
    """While a run holds the directory, another exits 2 naming the holder and writes nothing."""
    from hlip_jax.sweepio import store
    out = tmp_path / "o"
    _run_ok(capsys, tiny_sweep, out)
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file() and p.name != ".lock"}
    with store.results_lock(out):
        for extra in ([], ["--resume"], ["--overwrite"]):
            code, _, err = cli(capsys, "run", tiny_sweep, "--out", out, "--quiet", *extra)
            line = _one_line_error(code, err)
            assert f"pid {os.getpid()}" in line and "another run" in line
        r = hs("run", tiny_sweep, "--out", out, "--overwrite", "--quiet")
        assert f"pid {os.getpid()}" in _one_line_error(r.returncode, r.stderr)
    after = {p: p.read_bytes() for p in out.rglob("*") if p.is_file() and p.name != ".lock"}
    assert before == after


def test_stale_lock_is_taken_over(tmp_path, tiny_sweep, capsys, fake_loop):
    out = tmp_path / "o"
    out.mkdir()
    (out / ".lock").write_text("pid 999999 on gone since 2020-01-01T00:00:00+00:00\n")
    _run_ok(capsys, tiny_sweep, out)
    assert f"pid {os.getpid()}" in (out / ".lock").read_text()


def _truncate(p: Path):
    b = p.read_bytes()
    p.write_bytes(b[: len(b) // 2])


def _flip(p: Path):
    """One bit flipped inside the stored bytes of x_robot (a bit of a zip header may not be
    checked; every member's data is, by its CRC-32)."""
    import struct
    import zipfile
    with zipfile.ZipFile(p) as z:
        info = z.getinfo("x_robot.npy")
    b = bytearray(p.read_bytes())
    n_name, n_extra = struct.unpack("<HH", b[info.header_offset + 26:info.header_offset + 30])
    start = info.header_offset + 30 + n_name + n_extra
    b[start + info.compress_size // 2] ^= 0x10
    p.write_bytes(bytes(b))


def _empty(p: Path):
    p.write_bytes(b"")


def _swap(p: Path):
    other = p.parent / "chunk_00000.npz"
    p.write_bytes(other.read_bytes())


def _drop_array(p: Path):
    import numpy as np
    with np.load(p) as z:
        arrays = {k: z[k] for k in z.files if k != "x_robot"}
    np.savez(p, **arrays)


def _short_array(p: Path):
    import numpy as np
    with np.load(p) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["u_robot"] = arrays["u_robot"][:, :2]
    np.savez(p, **arrays)


@pytest.mark.parametrize("damage,why", [
    (_truncate, "corrupt"), (_flip, "CRC"), (_empty, "corrupt"), (_swap, "other scenarios"),
    (_drop_array, "x_robot"), (_short_array, "u_robot"),
])
def test_corrupt_chunk_report_names_it_and_resume_repairs(damage, why, tmp_path, tiny_sweep,
                                                          capsys, fake_loop):
    ref, out = tmp_path / "ref", tmp_path / "o"
    _run_ok(capsys, tiny_sweep, ref)
    _run_ok(capsys, tiny_sweep, out)
    bad = out / "chunks" / "chunk_00002.npz"
    damage(bad)
    code, _, err = cli(capsys, "report", out)
    line = _one_line_error(code, err)
    assert "chunk_00002.npz" in line and why in line and "--resume" in line
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", out, "--batch", "1", "--no-report",
                       "--resume")
    assert code == 0 and "chunk_00002.npz" in err and "simulating it again" in err
    assert "chunk_00001.npz" not in err
    for f in sorted((ref / "chunks").iterdir()):
        assert f.read_bytes() == (out / "chunks" / f.name).read_bytes(), f.name
    assert (ref / "summary.csv").read_bytes() == (out / "summary.csv").read_bytes()
    code, _, err = cli(capsys, "report", out)
    assert code == 0, err


@pytest.mark.parametrize("mask,mode", [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)])
def test_results_files_respect_the_umask(mask, mode, tmp_path, tiny_sweep, capsys, fake_loop):
    old = os.umask(mask)
    try:
        _run_ok(capsys, tiny_sweep, tmp_path / "o")
    finally:
        os.umask(old)
    for name in ("manifest.json", "summary.csv", "chunks/chunk_00000.npz"):
        assert (tmp_path / "o" / name).stat().st_mode & 0o777 == mode, name


_SLOW_CALLS = []


def slow_simulate(configs):
    """The fake closed loop, one second per chunk (time to send a signal); with
    ``HLIP_TEST_GATE`` set, every chunk after the first also waits (at most 120 s) for that file
    to exist, so a test can act while the run is surely still going."""
    import time

    from test_store import fake_simulate
    time.sleep(1.0)
    gate = os.environ.get("HLIP_TEST_GATE")
    if gate and _SLOW_CALLS:
        deadline = time.monotonic() + 120
        while not os.path.exists(gate) and time.monotonic() < deadline:
            time.sleep(0.05)
    _SLOW_CALLS.append(len(configs))
    return fake_simulate(configs)


def _slow_run(sweep_file, out, gate=None):
    """Start a slow run (one second per chunk; its later chunks held until the file ``gate``
    exists, where given) and return once its first chunk is stored."""
    import time
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")]),
               HLIP_SWEEP_SIMULATE="test_cli:slow_simulate", MPLBACKEND="Agg")
    if gate is not None:
        env["HLIP_TEST_GATE"] = str(gate)
    proc = subprocess.Popen([sys.executable, "-m", "hlip_jax.presentation.cli", "run", str(sweep_file), "--out",
                             str(out), "--batch", "1", "--quiet", "--no-report"], env=env,
                            text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while not (out / "chunks" / "chunk_00000.npz").exists() and time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.05)
    return proc


def test_two_concurrent_runs_the_second_exits_2(tmp_path, tiny_sweep, capsys, fake_loop):
    """The second run exits 2 naming the first's pid; the first's chunks equal those of an
    uninterrupted run made the same way (a subprocess: in this process other test modules may
    have switched JAX to float64, which changes the stored arrays)."""
    ref, out = tmp_path / "ref", tmp_path / "o"
    r0 = hs("run", tiny_sweep, "--out", ref, "--quiet", "--batch", "1", "--no-report")
    assert r0.returncode == 0, r0.stderr
    gate = tmp_path / "go"
    first = _slow_run(tiny_sweep, out, gate)       # held after its first chunk until `gate`
    try:
        r = hs("run", tiny_sweep, "--out", out, "--overwrite", "--quiet", "--batch", "1")
    finally:
        gate.write_text("")
    line = _one_line_error(r.returncode, r.stderr)
    assert f"pid {first.pid}" in line
    _, err = first.communicate(timeout=120)
    assert first.returncode == 0, err
    for f in sorted((ref / "chunks").iterdir()):
        assert f.read_bytes() == (out / "chunks" / f.name).read_bytes(), f.name
    assert json.loads((out / "manifest.json").read_text())["status"] == "complete"


@pytest.mark.parametrize("sig, code", [("SIGTERM", 143), ("SIGHUP", 129)])
def test_sigterm_leaves_an_incomplete_run_to_resume(tmp_path, tiny_sweep, sig, code):
    """SIGTERM, and SIGHUP (the terminal closed; round 8, D10: it ended a run without a word),
    end a run with one line naming the signal and how to resume, exit 128 + the signal."""
    import signal
    out = tmp_path / "o"
    proc = _slow_run(tiny_sweep, out)
    proc.send_signal(getattr(signal, sig))
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == code and sig in err and "Traceback" not in err, err
    assert "--resume" in err
    assert json.loads((out / "manifest.json").read_text())["status"] == "incomplete"


def collide_simulate(configs):
    """The fake closed loop with every step 0.5 m inside an obstacle (a finished run that hit
    one)."""
    from test_store import fake_simulate
    log = fake_simulate(configs)
    log.clearance[...] = -0.5
    return log


def test_negative_clearance_is_a_collision_in_summary_and_report(tmp_path, tiny_sweep, capsys,
                                                                monkeypatch):
    monkeypatch.setenv("HLIP_SWEEP_SIMULATE", "test_cli:collide_simulate")
    out = tmp_path / "o"
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", out, "--quiet")
    assert code == 0, err
    rows = (out / "summary.csv").read_text()
    assert ",collision," in rows and ",ok," not in rows
    assert "every scenario finished ok" not in (out / "report.md").read_text()


@pytest.mark.parametrize("args,frag", [
    (["run", "{sweep}", "--limit", "0"], "--limit"),
    (["run", "{sweep}", "--limit", "x"], "--limit"),
    (["run", "{sweep}", "--batch", "-1"], "--batch"),
    (["run", "{sweep}", "--duration", "nan"], "--duration"),
    (["run", "{sweep}", "--duration", "inf"], "--duration"),
    (["show", "{sweep}", "--plant", "atlas"], "--plant"),
    (["run"], "SWEEP"),
    (["frobnicate"], "invalid choice"),
])
def test_command_line_mistakes(args, frag, tiny_sweep, capsys):
    code, _, err = cli(capsys, *[a.format(sweep=tiny_sweep) for a in args])
    assert code == 2 and frag in err and "Traceback" not in err


@pytest.mark.parametrize("setup,frag", [
    ("file", "not a directory; give a results directory"),
    ("empty", "not a results directory"),
    ("bad_manifest", "unreadable manifest"),
])
def test_report_on_a_non_results_directory(setup, frag, tmp_path, capsys):
    d = tmp_path / "d"
    if setup == "file":
        d.write_text("x")
    else:
        d.mkdir()
    if setup == "bad_manifest":
        (d / "manifest.json").write_text("{not json")
    code, _, err = cli(capsys, "report", d)
    assert frag in _one_line_error(code, err)


def test_resume_and_overwrite_together(tmp_path, tiny_sweep, capsys, fake_loop):
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", tmp_path / "o", "--resume",
                       "--overwrite")
    assert "exclude each other" in _one_line_error(code, err)


def _run_two_processes(sw, out, timeout: int) -> None:
    """`hlip-sweep run SWEEP --distributed` as two processes of one CPU device each on this
    host (jax.distributed through JAX_COORDINATOR_ADDRESS / JAX_NUM_PROCESSES /
    JAX_PROCESS_ID, a free port), both asserted to exit 0."""
    import socket
    with socket.socket() as s:
        s.bind(("localhost", 0))
        port = s.getsockname()[1]
    env = dict(os.environ, JAX_PLATFORMS="cpu", JAX_COORDINATOR_ADDRESS=f"localhost:{port}",
               JAX_NUM_PROCESSES="2", MPLBACKEND="Agg",
               XLA_FLAGS="--xla_force_host_platform_device_count=1")
    env.pop("HLIP_SWEEP_SIMULATE", None)
    cmd = [sys.executable, "-m", "hlip_jax.presentation.cli", "run", str(sw), "--out", str(out),
           "--no-report", "--quiet", "--distributed"]
    procs = [subprocess.Popen(cmd, env=dict(env, JAX_PROCESS_ID=str(i)), cwd=ROOT, text=True,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE) for i in (0, 1)]
    for p in procs:
        _, err = p.communicate(timeout=timeout)
        assert p.returncode == 0, err


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_two_process_distributed_run_equals_one_process(tmp_path):
    """`--distributed` with two processes on this host (one CPU device each; jax.distributed
    through JAX_COORDINATOR_ADDRESS / JAX_NUM_PROCESSES / JAX_PROCESS_ID) writes the same
    chunks and summary as one process of two CPU devices (the same two scenarios per device:
    in float32 the numbers depend on the scenarios per device; the real H-LIP closed loop, 4
    scenarios of 2 s)."""
    sw = tmp_path / "dist.toml"
    sw.write_text('[base]\nduration = 2.0\n[[paths]]\nshape = "line"\n[grid.product]\n'
                  '"gain.type" = ["deadbeat", "lqr"]\n"mpc.alpha" = [0.01, 0.1]\n')
    two_devices = "--xla_force_host_platform_device_count=2"
    one = hs("run", sw, "--out", tmp_path / "one", "--no-report", "--quiet", fake=False,
             env={"XLA_FLAGS": two_devices})
    assert one.returncode == 0, one.stderr
    _run_two_processes(sw, tmp_path / "two", timeout=500)
    for f in sorted((tmp_path / "one" / "chunks").iterdir()):
        assert f.read_bytes() == (tmp_path / "two" / "chunks" / f.name).read_bytes(), f.name
    assert ((tmp_path / "one" / "summary.csv").read_bytes()
            == (tmp_path / "two" / "summary.csv").read_bytes())


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_two_process_distributed_cassie_equals_one_process_of_two_devices(tmp_path):
    """The Cassie plant under `--distributed`, two processes of one CPU device each, against
    one process of two CPU devices (the same two scenarios per device): the same statuses and
    the same step logs, bit for bit.  Before MJX's model was put on each process's own device
    (hlip_jax.plants.cassie.model.put), the second process failed to compile the closed loop
    (its model lived on process 0's device)."""
    sw = tmp_path / "dist.toml"
    sw.write_text('[base]\nplant = "cassie"\nduration = 0.6\n[[paths]]\nshape = "line"\n'
                  '[grid.product]\nseed = [1, 2, 3, 4]\n')
    one = hs("run", sw, "--out", tmp_path / "one", "--no-report", "--quiet", fake=False,
             timeout=800, env={"XLA_FLAGS": "--xla_force_host_platform_device_count=2"})
    assert one.returncode == 0, one.stderr
    _run_two_processes(sw, tmp_path / "two", timeout=800)
    a, b = store.load_log(tmp_path / "one"), store.load_log(tmp_path / "two")
    assert a["status"].tolist() == b["status"].tolist() == [0, 0, 0, 0]
    for k in ("x_robot", "u_robot", "e", "valid", "t_plant"):
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def test_distributed_process_id_must_be_an_integer(tmp_path, tiny_sweep, capsys, fake_loop,
                                                   monkeypatch):
    monkeypatch.setenv("JAX_PROCESS_ID", "first")
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", tmp_path / "o", "--distributed")
    assert "JAX_PROCESS_ID" in _one_line_error(code, err)


@pytest.mark.parametrize("args,frag", [
    (["ticks", "{out}", "99"], "SCENARIO"),
    (["ticks", "{out}", "no-such-scenario"], "SCENARIO"),
    (["report", "{out}", "--heatmap", "nope", "path"], "nope"),
])
def test_mistakes_on_a_results_directory(args, frag, tmp_path, tiny_sweep, capsys, fake_loop):
    out = tmp_path / "o"
    _run_ok(capsys, tiny_sweep, out)
    code, _, err = cli(capsys, *[a.format(out=out) for a in args])
    assert frag in _one_line_error(code, err)


def test_coverage_command(tmp_path, tiny_sweep, capsys, fake_loop):
    """`hlip-sweep coverage DIR` rewrites coverage.csv with the asked split and level; bad
    levels, splits and warm-ups, malformed or unknown --train-on fields exit 2 with one line
    naming the option."""
    out = tmp_path / "o"
    _run_ok(capsys, tiny_sweep, out)
    code, text, _ = cli(capsys, "coverage", out, "--train-on", "path=circle", "--q", "0.8")
    assert code == 0 and "coverage:" in text
    rows = list(csv.DictReader((out / "coverage.csv").open()))
    assert rows and all(r["split"] == "path in ['circle']" for r in rows)
    assert {float(r["q"]) for r in rows if r["w_method"] == "conformal_step"} == {0.8}
    for args, field in ((["--q", "1.0"], "--q"), (["--train-on", "path"], "--train-on"),
                        (["--train-on", "nofield=1"], "nofield"), (["--split", "time"], "--split"),
                        (["--warmup", "-2"], "--warmup")):
        code, _, err = cli(capsys, "coverage", out, *args)
        assert code == 2 and field in err and "Traceback" not in err
    # every path on the training side: no test run anywhere, one line, the file kept
    before = (out / "coverage.csv").read_bytes()
    code, _, err = cli(capsys, "coverage", out, "--train-on", "path=circle,line")
    assert "leaves no test run" in _one_line_error(code, err)
    assert (out / "coverage.csv").read_bytes() == before
    code, _, err = cli(capsys, "coverage", tmp_path / "missing")
    assert code == 2 and "not found" in err


def test_s2s_fit_command(tmp_path, tiny_sweep, capsys, fake_loop):
    code, _, err = cli(capsys, "s2s", tmp_path / "nope")
    assert code == 2 and "not found" in err
    out = tmp_path / "r"
    _run_ok(capsys, tiny_sweep, out)
    code, _, err = cli(capsys, "s2s", out, "--scenarios", "no-such-path")
    assert code == 2 and "--scenarios" in err and "matches none" in err
    code, _, err = cli(capsys, "s2s", out, "--scenarios", "(")
    assert code == 2 and "--scenarios" in err
    code, _, err = cli(capsys, "s2s", out, "--skip", "-1")
    assert code == 2 and "--skip" in err
    code, text, err = cli(capsys, "s2s", out, "--scenarios", "line")
    assert code == 0, err
    assert "2 scenarios" in text and text.count("H-LIP") == 4


def test_wbox_prints_sweep_lines_of_the_w_box(tmp_path, capsys):
    """`wbox` reads coverage.csv and prints [base.mpc] lines that a sweep file accepts: the
    symmetric enclosure of the groups' W, rounded up to 1e-4; bad input exits 2."""
    import tomllib

    from hlip_jax.sweepio import sweep
    d = tmp_path / "res"
    d.mkdir()
    rows = [("a", "sagittal", "-0.01 -0.05 -0.1", "0.02001 0.01 0.03"),
            ("a", "lateral", "-0.003 -0.002 -0.02", "0.001 0.004 0.005"),
            ("b", "sagittal", "-0.005 -0.07 -0.01", "0.004 0.06 0.12"),
            ("b", "lateral", "-0.001 -0.001 -0.001", "0.002 0.003 0.03")]
    with open(d / "coverage.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["group", "plane", "w_method", "level", "state", "w_lo", "w_hi"])
        for g, p, lo, hi in rows:
            w.writerow([g, p, "box", "run", "[c, p, v]", lo, hi])
    code, out, _ = cli(capsys, "wbox", d)
    assert code == 0
    mpc = tomllib.loads(out)["base"]["mpc"]
    assert mpc == {"w_frame": "heading", "w_c_1": 0.0201, "w_p_1": 0.07, "w_v_1": 0.12,
                   "w_c_2": 0.003, "w_p_2": 0.004, "w_v_2": 0.03}
    sweep_file = tmp_path / "tube.toml"
    sweep_file.write_text('name = "tube"\n[base]\nplant = "hlip"\n' + out.split("[base.mpc]")[1].join(
        ["[base.mpc]\nrobust = true", ""]) + '\n[[paths]]\nname = "l"\nshape = "line"\n')
    sc = sweep.load_sweep(sweep_file).scenarios[0]
    assert sc.mpc.robust and sc.mpc.w_c_1 == 0.0201 and sc.mpc.w_v_2 == 0.03
    code, out, _ = cli(capsys, "wbox", d, "--group", "b")
    assert code == 0 and "w_c_1 = 0.0050" in out
    for args, msg in ((["--group", "c"], "allowed: a, b"), (["--method", "x"], "allowed: box"),):
        code, _, err = cli(capsys, "wbox", d, *args)
        assert code == 2 and msg in err
    code, _, err = cli(capsys, "wbox", tmp_path)
    assert code == 2 and "coverage.csv" in err


def test_whull_writes_the_hull_w_a_sweep_reads(tmp_path, tiny_sweep, capsys, fake_loop):
    """`whull` pools the runs' disturbances, writes the vertices of their symmetric hull
    (every support of the samples kept, 1e-8: the file's 9 significant digits) and prints
    [base.mpc] lines that a tube sweep accepts; bad input exits 2 and nothing is overwritten."""
    import tomllib

    import numpy as np

    from hlip_jax.core import robust
    from hlip_jax.sweepio import store, sweep
    out = tmp_path / "o"
    _run_ok(capsys, tiny_sweep, out)
    hull = tmp_path / "w" / "hull.csv"
    code, text, err = cli(capsys, "whull", out, "--out", hull, "--scenarios", "circle")
    assert code == 0, err
    names = [c["name"] for c in store.read_manifest(out)["configs"]]
    chosen = [i for i, n in enumerate(names) if "circle" in n]
    _, samples, runs = store.disturbance_samples(out, chosen)
    assert runs == len(chosen) == 2
    points = robust.read_hull(hull)
    D = np.random.default_rng(0).normal(size=(2000, 3))
    for S, V in zip(samples, points):
        np.testing.assert_allclose(np.abs(V @ D.T).max(0), np.abs(S @ D.T).max(0), atol=1e-8)
    mpc = tomllib.loads(text)["base"]["mpc"]
    assert mpc["w_shape"] == "hull" and mpc["w_hull_file"] == str(hull)
    lines = "".join(f'{k} = "{v}"\n' for k, v in mpc.items())
    sc = sweep.parse_sweep('name = "t"\n[base]\nplant = "hlip"\n[base.mpc]\nrobust = true\n' + lines
                           + '[[paths]]\nname = "l"\nshape = "line"\n').scenarios[0]
    assert sc.mpc.w_shape == "hull"
    before = hull.read_bytes()
    for args, msg in ((["--out", hull], "exists"), (["--out", tmp_path / "x.csv", "--scenarios", "zz"],
                                                     "matches none")):
        code, _, err = cli(capsys, "whull", out, *args)
        assert code == 2 and msg in err and "Traceback" not in err
    assert hull.read_bytes() == before
    code, _, err = cli(capsys, "whull", tmp_path / "nope", "--out", tmp_path / "y.csv")
    assert code == 2 and "not found" in err


def test_run_ticks_refuses_bad_choices_before_running(tmp_path, tiny_sweep, capsys, fake_loop):
    # --ticks is checked against the sweep before anything is simulated or written: a
    # malformed pattern, no matching name, a plant without a tick log (the tiny sweep is
    # H-LIP) and --distributed are each a one-line error naming the option, exit 2
    out = tmp_path / "r"
    for args, msg in ((["--ticks", "("], "not a regular expression"),
                      (["--ticks", "zz-no-such"], "matches none"),
                      (["--ticks", "."], "keeps no per-tick log"),
                      (["--ticks", ".", "--distributed"], "exclude each other")):
        code, _, err = cli(capsys, "run", tiny_sweep, "--out", out, "--quiet", *args)
        assert "--ticks" in _one_line_error(code, err) and msg in err, err
        assert not out.exists()


def test_bench_variant_flags_take_the_config_choices(capsys):
    # the bench's variant flags offer exactly the sweep file's values (one list, in config), and
    # the condensation's and the terms' lists there are the modules' own
    from hlip_jax.presentation import cli
    from hlip_jax.simulation import config
    from hlip_jax.plants.cassie import dynamics, model
    spec = lambda f: tuple(config.field_spec(cli._field_table(f)[1], f)["choices"])
    assert spec("condense") == dynamics.SOLVES and spec("terms") == model.TERMS
    assert cli._field_table("physics")[0] == "impl" and cli._field_table("qp_rho_start")[0] == "cassie"
    ap = cli.build_parser()
    bench = next(a for a in ap._subparsers._group_actions[0].choices["bench"]._actions
                 if a.dest == "terms")
    assert tuple(bench.choices) == model.TERMS and bench.default == ["mjx"]
    for field, *_ in cli._BENCH_VARIANTS:
        with pytest.raises(SystemExit) as exc:
            main(["bench", "--" + field.replace("_", "-"), "nonsense"])
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert all(repr(c) in err for c in spec(field)), (field, err)


def test_control_characters_never_reach_the_terminal(tmp_path, capsys, fake_loop):
    """A description and a path name holding an escape sequence: `show` and the one-line
    error print it escaped (\\x1b), never the raw control character."""
    p = tmp_path / "esc.toml"
    p.write_text('description = "red \\u001b[31m text"\n[[paths]]\nshape = "line"\n')
    code, out, _ = cli(capsys, "show", p)
    assert code == 0 and "\x1b" not in out and "\\x1b[31m" in out
    p.write_text('[[paths]]\nshape = "line"\nname = "a\\u001b[2J"\n')
    code, _, err = cli(capsys, "show", p)
    assert code == 2 and "\x1b" not in err and "\\x1b" in err


def test_out_that_is_not_a_results_directory_and_resume_without_a_run(tmp_path, tiny_sweep,
                                                                     capsys, fake_loop):
    """A user's own directory as --out: refused, the user's file untouched; --resume into a
    directory that holds no run: refused, not started fresh; --overwrite removes the old run's
    report, figures and per-tick logs too."""
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "summary.csv").write_text("my own data\n")
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", mine, "--quiet")
    assert "not a results directory" in _one_line_error(code, err)
    assert (mine / "summary.csv").read_text() == "my own data\n"
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", tmp_path / "new", "--resume", "--quiet")
    assert "no run to resume" in _one_line_error(code, err)
    # process 0 of a --distributed run finds the other processes' private stores already there
    dist = tmp_path / "dist"
    (dist / ".process-1" / "chunks").mkdir(parents=True)
    _run_ok(capsys, tiny_sweep, dist)
    out = tmp_path / "o"
    _run_ok(capsys, tiny_sweep, out)
    for name in ("figures", "ticks"):
        (out / name).mkdir(exist_ok=True)
        (out / name / "old.png").write_text("old")
    (out / "report.html").write_text("old report")
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", out, "--overwrite", "--quiet",
                       "--no-report")
    assert code == 0, err
    assert not (out / "report.html").exists() and not (out / "figures").exists()
    assert not (out / "ticks").exists() and (out / "summary.csv").is_file()


@pytest.mark.parametrize("text,frag", [
    (b"[1, 2]", "expected a JSON object"),
    (b'{"batch": 2, "n_scenarios": 2}', "'configs'"),
    (b'{"configs": [{}, {}], "n_scenarios": 2}', "'batch'"),
    (b'{"configs": [{}], "batch": 1, "n_scenarios": 10}', "n_scenarios"),
    (b"\xff\xfe not utf-8", "unreadable manifest"),
    # a scenario config without the keys the summary reads was a KeyError traceback
    (b'{"configs": [{"name": "a", "plant": "hlip", "seed": 1, "path": {"shape": "line"}}], '
     b'"batch": 1, "n_scenarios": 1}', "configs[0]: 'swept' is missing or not a table"),
    (b'{"configs": [{"name": 7, "plant": "hlip", "seed": 1, "swept": {}, '
     b'"path": {"shape": "line"}}], "batch": 1, "n_scenarios": 1}', "configs[0]: 'name'"),
])
def test_a_damaged_manifest_is_one_line(text, frag, tmp_path, tiny_sweep, capsys, fake_loop):
    out = tmp_path / "o"
    _run_ok(capsys, tiny_sweep, out)
    (out / "manifest.json").write_bytes(text)
    for cmd in ("report", "coverage"):
        code, _, err = cli(capsys, cmd, out)
        assert frag in _one_line_error(code, err) and "manifest.json" in err


def test_a_hull_w_file_must_be_a_small_regular_file(tmp_path):
    """A FIFO or a device as mpc.w_hull_file is refused before it is opened (it would block
    or never end), as is a file over the size limit."""
    from hlip_jax.core import robust
    fifo = tmp_path / "w.fifo"
    os.mkfifo(fifo)
    for path in (fifo, "/dev/zero"):
        with pytest.raises(ValueError, match="not a regular file"):
            robust.read_hull(path)
    big = tmp_path / "big.csv"
    with open(big, "wb") as f:
        f.truncate(robust.HULL_FILE_MAX_BYTES + 1)
    with pytest.raises(ValueError, match="at most"):
        robust.read_hull(big)


def test_a_summary_cut_to_its_header_is_refused_and_rewritten_once_deleted(tmp_path, tiny_sweep,
                                                                          capsys, fake_loop):
    out = tmp_path / "o"
    _run_ok(capsys, tiny_sweep, out)
    whole = (out / "summary.csv").read_text()
    (out / "summary.csv").write_text(whole.splitlines()[0] + "\n")
    code, _, err = cli(capsys, "report", out)
    assert "summary.csv" in _one_line_error(code, err) and "rows" in err
    (out / "summary.csv").unlink()
    code, _, err = cli(capsys, "report", out)
    assert code == 0, err
    assert (out / "summary.csv").read_text() == whole


@pytest.mark.parametrize("name,data,frag", [
    ("coverage.csv", b"garbage,,x\n", "not a coverage table"),
    ("coverage.csv", b"a\x00b\n", "rewrite it with"),
    ("coverage.csv", b"\xff\xfe\x00", "rewrite it with"),
    ("ticks/3.json", b"{garbage", "not a per-tick record"),
    ("ticks/3.json", b"[1, 2]", "not a per-tick record"),
])
def test_damaged_results_files_are_one_line(name, data, frag, tmp_path, tiny_sweep, capsys,
                                            fake_loop):
    out = tmp_path / "o"
    _run_ok(capsys, tiny_sweep, out)
    (out / name).parent.mkdir(exist_ok=True)
    (out / name).write_bytes(data)
    code, _, err = cli(capsys, "report", out)
    assert frag in _one_line_error(code, err) and name.split("/")[-1] in err


def test_run_refuses_a_huge_grid_before_building_it_and_a_dangling_out(tmp_path, capsys):
    """A 9,999,000-scenario grid is refused in one line naming the limit and the flag before any
    scenario is built (the check reads the grid's count); --max-scenarios raises the limit; an
    --out that is a symbolic link to nothing is named as such."""
    import time
    seeds = ", ".join(str(i) for i in range(9999))
    alphas = ", ".join(str(0.001 * (i + 1)) for i in range(1000))
    p = tmp_path / "huge.toml"
    p.write_text('name = "huge"\n[base]\nplant = "hlip"\nduration = 2.0\n[[paths]]\n'
                 f'shape = "line"\n[grid.product]\nseed = [{seeds}]\n"mpc.alpha" = [{alphas}]\n')
    t0 = time.perf_counter()
    assert main(["run", str(p), "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert "9999000 scenarios; allowed: at most 65536 per run (--max-scenarios N" in err
    assert time.perf_counter() - t0 < 30 and not (tmp_path / "r").exists()
    assert main(["run", str(p), "--out", str(tmp_path / "r"), "--max-scenarios", "1000"]) == 2
    assert "at most 1000 per run" in capsys.readouterr().err
    small = tmp_path / "small.toml"
    small.write_text('name = "s"\n[base]\nplant = "hlip"\nduration = 2.0\n[[paths]]\n'
                     'shape = "line"\n')
    (tmp_path / "dangling").symlink_to(tmp_path / "nowhere")
    capsys.readouterr()
    assert main(["run", str(small), "--out", str(tmp_path / "dangling")]) == 2
    assert "a symbolic link to a missing path" in capsys.readouterr().err
    assert not (tmp_path / "nowhere").exists()


def test_a_summary_with_swapped_or_edited_scenario_cells_is_refused(tmp_path, tiny_sweep, capsys,
                                                                    fake_loop):
    """summary.csv with two rows' names swapped (same row count) was reported as if right, each
    row's numbers under the other scenario's name: exit 2 naming the line and the column; once
    rewritten from the chunks it reads back with the right names."""
    out = tmp_path / "o"
    _run_ok(capsys, tiny_sweep, out)
    rows = list(csv.reader((out / "summary.csv").open(newline="")))
    k = rows[0].index("name")
    names = [r[k] for r in rows[1:]]
    rows[1][k], rows[2][k] = rows[2][k], rows[1][k]
    with (out / "summary.csv").open("w", newline="") as fh:
        csv.writer(fh, lineterminator="\n").writerows(rows)
    code, _, err = cli(capsys, "report", out)
    line = _one_line_error(code, err)
    assert "summary.csv: line 2: column 'name' of scenario 0" in line and "manifest says" in line
    assert not (out / "report.md").exists()
    store.write_summary(out)                  # what `report` does once it is deleted
    assert [r["name"] for r in store.read_summary(out)] == names


def test_non_ascii_digits_are_not_indices(tmp_path, tiny_sweep, capsys, fake_loop):
    """'²' passes str.isdigit but not int(): `ticks DIR ²` and a results file ticks/²².json
    were tracebacks; now the scenario is refused in one line and the stray file is skipped."""
    out = tmp_path / "o"
    _run_ok(capsys, tiny_sweep, out)
    code, _, err = cli(capsys, "ticks", out, "²")
    assert "SCENARIO" in _one_line_error(code, err)
    (out / "ticks").mkdir()
    (out / "ticks" / "²².json").write_text("{}")
    code, _, err = cli(capsys, "report", out)
    assert code == 0, err


def test_an_interrupted_report_does_not_speak_of_chunks(tmp_path, tiny_sweep, capsys, fake_loop,
                                                        monkeypatch):
    """Ctrl-C during `report` said 'finished chunks are kept: rerun with --resume' (run's
    advice); it now says to run the report again (exit 130)."""
    out = tmp_path / "o"
    _run_ok(capsys, tiny_sweep, out)
    from hlip_jax.presentation import report

    def interrupted(*a, **k):
        raise KeyboardInterrupt
    monkeypatch.setattr(report, "write_report", interrupted)
    code, _, err = cli(capsys, "report", out)
    assert code == 130 and "run `hlip-sweep report` again" in err and "--resume" not in err


def test_a_refused_out_is_left_as_it_was(tmp_path, tiny_sweep, capsys, fake_loop):
    """`run --out DIR` refused because DIR is not a results directory (a user's folder, the
    sweeps folder, `/`) left a `.lock` file in it; `--resume` into a missing directory left
    that directory behind. Both are now left exactly as they were."""
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", mine, "--quiet")
    assert "not a results directory" in _one_line_error(code, err)
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]
    code, _, err = cli(capsys, "run", tiny_sweep, "--out", tmp_path / "new", "--resume", "--quiet")
    assert "--resume" in _one_line_error(code, err)
    assert not (tmp_path / "new").exists()
