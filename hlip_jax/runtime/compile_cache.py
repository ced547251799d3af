"""Persistent XLA compilation cache of the ``hlip-sweep`` commands that simulate.

A Cassie sweep's closed loop takes minutes to compile (about 150 s on a 2-core CPU, 90–160 s
on an H100) and is the same program every time the same sweep shapes come back (a rerun, a
resumed run, the same sweep at another out directory, ``hlip-sweep ticks`` after ``run``).
JAX can keep compiled executables on disk (``jax_compilation_cache_dir``); the CLI turns that
on by default so that a second run starts simulating after a cache read instead of a compile.

Directory: ``--compile-cache DIR`` where given, else ``$HLIP_JAX_CACHE_DIR``, else
``$XDG_CACHE_HOME/hlip_jax/xla``, else ``~/.cache/hlip_jax/xla``.  Only programs that took at
least ``MIN_COMPILE_S`` to compile are stored (the small ones are quicker to rebuild than to
read).  The cache is keyed by JAX on the program, the JAX/XLA versions and the device, so a
stale entry is never used for a different program.  The traced closed loops that lead to
those programs are kept beside them (``DIR/traces``, :mod:`hlip_jax.runtime.trace_cache`), so a rerun
skips tracing too.

Bound: JAX bounds its own directory only with the ``filelock`` package (not a dependency), so
:func:`enable` prunes it instead, before the command compiles anything: while JAX's
executables total more than :data:`MAX_BYTES`, the least recently used goes (by the later of
its access and modification times; JAX's ``-atime`` stamp goes with it).  A Cassie sweep's
executables are a few MB on a CPU.  Another process that loses an entry this way compiles it
again; nothing else in the directory (the traces, files that are not JAX's) is touched.
"""

from __future__ import annotations

import os
from pathlib import Path

from hlip_jax.runtime.cache_files import least_recently_used

MIN_COMPILE_S = 1.0    # [s] programs faster to compile than this are not stored
TRACES = "traces"      # subdirectory of the traced closed loops (hlip_jax.runtime.trace_cache)
MAX_BYTES = 4 * 2**30  # JAX's executables beyond this total are pruned when a command starts
ENTRY, STAMP = "-cache", "-atime"   # JAX's names: <key>-cache, and <key>-atime where it keeps one


class CacheDirError(ValueError):
    """The cache directory cannot be created or written (message names the path)."""


def default_dir() -> Path:
    """The cache directory when none is given (module doc)."""
    if os.environ.get("HLIP_JAX_CACHE_DIR"):
        return Path(os.environ["HLIP_JAX_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "hlip_jax" / "xla"


def usable(path: Path) -> Path:
    """``path`` created if needed; raises :class:`CacheDirError` when it is not a writable
    directory."""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise CacheDirError(f"{path}: cannot create the compilation cache directory "
                            f"({err.strerror or err})") from None
    if not path.is_dir() or not os.access(path, os.W_OK):
        raise CacheDirError(f"{path}: not a writable directory")
    return path


def enable(path: Path) -> None:
    """Store and reuse compiled programs in ``path`` for the rest of the process (call before
    the first compile: JAX reads the setting when it first compiles), and the traced closed
    loops in ``path / "traces"`` (:mod:`hlip_jax.runtime.trace_cache`)."""
    import jax

    from hlip_jax.runtime import trace_cache

    prune(usable(path))
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_S)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    trace_cache.enable(path / TRACES)


def prune(path: Path, budget: int = MAX_BYTES) -> int:
    """Delete JAX's least recently used executables in ``path`` until they total at most
    ``budget`` bytes (module doc); returns the bytes freed.  Best effort: entries another
    process removes meanwhile are skipped."""
    freed = 0
    for f, size in least_recently_used(path.glob("*" + ENTRY), budget,
                                       lambda st: max(st.st_atime_ns, st.st_mtime_ns)):
        f.unlink(missing_ok=True)
        f.with_name(f.name[:-len(ENTRY)] + STAMP).unlink(missing_ok=True)
        freed += size
    return freed
