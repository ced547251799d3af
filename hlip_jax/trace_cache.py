"""Traced closed loops kept on disk, so that a rerun skips tracing as well as compiling.

The persistent compilation cache (:mod:`hlip_jax.compile_cache`) saves XLA's compile, but JAX
finds a cached executable only after tracing the Python closed loop and lowering it to
StableHLO: about 10 s of a warm 2-core-CPU start of ``sweeps/paper.toml`` (BENCHMARKS.md,
"warm start").  This module keeps that traced and lowered program as well, in JAX's export
format (:func:`jax.export.export`, serialized StableHLO), and on a rerun calls the loaded
program instead of tracing again; XLA's persistent cache then supplies its executable.

A stored program is found by a key (SHA-256) of everything its tracing depends on:

* the package's own source files and the Cassie model files (their bytes),
* the versions of jax, jaxlib, numpy, mujoco and mujoco-mjx,
* the JAX backend, device kind, x64 flag and default matmul precision,
* the function's name, ``repr`` of its static settings, and the arguments' tree structure
  (with its static data), shapes and dtypes.

So editing the code, upgrading a library or changing a setting makes a new entry; nothing is
ever reused for a program it was not traced from.  Static settings whose ``repr`` is not a
complete description (truncated arrays, object addresses) are never stored.  Programs that
cannot be exported (e.g. foreign calls without a stable ABI, such as MJX's Warp physics) and
runs over several devices or processes take the ordinary jitted call.  A damaged entry is
replaced by a fresh trace.  The directory is ``<compilation cache>/traces``; the CLI's
``--no-compile-cache`` turns both caches off.
"""

from __future__ import annotations

import functools
import hashlib
import os
import pickle
import tempfile
from pathlib import Path
from typing import Any, Callable, NamedTuple

import jax
import numpy as np
from jax import export as jax_export

SUFFIX = ".hlotrace"
#: libraries whose version is part of every key (missing ones count as "absent")
LIBRARIES = ("jax", "jaxlib", "numpy", "mujoco", "mujoco-mjx")

_dir: Path | None = None


class Program(NamedTuple):
    """A loaded program: the exported function, its output's tree structure, and how to run
    it on flat leaves (jitted on first use, or compiled ahead by :func:`compile_together`)."""
    exported: Any
    out_tree: Any
    run: Callable


_loaded: dict[str, Program] = {}      # key -> program, for the rest of the process
_unexportable: set[str] = set()       # keys whose export failed (not retried in this process)


def enable(path: Path | None) -> None:
    """Store and reuse traced programs under ``path`` (None: off) for the rest of the process."""
    global _dir
    _dir = None if path is None else Path(path)


def directory() -> Path | None:
    """Where programs are stored now (None: the cache is off)."""
    return _dir


def loaded(name: str) -> int:
    """How many programs of the function ``name`` this process holds from the cache."""
    return sum(1 for k in _loaded if k.startswith(name + "-"))


@functools.lru_cache(maxsize=1)
def code_digest() -> str:
    """SHA-256 over the package's ``.py`` files and the Cassie model directory (names and
    bytes, in sorted order)."""
    from hlip_jax import resources
    package = Path(__file__).resolve().parent
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


def _versions() -> str:
    from importlib import metadata
    out = []
    for lib in LIBRARIES:
        try:
            out.append(f"{lib}={metadata.version(lib)}")
        except metadata.PackageNotFoundError:
            out.append(f"{lib}=absent")
    return ",".join(out)


def _static_text(x) -> str:
    """A description of a node's static data that depends only on its contents: arrays by
    dtype, shape and a digest of their bytes, objects with slots or attributes by those.
    Raises ValueError for anything whose ``repr`` is an object address."""
    if isinstance(x, np.ndarray):
        digest = hashlib.sha256(np.ascontiguousarray(x).tobytes()).hexdigest()[:16]
        return f"array({x.dtype},{x.shape},{digest})"
    if isinstance(x, (tuple, list)):
        return type(x).__name__ + "(" + ",".join(_static_text(v) for v in x) + ")"
    if isinstance(x, dict):
        return "{" + ",".join(f"{k!r}:{_static_text(x[k])}" for k in sorted(x, key=repr)) + "}"
    text = repr(x)
    if " at 0x" not in text:
        return text
    slots = getattr(type(x), "__slots__", None)
    fields = ({k: getattr(x, k) for k in slots} if slots is not None
              else getattr(x, "__dict__", None))
    if fields is None:
        raise ValueError(f"no content description of {type(x).__qualname__}")
    return type(x).__qualname__ + _static_text(fields)


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


def key(name: str, static, leaves, treedef) -> str | None:
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
    parts = [name, code_digest(), _versions(), jax.default_backend(), dev.device_kind,
             str(jax.config.jax_enable_x64), str(jax.config.jax_default_matmul_precision),
             text, tree,
             ";".join(str(jax.typeof(x)) for x in leaves)]
    return name + "-" + hashlib.sha256("\n".join(parts).encode()).hexdigest()[:40]


def _usable() -> bool:
    """On, and one process on one device: the exported program has no shardings to honour."""
    return _dir is not None and jax.process_count() == 1 and jax.device_count() == 1


def _load(file: Path) -> Program | None:
    """The program stored in ``file``, or None (missing or damaged: a damaged file is removed)."""
    if not file.is_file():
        return None
    try:
        blob, out_tree = pickle.loads(file.read_bytes())
        exported = jax_export.deserialize(bytearray(blob))
    except Exception:                               # damaged or from an incompatible writer
        file.unlink(missing_ok=True)
        return None
    return Program(exported, out_tree, jax.jit(exported.call))


def _export(fn: Callable, static, args, treedef) -> tuple[Any, Any, bytes]:
    """Trace and lower ``fn(*args, static=static)`` on flat leaves: (Exported, output tree,
    the entry's bytes).  Serializing needs the ``flatbuffers`` package (a dependency)."""
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


def _program(fn: Callable, static, args, k: str) -> Program | None:
    """The program of key ``k``: from memory, from disk, or traced now and stored."""
    if k in _loaded:
        return _loaded[k]
    file = _dir / (k + SUFFIX)
    prog = _load(file)
    if prog is None:
        try:
            exported, out_tree, blob = _export(fn, static, args, jax.tree.structure(args))
        except Exception:          # not exportable (module doc): the plain jitted call
            _unexportable.add(k)
            return None
        _store(file, blob)
        prog = Program(exported, out_tree, jax.jit(exported.call))
    _loaded[k] = prog
    return prog


def _lookup(fn: Callable, static, args) -> tuple[str | None, Program | None]:
    """(key, program) of ``fn(*args, static=static)``; (None, None) where the cache does not
    serve it (off, several devices, incomplete settings, not exportable)."""
    leaves, treedef = jax.tree.flatten(args)
    k = key(fn.__name__, static, leaves, treedef) if _usable() else None
    if k is None or k in _unexportable:
        return None, None
    return k, _program(fn, static, args, k)


def call(fn: Callable, static, *args):
    """``fn(*args, static=static)`` — ``fn`` a jitted function of the arrays ``args`` and a
    hashable static ``static`` — through the cache where it is on and usable (module doc)."""
    _, prog = _lookup(fn, static, args)
    if prog is None:
        return fn(*args, static=static)
    return jax.tree.unflatten(prog.out_tree, prog.run(*jax.tree.leaves(args)))


def out_shapes(fn: Callable, static, *args):
    """``fn(*args, static=static)``'s output as :class:`jax.ShapeDtypeStruct` leaves, from
    its stored or newly traced program, without compiling it; None where the cache does
    not serve the call.  ``args`` may hold ShapeDtypeStructs."""
    _, prog = _lookup(fn, static, args)
    if prog is None:
        return None
    return jax.tree.unflatten(prog.out_tree, [jax.ShapeDtypeStruct(a.shape, a.dtype)
                                              for a in prog.exported.out_avals])


def _ahead(prog: Program) -> Callable:
    """Compile ``prog`` for its argument types now; the result runs flat leaves (the jitted
    call where a caller's argument types differ from the exported ones, e.g. weak types)."""
    avals = [jax.ShapeDtypeStruct(a.shape, a.dtype) for a in prog.exported.in_avals]
    compiled = jax.jit(prog.exported.call).lower(*avals).compile()
    jitted = prog.run

    def run(*leaves):
        try:
            return compiled(*leaves)
        except TypeError:          # argument types differ from the compiled ones
            return jitted(*leaves)
    return run


def compile_together(calls) -> None:
    """Trace or load the programs of several calls ``(fn, static, args)`` (one after the
    other: tracing holds Python's lock), then compile them concurrently in threads (XLA
    compiles without it), so a loop's start and step programs cost the longer compile, not
    the sum.  Calls the cache does not serve are left to their first use."""
    todo = {}
    for fn, static, args in calls:
        k, prog = _lookup(fn, static, args)
        if prog is not None and isinstance(prog.run, jax.stages.Wrapped):
            todo[k] = prog
    if not todo:
        return
    from concurrent.futures import ThreadPoolExecutor
    with ThreadPoolExecutor(len(todo)) as pool:
        runs = dict(zip(todo, pool.map(_ahead, todo.values())))
    for k, run in runs.items():
        _loaded[k] = todo[k]._replace(run=run)
