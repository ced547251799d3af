"""Host-side analysis in worker processes: one map over spawned processes, defined once.

The analysis after a simulation (per-scenario metrics, coverage.csv) is numpy and small JAX
kernels on the CPU; spread over processes it scales with the host's cores.  A worker:

* is spawned (a fork would copy a process that holds an accelerator and XLA's threads);
* sees JAX on the CPU only (it must not claim the accelerator the simulation holds) and
  single-threaded BLAS (:func:`cpu_children`);
* computes in the parent's JAX precision (float64 or not), so its numbers are the ones the
  parent would have computed.

Where no process can be started (a sandbox without spawn, a killed worker) the same calls run
in this process: results already simulated are never lost to the pool.

The pool outlives one map: a run writes coverage.csv and then draws its report, and spawning
the workers (each imports JAX, matplotlib and the package) costs seconds each time, so the
second map reuses the first one's processes when it asks for as many workers (each call sets
its worker's precision; :func:`close` ends them, and runs at the interpreter's exit).
"""

from __future__ import annotations

import atexit
import concurrent.futures
import contextlib
import multiprocessing
import os
from typing import Callable, Sequence


def count(n: int, per_worker: int, cpus: int | None = None) -> int:
    """Worker processes for ``n`` items: one per ``per_worker`` items, at most one per CPU;
    below 2 the work stays in this process."""
    cpus = (os.cpu_count() or 1) if cpus is None else cpus
    return max(1, min(cpus, n // max(1, per_worker)))


@contextlib.contextmanager
def cpu_children():
    """Environment for worker processes spawned inside: JAX on the CPU only and
    single-threaded BLAS."""
    keys = ("JAX_PLATFORMS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
    old = {k: os.environ.get(k) for k in keys}
    os.environ.update(dict.fromkeys(keys, "1"), JAX_PLATFORMS="cpu")
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _in_precision(x64: bool, fn: Callable, args: tuple):
    import jax
    if jax.config.jax_enable_x64 != x64:
        jax.config.update("jax_enable_x64", x64)
    return fn(*args)


def apply(fn: Callable, args: tuple):
    """fn(*args): lets one :func:`starmap` run calls of different module-level functions."""
    return fn(*args)


def starmap(fn: Callable, calls: Sequence[tuple], workers: int) -> list:
    """[fn(*args) for args in calls], in order, over ``workers`` spawned processes (in this
    process when ``workers`` < 2 or no process can be started).  ``fn`` must be a module-level
    function and its arguments picklable."""
    if workers < 2 or len(calls) < 2:
        return [fn(*args) for args in calls]
    import jax
    x64 = bool(jax.config.jax_enable_x64)
    n = min(workers, len(calls))
    try:
        with cpu_children():                 # workers are spawned on demand, inside the map
            ex = _pool(n)
            return list(ex.map(_in_precision, [x64] * len(calls), [fn] * len(calls), calls))
    except (OSError, concurrent.futures.process.BrokenProcessPool):
        close()
        return [fn(*args) for args in calls]


#: the pool kept between maps: {"workers": its size, "ex": ProcessPoolExecutor}
_POOL: dict = {}


def _pool(n: int) -> concurrent.futures.ProcessPoolExecutor:
    """The kept pool of ``n`` spawned workers (a new one, the old one closed, for another
    ``n``)."""
    if _POOL.get("workers") != n:
        close()
        ctx = multiprocessing.get_context("spawn")
        _POOL.update(workers=n, ex=concurrent.futures.ProcessPoolExecutor(n, mp_context=ctx))
    return _POOL["ex"]


def close() -> None:
    """End the kept pool's workers (a no-op without one)."""
    ex = _POOL.pop("ex", None)
    _POOL.pop("workers", None)
    if ex is not None:
        ex.shutdown(wait=True, cancel_futures=True)


# ended before the interpreter tears its modules down (a pool collected then reports an error)
atexit.register(close)
