"""Traced closed loops kept on disk, so that a rerun skips tracing as well as compiling.

The persistent compilation cache (:mod:`hlip_jax.runtime.compile_cache`) saves XLA's compile, but JAX
finds a cached executable only after tracing the Python closed loop and lowering it to
StableHLO: about 10 s of a warm 2-core-CPU start of ``sweeps/paper.toml`` (docs/benchmarks/sweeps.md,
"warm start").  This module keeps that traced and lowered program as well, in JAX's export
format (:func:`jax.export.export`, serialized StableHLO), and on a rerun calls the loaded
program instead of tracing again; XLA's persistent cache then supplies its executable.

A stored program is found by a key (SHA-256) of everything its tracing depends on:

* the package's own source files and the Cassie model files (their bytes),
* the versions of jax, jaxlib, numpy, mujoco and mujoco-mjx,
* the JAX backend, device kind, and the JAX settings that change a traced program
  (:data:`JAX_FLAGS`: x64, matmul precision, the PRNG implementation, type promotion),
* the function's name, ``repr`` of its static settings, and the arguments' tree structure
  (with its static data, :func:`describe`), shapes and dtypes.

So editing the code, upgrading a library or changing a setting makes a new entry.  Static
data that cannot be described by its contents alone (functions, objects of unknown types,
truncated ``repr`` s, object addresses) keeps the call out of the cache.  Programs that cannot
be exported (foreign calls without a stable ABI, such as MJX's Warp physics) are marked so
on disk and take the ordinary jitted call, as do runs over several processes, runs under
``jax.disable_jit`` and installs without ``flatbuffers`` (jax.export's serializer); such a
call is still compiled ahead beside the others by :func:`compile_together` (traced again in
every process, though).  A
program run by several devices of this process (:func:`hlip_jax.simulation.execution.run`'s per-device
loops: their name says how many) is stored with its device split and compiled for the
arguments' placement; programs XLA partitions over several GPUs are not given to the cache
(the rollout calls them directly).  The directory is ``<compilation cache>/traces``; the CLI's
``--no-compile-cache`` turns both caches off.  It holds at most :data:`MAX_BYTES` of entries
(about 1 MB per sweep shape): storing a new one evicts the least recently used (a load counts
as a use).  JAX's compiled executables beside it are bounded by
:func:`hlip_jax.runtime.compile_cache.prune`.  Entries are Python pickles: like JAX's own
compilation cache, the directory must be writable by its user only.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import hashlib
import importlib.util
import os
import pickle
import tempfile
import threading
from pathlib import Path
from typing import Any, Callable, NamedTuple, Optional

import jax
import numpy as np
from jax import export as jax_export

from hlip_jax.runtime.cache_files import least_recently_used

SUFFIX = ".hlotrace"
MAX_BYTES = 512 * 2**20      # entries beyond this total are evicted, least recently used first
REFUSED = ".unexportable"    # marker of a program jax.export refused
#: libraries whose version is part of every key (missing ones count as "absent")
LIBRARIES = ("jax", "jaxlib", "numpy", "mujoco", "mujoco-mjx")
#: JAX settings that change a traced program (read with getattr: absent ones count as None)
JAX_FLAGS = ("jax_enable_x64", "jax_default_matmul_precision", "jax_default_prng_impl",
             "jax_enable_custom_prng", "jax_threefry_partitionable",
             "jax_numpy_dtype_promotion", "jax_numpy_rank_promotion")

_dir: Optional[Path] = None


class Program(NamedTuple):
    """A loaded program: the exported function, its output's tree structure, its jitted call
    on flat leaves, and the executables compiled ahead by :func:`compile_together`, one per
    placement of the arguments (:func:`placement`; empty until then)."""
    exported: Any
    out_tree: Any
    jitted: Callable
    compiled: dict

    def run(self, leaves):
        """The outputs' flat leaves.  The executable compiled for the arguments' placement
        where it accepts them (it raises TypeError where their types differ from the ones it
        was compiled for), else the jitted call, which compiles for them."""
        exe = self.compiled.get(placement(leaves))
        if exe is not None:
            try:
                return exe(*leaves)
            except TypeError:
                pass
        return self.jitted(*leaves)


def placement(args) -> Optional[tuple]:
    """The ids of the devices the arguments' first leaf is committed to (None for host or
    uncommitted arrays): executables compiled ahead are kept per placement, since the
    closed loop may run the same program on several devices at once
    (:func:`hlip_jax.simulation.execution.run_each`)."""
    leaves = jax.tree.leaves(args)
    leaf = leaves[0] if leaves else None
    if leaf is None or not getattr(leaf, "committed", False):
        return None
    return tuple(sorted(d.id for d in leaf.sharding.device_set))


_loaded: dict[str, Program] = {}      # key -> program, for the rest of the process
_ahead: dict[tuple, Callable] = {}    # call signature -> executable compiled ahead by jit
                                      # (calls the cache does not serve: compile_together)
_lock = threading.Lock()              # one thread at a time traces, loads or stores a program


def enable(path: Path) -> None:
    """Store and reuse traced programs under ``path`` for the rest of the process."""
    global _dir
    _dir = Path(path)


def disable() -> None:
    """Trace every call afresh from now on (programs already loaded are forgotten)."""
    global _dir
    _dir = None
    _loaded.clear()
    _ahead.clear()


def directory() -> Optional[Path]:
    """Where programs are stored now (None while the cache is off)."""
    return _dir


def loaded(name: str) -> int:
    """How many programs of the function ``name`` this process runs through the cache
    (loaded from disk or traced and stored here)."""
    return sum(1 for k in _loaded if k.startswith(name + "-"))


def compiled_ahead(name: str) -> int:
    """How many executables of the function ``name`` were compiled ahead for calls the cache
    does not serve (:func:`compile_together`)."""
    return sum(1 for sig in _ahead if sig[0].__name__ == name)


@functools.lru_cache(maxsize=1)
def code_digest() -> str:
    """SHA-256 over the package's ``.py`` files and the Cassie model directory (names and
    bytes, in sorted order)."""
    from hlip_jax.runtime import resources
    package = Path(__file__).resolve().parents[1]       # hlip_jax/, all its layers
    files = [(package, p) for p in sorted(package.rglob("*.py"))]
    try:
        model = resources.data_dir("assets", "cassie")
        files += [(model, p) for p in sorted(model.rglob("*")) if p.is_file()]
    except FileNotFoundError:       # a plant-less install: the H-LIP plant only
        pass
    h = hashlib.sha256()
    for root, p in files:
        h.update(str(p.relative_to(root)).encode())
        h.update(p.read_bytes())
    return h.hexdigest()


@functools.lru_cache(maxsize=1)
def _versions() -> str:
    """``lib=version`` of every library in :data:`LIBRARIES`."""
    from importlib import metadata
    out = []
    for lib in LIBRARIES:
        try:
            out.append(f"{lib}={metadata.version(lib)}")
        except metadata.PackageNotFoundError:
            out.append(f"{lib}=absent")
    return ",".join(out)


def _static_text(x) -> str:
    """A description of a node's static data by its contents alone: scalars, strings, enums
    and dtypes by ``repr``, arrays by dtype, shape and a digest of their bytes, containers,
    dataclasses and slotted objects by their items.  Raises ValueError for anything else
    (functions, other objects): their ``repr`` may hide what tracing reads."""
    if x is None or isinstance(x, (bool, int, float, complex, str, bytes, enum.Enum,
                                   np.generic, np.dtype)):
        return repr(x)
    if isinstance(x, type):
        return f"type:{x.__module__}.{x.__qualname__}"
    if isinstance(x, np.ndarray):
        digest = hashlib.sha256(np.ascontiguousarray(x).tobytes()).hexdigest()[:16]
        return f"array({x.dtype},{x.shape},{digest})"
    name = f"{type(x).__module__}.{type(x).__qualname__}"
    if isinstance(x, (tuple, list)):
        return name + "(" + ",".join(_static_text(v) for v in x) + ")"
    if isinstance(x, dict):
        return name + "{" + ",".join(f"{_static_text(k)}:{_static_text(x[k])}"
                                     for k in sorted(x, key=repr)) + "}"
    if dataclasses.is_dataclass(x):
        return name + _static_text({f.name: getattr(x, f.name) for f in dataclasses.fields(x)})
    slots = [s for c in type(x).__mro__ for s in _slot_names(c)]
    if slots and not hasattr(x, "__dict__"):
        return name + _static_text({s: getattr(x, s) for s in slots if hasattr(x, s)})
    raise ValueError(f"no content description of a {name}")


def _slot_names(cls) -> tuple[str, ...]:
    slots = cls.__dict__.get("__slots__", ())
    return (slots,) if isinstance(slots, str) else tuple(slots)


def describe(treedef) -> str:
    """The tree structure as text, static node data by content (:func:`_static_text`): MJX's
    contact data carries static index arrays whose ``repr`` is an object address, different
    in every process."""
    data = treedef.node_data()
    if data is None:
        return "*"
    typ, aux = data
    kids = ",".join(describe(c) for c in treedef.children())
    return f"{typ.__module__}.{typ.__qualname__}[{_static_text(aux)}]({kids})"


def key(name: str, static, leaves, treedef) -> Optional[str]:
    """The entry's key (module doc), or None when ``static`` or the tree structure has no
    complete description (:func:`describe`)."""
    text = repr(static)
    if "..." in text or " at 0x" in text:
        return None
    try:
        tree = describe(treedef)
    except ValueError:
        return None
    dev = jax.devices()[0]
    flags = ",".join(f"{f}={getattr(jax.config, f, None)}" for f in JAX_FLAGS)
    parts = [name, code_digest(), _versions(), jax.default_backend(), dev.device_kind, flags,
             text, tree, ";".join(str(jax.typeof(x)) for x in leaves)]
    return name + "-" + hashlib.sha256("\n".join(parts).encode()).hexdigest()[:40]


def _usable() -> bool:
    """On, jit on, jax.export's serializer installed, one process (a program over several
    processes' devices is not exported)."""
    return (_dir is not None and not jax.config.jax_disable_jit
            and importlib.util.find_spec("flatbuffers") is not None
            and jax.process_count() == 1)


def _program_of(exported, out_tree) -> Program:
    return Program(exported, out_tree, jax.jit(exported.call), {})


def _load(file: Path) -> Optional[Program]:
    """The program stored in ``file``; None where it is missing or unreadable (a damaged
    entry, or one from an incompatible JAX: the fresh trace overwrites it)."""
    if not file.is_file():
        return None
    try:
        blob, out_tree = pickle.loads(file.read_bytes())
        prog = _program_of(jax_export.deserialize(bytearray(blob)), out_tree)
    except Exception:
        return None
    try:
        os.utime(file)                      # a use: the entry is the most recent for eviction
    except OSError:
        pass
    return prog


def _export(fn: Callable, static, args) -> tuple[Any, Any, bytes]:
    """Trace and lower ``fn(*args, static=static)`` on flat leaves: (Exported, output tree,
    the entry's bytes)."""
    treedef = jax.tree.structure(args)
    box = {}

    def flat(*leaves):
        out = fn(*jax.tree.unflatten(treedef, leaves), static=static)
        out_leaves, box["tree"] = jax.tree.flatten(out)
        return out_leaves

    exported = jax_export.export(jax.jit(flat))(*jax.tree.leaves(args))
    return exported, box["tree"], pickle.dumps((bytes(exported.serialize()), box["tree"]))


def _store(file: Path, blob: bytes) -> None:
    """Write the entry atomically (a reader never sees half a file); disk errors are ignored,
    the run goes on without the entry."""
    tmp = None
    try:
        file.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=file.parent, suffix=".tmp")
        with os.fdopen(fd, "wb") as f:
            f.write(blob)
        os.replace(tmp, file)
    except OSError:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)


def _evict(keep: Path, budget: int) -> None:
    """Delete the least recently used entries of ``keep``'s directory (by modification time)
    until the entries total at most ``budget`` bytes; ``keep`` (just written) stays.  Best
    effort: entries another process removes or holds open are skipped."""
    for f, _ in least_recently_used(keep.parent.glob("*" + SUFFIX), budget,
                                                  lambda st: st.st_mtime_ns, keep):
        f.unlink(missing_ok=True)


def _program(fn: Callable, static, args, k: str) -> Optional[Program]:
    """The program of key ``k``: from memory, from disk, or traced now and stored; None when
    jax.export refuses it (marked on disk, so later runs do not try again)."""
    if k in _loaded:
        return _loaded[k]
    if (_dir / (k + REFUSED)).exists():
        return None
    file = _dir / (k + SUFFIX)
    prog = _load(file)
    if prog is None:
        try:
            exported, out_tree, blob = _export(fn, static, args)
        except Exception:     # refused (module doc); a real error recurs in the plain call
            _store(_dir / (k + REFUSED), b"")
            return None
        _store(file, blob)
        _evict(file, MAX_BYTES)
        prog = _program_of(exported, out_tree)
    _loaded[k] = prog
    return prog


def _lookup(fn: Callable, static, args) -> Optional[tuple[str, Program]]:
    """(key, program) of ``fn(*args, static=static)``, or None where the cache does not serve
    it (module doc)."""
    if not _usable():
        return None
    leaves, treedef = jax.tree.flatten(args)
    k = key(fn.__name__, static, leaves, treedef)
    if k is None:
        return None
    with _lock:          # a second thread asking for the same program waits for the first's
        prog = _program(fn, static, args, k)
    return None if prog is None else (k, prog)


def call(fn: Callable, static, *args):
    """``fn(*args, static=static)`` — ``fn`` a jitted function of the arrays ``args`` and a
    hashable static ``static`` — through the cache where it serves the call (module doc)."""
    found = _lookup(fn, static, args)
    if found is None:
        return _call_ahead(fn, static, args)
    prog = found[1]
    return jax.tree.unflatten(prog.out_tree, prog.run(jax.tree.leaves(args)))


def _signature(fn: Callable, static, args) -> tuple:
    """The function, its static settings, the arguments' structure, shapes and dtypes, and
    their :func:`placement`."""
    leaves, treedef = jax.tree.flatten(args)
    return (fn, static, treedef, tuple((tuple(a.shape), str(a.dtype)) for a in leaves),
            placement(leaves))


def _call_ahead(fn: Callable, static, args):
    """``fn(*args, static=static)`` by the executable :func:`compile_together` made for these
    argument types and placement (:func:`placement`), where it accepts the arguments (it
    raises TypeError where their types differ: a committed array where the lowering had
    none), else by jit."""
    compiled = _ahead.get(_signature(fn, static, args))
    if compiled is not None:
        try:
            return compiled(*args)
        except TypeError:
            pass
    return fn(*args, static=static)


def out_shapes(fn: Callable, static, *args):
    """``fn(*args, static=static)``'s output as :class:`jax.ShapeDtypeStruct` leaves, without
    compiling it: from its stored or newly traced program, or, where the cache does not serve
    the call (module doc), from ``fn``'s own jit lowering (:func:`_jit_lowered`).  None under
    ``jax.disable_jit``.  ``args`` may hold ShapeDtypeStructs."""
    found = _lookup(fn, static, args)
    if found is None:
        lowered = _jit_lowered(fn, static, args)
        return None if lowered is None else jax.tree.map(
            lambda a: jax.ShapeDtypeStruct(a.shape, a.dtype), lowered.out_info)
    prog = found[1]
    return jax.tree.unflatten(prog.out_tree, [jax.ShapeDtypeStruct(a.shape, a.dtype)
                                              for a in prog.exported.out_avals])


def _jit_lowered(fn: Callable, static, args):
    """``fn(*args, static=static)`` traced and lowered by ``fn``'s own jit (None under
    ``jax.disable_jit``): how calls the cache does not serve (MJX's Warp physics) are
    compiled ahead.  :func:`compile_together` keeps the executable, and :func:`call` runs it."""
    if jax.config.jax_disable_jit:
        return None
    return fn.lower(*args, static=static)


def _compile(prog: Program, args):
    """``prog``'s executable for its exported argument types, placed as ``args`` are (their
    shardings: one device, or a program run by several devices)."""
    avals = [jax.ShapeDtypeStruct(a.shape, a.dtype, sharding=getattr(x, "sharding", None))
             for a, x in zip(prog.exported.in_avals, jax.tree.leaves(args))]
    return prog.jitted.lower(*avals).compile()


def compile_together(calls) -> None:
    """Trace or load the programs of several calls ``(fn, static, args)`` (one after the
    other: tracing holds Python's lock), then compile them concurrently in threads (XLA
    compiles without it), so a loop's start and step programs cost the longer compile, not
    the sum.  Calls the cache does not serve are lowered by their own jit and compiled the
    same way (:func:`_jit_lowered`); their first use then runs the executable made here."""
    todo, lowered = {}, {}
    for fn, static, args in calls:
        found = _lookup(fn, static, args)
        if found is None:
            sig = _signature(fn, static, args)
            low = None if sig in _ahead else _jit_lowered(fn, static, args)
            lowered.update({} if low is None else {sig: low})
        elif placement(args) not in found[1].compiled:
            todo[found[0]] = (found[1], args)
    if not todo and not lowered:
        return
    from concurrent.futures import ThreadPoolExecutor
    with ThreadPoolExecutor(len(todo) + len(lowered)) as pool:
        jitted = {sig: pool.submit(low.compile) for sig, low in lowered.items()}
        done = dict(zip(todo, pool.map(lambda pa: _compile(*pa), todo.values())))
        _ahead.update({sig: f.result() for sig, f in jitted.items()})
    for k, compiled in done.items():
        prog, args = todo[k]
        prog.compiled[placement(args)] = compiled
