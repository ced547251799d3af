"""The CLI's XLA settings (hlip_jax.runtime.xla_flags): deterministic GPU operations and one CPU device
per core, each unless the user's environment already chooses."""

from hlip_jax.presentation import cli
from hlip_jax.runtime import xla_flags


def test_flag_added_unless_the_user_chose():
    f = xla_flags.FLAG
    assert xla_flags.with_deterministic_ops("") == f"{f}=true"
    assert xla_flags.with_deterministic_ops("--xla_dump_to=/tmp/x") == f"--xla_dump_to=/tmp/x {f}=true"
    for chosen in (f"{f}=false", f"--a=1 {f}=true", f"{f}=false --b=2"):
        assert xla_flags.with_deterministic_ops(chosen) == chosen
    assert xla_flags.with_deterministic_ops(f"{f}_x=1") == f"{f}_x=1 {f}=true"   # another flag
    env = {}
    xla_flags.apply(env, cores=1)
    xla_flags.apply(env, cores=1)                            # idempotent
    assert env == {"XLA_FLAGS": f"{f}=true"}


def test_one_cpu_device_per_core_with_a_larger_thread_pool():
    """N cores: N CPU devices and a pool of 2N threads (more threads than devices: jaxlib
    0.10's LAPACK kernels wait on the pool); a user's own device count or pool size stays."""
    d = xla_flags.DEVICES_FLAG
    env = {}
    xla_flags.apply(env, cores=4)
    assert f"{d}=4" in env["XLA_FLAGS"].split() and env["PJRT_NPROC"] == "8"
    xla_flags.apply(env, cores=4)                            # idempotent
    assert env["XLA_FLAGS"].count(d) == 1
    env = {"XLA_FLAGS": f"{d}=1"}                            # the user's choice: one device
    xla_flags.apply(env, cores=4)
    assert f"{d}=1" in env["XLA_FLAGS"].split() and "PJRT_NPROC" not in env
    env = {"XLA_FLAGS": f"{d}=6", "NPROC": "3"}              # the user's pool
    xla_flags.apply(env, cores=2)
    assert f"{d}=6" in env["XLA_FLAGS"].split() and "PJRT_NPROC" not in env
    env = {"XLA_FLAGS": f"{d}=3"}                            # more devices than cores
    xla_flags.apply(env, cores=2)
    assert env["PJRT_NPROC"] == "6"
    assert xla_flags.cpu_devices(f"--a=1 {d}=5") == 5 and xla_flags.cpu_devices("") == 1
    assert xla_flags.usable_cores() >= 1


def test_the_cli_sets_it_before_running(monkeypatch, capsys):
    monkeypatch.delenv("XLA_FLAGS", raising=False)
    monkeypatch.delenv("PJRT_NPROC", raising=False)
    assert cli.main(["list"]) == 0
    import os
    assert f"{xla_flags.FLAG}=true" in os.environ["XLA_FLAGS"]
    monkeypatch.setenv("XLA_FLAGS", f"{xla_flags.FLAG}=false")
    assert cli.main(["list"]) == 0
    flags = os.environ["XLA_FLAGS"].split()
    assert f"{xla_flags.FLAG}=false" in flags and f"{xla_flags.FLAG}=true" not in flags


def test_a_pool_size_that_is_not_an_ascii_count_counts_as_unset():
    """NPROC='²' (str.isdigit, but int() refuses it) kept hlip-sweep from sizing the pool and
    the run stopped in a traceback: it now counts as unset, and '²' as a device count is
    ignored as well."""
    env = {"NPROC": "²"}
    xla_flags.apply(env, cores=2)
    assert env["PJRT_NPROC"] == "4"
    assert xla_flags.cpu_pool_threads({"NPROC": "²"}) == xla_flags.usable_cores()
    assert xla_flags.cpu_devices(f"{xla_flags.DEVICES_FLAG}=²") == 1


def test_a_user_pool_too_small_for_the_devices_is_one_line(monkeypatch, capsys):
    """NPROC=2 set by the user on a 2-core machine (2 CPU devices): the guard against jaxlib
    0.10's hang stopped `run` in a traceback; it is now one line, exit 2."""
    def refuse(args):
        raise xla_flags.PoolTooSmall("the batch is split over 2 CPU devices ... PJRT_NPROC=4")
    monkeypatch.setattr(cli, "cmd_list", refuse)
    assert cli.main(["list"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "PJRT_NPROC=4" in err and "Traceback" not in err


def test_a_flag_xla_does_not_know_is_refused_in_one_line_exit_2(tmp_path):
    """XLA ends the process (a fatal log line, exit 1) on an unknown flag; the CLI finds it in a
    probe process first and exits 2 with one line naming XLA_FLAGS and the flag."""
    import os
    import subprocess
    import sys
    env = dict(os.environ, XLA_FLAGS="--xla_no_such_flag_here=1")
    r = subprocess.run([sys.executable, "-m", "hlip_jax", "show", "paper_hlip"], env=env,
                       capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "XLA_FLAGS" in lines[0] and "--xla_no_such_flag_here=1" in lines[0]
    assert xla_flags.refused("--xla_no_such_flag_here=1") is not None


def test_only_the_modules_own_flags_need_no_probe(monkeypatch):
    """Flags this module reads are checked by problem(); refused() starts no process for them."""
    def no_process(*a, **k):
        raise AssertionError("a probe process was started")
    monkeypatch.setattr(xla_flags.subprocess, "run", no_process)
    assert xla_flags.refused(f"{xla_flags.FLAG}=true {xla_flags.DEVICES_FLAG}=2") is None
    assert xla_flags.refused("") is None
