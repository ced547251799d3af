"""The traced-program cache (:mod:`hlip_jax.runtime.trace_cache`): a rerun calls the closed loop
stored on disk instead of tracing it, and gets the numbers of the plain jitted run.

Equality is bit for bit (NaN where the plain run has NaN): the stored program is the same
StableHLO the jitted call lowers to, called through a wrapper that XLA inlines, and the CPU
backend's operations are deterministic, so any difference would be a different program, not
round-off.  (On a GPU, repeatability also needs XLA's deterministic operations:
:mod:`hlip_jax.runtime.xla_flags`.)
"""

import os

import numpy as np
import pytest

from hlip_jax.simulation import arrays, execution
from hlip_jax.runtime import compile_cache, trace_cache
from hlip_jax.simulation.config import PathConfig, ScenarioConfig

CONFIGS = [ScenarioConfig(duration=2.0, seed=i, path=PathConfig(shape=s, params=dict(peak_speed=v)))
           for i, (s, v) in enumerate([("circle", 0.3), ("line", 0.5), ("sinusoid", 0.4)])]


@pytest.fixture
def cache(tmp_path):
    """The cache on in a fresh directory with nothing loaded (conftest turns it off after)."""
    trace_cache.disable()
    trace_cache.enable(tmp_path)
    yield tmp_path


def _run(progress: bool, max_iter=None):
    batch, static = arrays.build(CONFIGS)
    static = static._replace(progress=progress)
    if max_iter is not None:
        static = static._replace(settings=static.settings._replace(max_iter=max_iter))
    return execution.run(batch, static)


def _plain(progress: bool, **kw):
    d = trace_cache.directory()
    trace_cache.disable()
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
    entries = sorted(cache.glob("*" + trace_cache.SUFFIX), key=lambda f: f.stat().st_mtime_ns)
    assert len(entries) == 2
    # a budget of one entry evicts the older (the newer was just written and stays)
    trace_cache._evict(entries[1], entries[1].stat().st_size)
    assert list(cache.glob("*" + trace_cache.SUFFIX)) == [entries[1]]


def test_eviction_keeps_the_most_recently_used_within_the_budget(tmp_path):
    # five entries of 100 bytes, used at times 1..5 (mtime); a load of #1 makes it the newest
    files = [tmp_path / f"e{i}{trace_cache.SUFFIX}" for i in range(5)]
    for i, f in enumerate(files):
        f.write_bytes(b"x" * 100)
        os.utime(f, ns=(10**9 * (i + 1),) * 2)
    os.utime(files[1], ns=(10**9 * 9,) * 2)
    (tmp_path / ("m" + trace_cache.REFUSED)).write_bytes(b"")    # markers are not entries
    trace_cache._evict(files[4], 250)
    left = sorted(f.name for f in tmp_path.glob("*" + trace_cache.SUFFIX))
    assert left == ["e1.hlotrace", "e4.hlotrace"]                   # the two most recent
    assert (tmp_path / ("m" + trace_cache.REFUSED)).exists()
    trace_cache._evict(files[0], 10**6)             # within the budget: nothing goes
    assert len(list(tmp_path.glob("*" + trace_cache.SUFFIX))) == 2
    trace_cache._evict(files[1], 0)                 # the kept entry stays over any budget
    assert sorted(f.name for f in tmp_path.glob("*" + trace_cache.SUFFIX)) == ["e1.hlotrace"]


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
    calls = _count_traces(monkeypatch)

    def refuse(*a, **kw):
        raise ValueError("no stable ABI")
    monkeypatch.setattr(trace_cache.jax_export, "export", refuse)
    out = _run(False)
    assert [p.suffix for p in cache.iterdir()] == [trace_cache.REFUSED]   # marked, not stored
    assert trace_cache.loaded("run_whole") == 0
    _assert_equal(out, _plain(False))
    trace_cache._loaded.clear()                                            # a later process
    _run(False)
    assert len(calls) == 1                                                 # does not try again


@pytest.mark.parametrize("refused", [("start_batch", "segment_batch"), ("segment_batch",)],
                         ids=["both", "segment"])
def test_programs_that_cannot_be_exported_compile_ahead_in_threads(cache, monkeypatch, refused):
    """Without an exported program (MJX's Warp physics: the segment steps it, the start does
    not) a program is lowered by its own jit and compiled together with the other in a
    worker thread, each program once: the loop's calls run those executables (the segment's
    carry then comes committed to its device from the exported start), with the plain run's
    numbers."""
    import threading

    import jax
    inner = trace_cache._export

    def export(fn, static, args):
        if fn.__name__ in refused:
            raise ValueError("no stable ABI")
        return inner(fn, static, args)
    monkeypatch.setattr(trace_cache, "_export", export)
    compiles = []

    def listen(event, duration, **kw):
        if event == "/jax/core/compile/backend_compile_duration":
            compiles.append((str(kw.get("fun_name")), threading.current_thread().name))
    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        out = _run(True, max_iter=31 + len(refused))    # static settings no other test compiles
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)
    names = {"jit(start_batch)": "start", "jit(segment_batch)": "segment", "jit(call)": "stored"}
    loops = [(names[f], t) for f, t in compiles if f in names]
    expected = ["segment", "start"] if len(refused) == 2 else ["segment", "stored"]
    assert sorted(f for f, _ in loops) == expected
    assert all(t != threading.main_thread().name for _, t in loops)
    _assert_equal(out, _plain(True, max_iter=31 + len(refused)))


def test_key_covers_code_settings_and_flags(monkeypatch):
    import jax
    leaves, tree = jax.tree.flatten((np.zeros(3),))
    k = trace_cache.key("f", ("a", 1), leaves, tree)
    assert k.startswith("f-")
    assert trace_cache.key("f", ("a", 2), leaves, tree) != k
    f32 = jax.tree.leaves((np.zeros(3, np.float32),))
    assert trace_cache.key("f", ("a", 1), f32, tree) != k
    assert trace_cache.key("f", (np.zeros(5000),), leaves, tree) is None   # repr truncated
    assert trace_cache.key("f", (object(),), leaves, tree) is None          # repr has an address
    with jax.threefry_partitionable(not jax.config.jax_threefry_partitionable):
        assert trace_cache.key("f", ("a", 1), leaves, tree) != k      # other random numbers
    assert trace_cache.key("f", ("a", 1), leaves, tree) == k
    monkeypatch.setattr(trace_cache, "code_digest", lambda: "edited")
    assert trace_cache.key("f", ("a", 1), leaves, tree) != k


class _Slotted:
    __slots__ = ("array", "tag")

    def __init__(self, array, tag):
        self.array, self.tag = array, tag


def _node(aux):
    """A tree whose one custom node carries ``aux`` as static data."""
    import jax

    class Node:
        pass
    jax.tree_util.register_pytree_node(Node, lambda n: ((), aux), lambda a, c: Node())
    return jax.tree.structure(Node())


def test_static_data_is_described_by_its_contents():
    """Equal contents give one text (in another object, as in another process); different
    contents give another; functions and unknown objects are refused."""
    d = trace_cache.describe
    a = d(_node((_Slotted(np.arange(4), "x"), 3)))
    assert a == d(_node((_Slotted(np.arange(4).copy(), "x"), 3)))
    assert " at 0x" not in a
    assert a != d(_node((_Slotted(np.arange(4) + 1, "x"), 3)))
    assert a != d(_node((_Slotted(np.arange(4), "y"), 3)))
    assert d(_node((0.1234567891,))) != d(_node((0.1234567892,)))
    for bad in (lambda: 0, object()):
        with pytest.raises(ValueError):
            d(_node((bad,)))


def test_code_digest_changes_with_the_package_source(tmp_path, monkeypatch):
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "sub" / "a.py").write_text("x = 1\n")
    monkeypatch.setattr(trace_cache, "__file__", str(pkg / "trace_cache.py"))
    trace_cache.code_digest.cache_clear()
    try:
        first = trace_cache.code_digest()
        (pkg / "sub" / "a.py").write_text("x = 2\n")
        trace_cache.code_digest.cache_clear()
        assert trace_cache.code_digest() != first
    finally:
        trace_cache.code_digest.cache_clear()


def test_compile_cache_turns_the_trace_cache_on_beside_it(tmp_path, monkeypatch):
    import jax
    monkeypatch.setattr(jax.config, "update", lambda *a: None)   # keep this process's XLA cache
    compile_cache.enable(tmp_path)
    assert trace_cache.directory() == tmp_path / compile_cache.TRACES


def test_segments_compile_ahead_with_the_keys_the_loop_uses(cache, monkeypatch):
    """The start and segment programs are compiled together before the loop, under the keys
    the loop's calls then find (one trace each, no second entry), and the loop runs those
    executables (their jitted fallbacks never compile), with the same numbers."""
    calls = _count_traces(monkeypatch)
    out = _run(True)
    assert len(calls) == 2
    assert len(list(cache.glob("*" + trace_cache.SUFFIX))) == 2
    progs = list(trace_cache._loaded.values())
    assert len(progs) == 2 and all(len(p.compiled) == 1 for p in progs)
    assert all(p.jitted._cache_size() == 0 for p in progs)
    _assert_equal(out, _plain(True))


def test_prune_drops_jaxs_least_recently_used_executables_only(tmp_path):
    # four JAX entries of 100 bytes used at t = 1..4 s (the later of access and modification
    # time counts), an -atime stamp beside the oldest, a trace directory and a foreign file:
    # a 250-byte budget keeps the two most recent entries and touches nothing else
    import os
    for i, name in enumerate(["a", "b", "c", "d"]):
        f = tmp_path / f"jit_{name}-cache"
        f.write_bytes(b"x" * 100)
        os.utime(f, ns=((i + 1) * 10**9, (i + 1) * 10**9))
    os.utime(tmp_path / "jit_c-cache", ns=(9 * 10**9, 3 * 10**9))   # read last: kept
    (tmp_path / "jit_a-atime").write_bytes(b"t")
    (tmp_path / compile_cache.TRACES).mkdir()
    (tmp_path / compile_cache.TRACES / "k.hlotrace").write_bytes(b"y" * 1000)
    (tmp_path / "notes.txt").write_bytes(b"z" * 1000)
    assert compile_cache.prune(tmp_path, budget=250) == 200
    left = sorted(p.name for p in tmp_path.iterdir())
    assert left == ["jit_c-cache", "jit_d-cache", "notes.txt", compile_cache.TRACES]
    assert compile_cache.prune(tmp_path, budget=250) == 0            # within budget: nothing
    assert compile_cache.prune(tmp_path, budget=0) == 200            # every entry, no other file
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt", compile_cache.TRACES]
