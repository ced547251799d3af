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
"""

from __future__ import annotations

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
    ctx = multiprocessing.get_context("spawn")
    try:
        with cpu_children(), concurrent.futures.ProcessPoolExecutor(
                min(workers, len(calls)), mp_context=ctx) as ex:
            return list(ex.map(_in_precision, [x64] * len(calls), [fn] * len(calls), calls))
    except (OSError, concurrent.futures.process.BrokenProcessPool):
        return [fn(*args) for args in calls]
