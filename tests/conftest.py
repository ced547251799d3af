"""Shared test fixtures, and the suite's one numeric setting: JAX runs in float64.

The numerical tests compare against closed forms, OSQP, C MuJoCo and finite differences at
tolerances only float64 reaches, so x64 is switched on here, once, before any test module is
imported (a test module that switched it itself would change the setting for every module
collected after it).  A test of float32 behaviour runs its program in a subprocess or casts
explicitly; ``float64`` below keeps tests that need x64 correct when run alone."""

import jax
import pytest

jax.config.update("jax_enable_x64", True)
# Start the backend now, with the environment pytest was given: a test that runs the CLI
# in-process sets XLA_FLAGS (one CPU device per core, hlip_jax.runtime.xla_flags), and a backend
# started after that would split every later test's batch over the cores.
jax.devices()


def _x64(enabled: bool):
    """JAX's float64 switch set to ``enabled`` for the test, restored afterwards."""
    old = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", enabled)
    try:
        yield
    finally:
        jax.config.update("jax_enable_x64", old)


@pytest.fixture
def float64():
    """Run the test with JAX's float64 enabled (restored afterwards)."""
    yield from _x64(True)


@pytest.fixture
def float32():
    """Run the test without x64, JAX's default (restored afterwards)."""
    yield from _x64(False)


@pytest.fixture(autouse=True, scope="session")
def _private_compile_cache(tmp_path_factory):
    """The CLI's persistent compilation cache (hlip_jax.runtime.compile_cache) goes to a directory of
    this test session, never the user's, also for CLI subprocesses (they inherit the
    variable)."""
    import os
    old = os.environ.get("HLIP_JAX_CACHE_DIR")
    os.environ["HLIP_JAX_CACHE_DIR"] = str(tmp_path_factory.mktemp("xla_cache"))
    yield
    if old is None:
        os.environ.pop("HLIP_JAX_CACHE_DIR", None)
    else:
        os.environ["HLIP_JAX_CACHE_DIR"] = old


@pytest.fixture(autouse=True)
def _trace_cache_off_after_each_test():
    """The traced-program cache (hlip_jax.runtime.trace_cache) ends every test off and empty: a test
    that runs the CLI in-process turns it on (with the compilation cache), and the tests
    after it would otherwise take its path or not depending on their order."""
    yield
    from hlip_jax.runtime import trace_cache
    trace_cache.disable()


@pytest.fixture(autouse=True)
def _xla_environment_restored():
    """The CLI sets XLA's environment when it starts (hlip_jax.runtime.xla_flags); a test that runs
    it in-process must not hand those settings to the subprocesses of later tests."""
    import os
    names = ("XLA_FLAGS", "PJRT_NPROC")
    old = {n: os.environ.get(n) for n in names}
    yield
    for n, v in old.items():
        if v is None:
            os.environ.pop(n, None)
        else:
            os.environ[n] = v
