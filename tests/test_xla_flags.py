"""The CLI's XLA flags (hlip_jax.xla_flags): deterministic GPU operations unless the user's
XLA_FLAGS already choose."""

from hlip_jax import cli, xla_flags


def test_flag_added_unless_the_user_chose():
    f = xla_flags.FLAG
    assert xla_flags.with_deterministic_ops("") == f"{f}=true"
    assert xla_flags.with_deterministic_ops("--xla_dump_to=/tmp/x") == f"--xla_dump_to=/tmp/x {f}=true"
    for chosen in (f"{f}=false", f"--a=1 {f}=true", f"{f}=false --b=2"):
        assert xla_flags.with_deterministic_ops(chosen) == chosen
    assert xla_flags.with_deterministic_ops(f"{f}_x=1") == f"{f}_x=1 {f}=true"   # another flag
    env = {}
    xla_flags.apply(env)
    xla_flags.apply(env)                                     # idempotent
    assert env == {"XLA_FLAGS": f"{f}=true"}


def test_the_cli_sets_it_before_running(monkeypatch, capsys):
    monkeypatch.delenv("XLA_FLAGS", raising=False)
    assert cli.main(["list"]) == 0
    import os
    assert f"{xla_flags.FLAG}=true" in os.environ["XLA_FLAGS"]
    monkeypatch.setenv("XLA_FLAGS", f"{xla_flags.FLAG}=false")
    assert cli.main(["list"]) == 0
    assert os.environ["XLA_FLAGS"] == f"{xla_flags.FLAG}=false"
