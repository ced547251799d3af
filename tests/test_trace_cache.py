"""The traced-program cache (:mod:`hlip_jax.trace_cache`): a rerun calls the closed loop
stored on disk instead of tracing it, and gets the numbers of the plain jitted run.

Equality is bit for bit (NaN where the plain run has NaN): the stored program is the same
StableHLO the jitted call lowers to, called through a wrapper that XLA inlines, so any
difference would be a different program, not round-off.
"""

import numpy as np
import pytest

from hlip_jax import compile_cache, rollout, trace_cache
from hlip_jax.config import PathConfig, ScenarioConfig

CONFIGS = [ScenarioConfig(duration=2.0, seed=i, path=PathConfig(shape=s, params=dict(peak_speed=v)))
           for i, (s, v) in enumerate([("circle", 0.3), ("line", 0.5), ("sinusoid", 0.4)])]


@pytest.fixture
def cache(tmp_path):
    """The cache on in a fresh directory with nothing loaded; the process's state restored."""
    old = (trace_cache.directory(), dict(trace_cache._loaded), set(trace_cache._unexportable))
    trace_cache._loaded.clear()
    trace_cache._unexportable.clear()
    trace_cache.enable(tmp_path)
    yield tmp_path
    trace_cache.enable(old[0])
    trace_cache._loaded.clear()
    trace_cache._loaded.update(old[1])
    trace_cache._unexportable.clear()
    trace_cache._unexportable.update(old[2])


def _run(progress: bool, max_iter=None):
    batch, static = rollout.build(CONFIGS)
    static = static._replace(progress=progress)
    if max_iter is not None:
        static = static._replace(settings=static.settings._replace(max_iter=max_iter))
    return rollout.run(batch, static)


def _plain(progress: bool, **kw):
    d = trace_cache.directory()
    trace_cache.enable(None)
    try:
        return _run(progress, **kw)
    finally:
        trace_cache.enable(d)


def _assert_equal(a: dict, b: dict):
    assert a.keys() == b.keys()
    for k in a:
        x, y = np.asarray(a[k]), np.asarray(b[k])
        assert x.dtype == y.dtype and x.shape == y.shape, k
        assert np.array_equal(x, y, equal_nan=np.issubdtype(x.dtype, np.inexact)), k


def _count_traces(monkeypatch) -> list:
    """Count the cache's traces (a program loaded from disk is not traced; jit's own
    in-process trace cache would hide a re-trace from a counter inside the loop)."""
    calls = []
    inner = trace_cache._export

    def counting(*a, **kw):
        calls.append(1)
        return inner(*a, **kw)
    monkeypatch.setattr(trace_cache, "_export", counting)
    return calls


@pytest.mark.parametrize("progress", [False, True], ids=["whole", "segments"])
def test_rerun_loads_the_traced_loop_and_gives_the_same_numbers(cache, monkeypatch, progress):
    calls = _count_traces(monkeypatch)
    first = _run(progress)
    assert len(calls) == (1 if not progress else 2)
    files = sorted(p.name for p in cache.glob("*" + trace_cache.SUFFIX))
    assert len(files) == (1 if not progress else 2)        # whole run; start + segment
    trace_cache._loaded.clear()                              # a new process, as far as it knows
    calls.clear()
    again = _run(progress)
    assert calls == []                                       # nothing traced
    _assert_equal(again, first)
    _assert_equal(first, _plain(progress))


def test_another_setting_is_another_entry(cache):
    _run(False)
    _run(False, max_iter=123)
    assert len(list(cache.glob("*" + trace_cache.SUFFIX))) == 2


def test_a_damaged_entry_is_traced_again(cache, monkeypatch):
    first = _run(False)
    (entry,) = cache.glob("*" + trace_cache.SUFFIX)
    entry.write_bytes(b"not a program")
    trace_cache._loaded.clear()
    calls = _count_traces(monkeypatch)
    again = _run(False)
    assert len(calls) == 1                                  # traced afresh
    _assert_equal(again, first)
    assert entry.read_bytes() != b"not a program"           # and stored again


def test_a_loop_that_cannot_be_exported_runs_plain(cache, monkeypatch):
    def refuse(*a, **kw):
        raise ValueError("no stable ABI")
    monkeypatch.setattr(trace_cache.jax_export, "export", refuse)
    out = _run(False)
    assert list(cache.iterdir()) == []
    assert len(trace_cache._unexportable) == 1
    _assert_equal(out, _plain(False))


def test_key_covers_code_and_refuses_incomplete_settings(cache, monkeypatch):
    import jax
    import numpy as np_
    leaves, tree = jax.tree.flatten((np_.zeros(3),))
    k = trace_cache.key("f", ("a", 1), leaves, tree)
    assert k.startswith("f-")
    assert trace_cache.key("f", ("a", 2), leaves, tree) != k
    f32 = jax.tree.leaves((np_.zeros(3, np_.float32),))
    assert trace_cache.key("f", ("a", 1), f32, tree) != k
    assert trace_cache.key("f", (np_.zeros(5000),), leaves, tree) is None   # repr truncated
    assert trace_cache.key("f", (object(),), leaves, tree) is None          # repr has an address
    monkeypatch.setattr(trace_cache, "code_digest", lambda: "edited")
    assert trace_cache.key("f", ("a", 1), leaves, tree) != k


def test_compile_cache_turns_the_trace_cache_on_beside_it(tmp_path, monkeypatch):
    import jax
    monkeypatch.setattr(jax.config, "update", lambda *a: None)   # keep this process's XLA cache
    old = trace_cache.directory()
    try:
        compile_cache.enable(tmp_path)
        assert trace_cache.directory() == tmp_path / compile_cache.TRACES
    finally:
        trace_cache.enable(old)


def test_segments_compile_ahead_with_the_keys_the_loop_uses(cache, monkeypatch):
    """The start and segment programs are compiled together before the loop, under the keys
    the loop's calls then find (one trace each, no second entry), with the same numbers."""
    calls = _count_traces(monkeypatch)
    ahead = []
    inner = trace_cache._ahead
    monkeypatch.setattr(trace_cache, "_ahead", lambda p: ahead.append(1) or inner(p))
    out = _run(True)
    assert len(calls) == 2 and len(ahead) == 2
    assert len(list(cache.glob("*" + trace_cache.SUFFIX))) == 2
    _assert_equal(out, _plain(True))
