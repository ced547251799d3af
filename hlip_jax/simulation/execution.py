"""Running the closed loop on devices: the compiled programs of a batch, one device or several,
one process or several (``jax.distributed``), with or without progress reports, and the
outputs brought back to the host.

* One device: the batch placed once, the whole run one call, or the steps in segments of
  :func:`hlip_jax.simulation.rollout.segment_length` reported to :mod:`hlip_jax.runtime.progress` (:func:`run`).
* Several CPU devices: one ``shard_map`` program in which each device runs its own scenarios'
  loop (:func:`place`, :func:`run`).
* Several GPUs (and several processes): the batch cut into one block per device, each device
  running the one-device program from its own thread, the blocks gathered in order
  (:func:`spread_of`, :func:`run_blocks`, :func:`run_on`).

:func:`simulate` is the sweep's entry point: configs in, a :class:`hlip_jax.core.steplog.Log` out.
"""

from __future__ import annotations

import functools
import itertools
from typing import NamedTuple, Optional, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from hlip_jax import plants
from hlip_jax.runtime import progress, trace_cache
from hlip_jax.simulation.arrays import Scenario, Shapes, Static, build, shapes_of
from hlip_jax.simulation.config import ScenarioConfig
from hlip_jax.simulation.rollout import (finish_batch, run_whole, segment_batch, segment_length,
                              start_batch)
from hlip_jax.core.steplog import Log

def compiled_loops() -> int:
    """How many compiled closed-loop programs this process holds (whole runs and segments,
    traced here, loaded by :mod:`hlip_jax.runtime.trace_cache` or compiled ahead beside the start
    program): a sweep whose chunks share their shapes adds one."""
    loops = [run_whole, segment_batch]
    loops += [p for whole, _, segment in _per_mesh.values() for p in (whole, segment)]
    return sum(f._cache_size() + trace_cache.loaded(f.__name__)
               + trace_cache.compiled_ahead(f.__name__) for f in loops)


def _compile_ahead(start, segment, batch: Scenario, static: Static, L: int,
                   split: Optional[jax.sharding.Sharding]) -> None:
    """Trace or load the ``start`` and ``segment`` programs (through :mod:`hlip_jax.runtime.trace_cache`
    where it serves them, else by their own jit: MJX's Warp physics) and compile both at once
    (the segment's carry shapes from the start's program).  ``split``: where the batch's
    arrays are committed (:func:`_committed_to`), the carry is placed the same way and the
    step indices given whole to its device(s); None for a host batch."""
    shapes = trace_cache.out_shapes(start, static, batch)
    if shapes is None:
        return
    carry, ks = shapes[0], jax.ShapeDtypeStruct((L,), jax.dtypes.canonicalize_dtype(jnp.int_))
    if split is not None:
        carry = jax.tree.map(lambda a: jax.ShapeDtypeStruct(a.shape, a.dtype, sharding=split),
                             carry)
        whole = (jax.sharding.NamedSharding(split.mesh, jax.sharding.PartitionSpec())
                 if isinstance(split, jax.sharding.NamedSharding) else split)
        ks = jax.ShapeDtypeStruct(ks.shape, ks.dtype, sharding=whole)
    trace_cache.compile_together([(start, static, (batch,)),
                                  (segment, static, (batch, carry, ks))])


def _committed_to(batch) -> Optional[jax.sharding.Sharding]:
    """The sharding a batch's arrays are committed to (:func:`place`, or one device by
    :func:`run_blocks`); None for host (numpy) or uncommitted arrays."""
    leaf = jax.tree.leaves(batch)[0]
    return leaf.sharding if getattr(leaf, "committed", False) else None


def _mesh_of(batch) -> Optional[jax.sharding.Mesh]:
    """The mesh a batch is split over when it spans several devices (:func:`place`), else
    None (a batch on one device)."""
    sharding = getattr(jax.tree.leaves(batch)[0], "sharding", None)
    if isinstance(sharding, jax.sharding.NamedSharding) and sharding.mesh.size > 1:
        return sharding.mesh
    return None


def _per_device(fn, mesh, replicated: int = 0):
    """``fn`` (a jitted ``(batch, ..., static=)`` closed-loop program) run by every device of
    ``mesh`` on its own scenarios: ``shard_map`` over the scenario axis, the last
    ``replicated`` arguments given whole to every device.  Scenarios never communicate, so
    the devices never do either: left to XLA's partitioner, the tick loop's stopping test
    (any robot of the batch still in its step) became a cross-device reduction every tick,
    83× slower in a toy loop on two CPU devices (docs/benchmarks/sweeps.md, "CPU cores as devices")."""
    from jax.sharding import PartitionSpec
    split = PartitionSpec(mesh.axis_names[0])

    def program(*args, static):
        specs = (split,) * (len(args) - replicated) + (PartitionSpec(),) * replicated
        body = functools.partial(fn.__wrapped__, static=static)
        return jax.shard_map(body, mesh=mesh, in_specs=specs, out_specs=split,
                             check_vma=False)(*args)

    program.__name__ = f"{fn.__name__}_on_{mesh.size}_{mesh.devices.flat[0].platform}"
    return jax.jit(program, static_argnames=("static",))


def _check_cpu_pool(mesh: jax.sharding.Mesh) -> None:
    """Refuse a batch split over as many CPU devices of this process as XLA's CPU thread
    pool has threads under jaxlib < 0.11, whose batched LAPACK kernels then wait forever for
    a free thread (:mod:`hlip_jax.runtime.xla_flags`).  The pool has ``PJRT_NPROC`` (or ``NPROC``)
    threads, else one per usable core."""
    from hlip_jax.runtime import xla_flags
    if mesh.devices.flat[0].platform != "cpu" or _jaxlib_version() >= (0, 11):
        return
    pool = xla_flags.cpu_pool_threads()
    here = sum(d.process_index == jax.process_index() for d in mesh.devices.flat)
    if here >= pool:
        raise xla_flags.PoolTooSmall(
            f"the batch is split over {here} CPU devices of this process, but XLA's CPU thread "
            f"pool has {pool} threads: jaxlib {jax.lib.__version__} can deadlock unless it has "
            f"more (set PJRT_NPROC={2 * here} before JAX starts, as hlip-sweep does)")


def _jaxlib_version() -> tuple[int, ...]:
    return tuple(int(p) for p in jax.lib.__version__.split(".")[:2] if p.isdigit())


_per_mesh: dict = {}     # mesh -> its (whole run, start, segment) programs


def _jitted_call(fn, static, *args):
    """``fn(*args, static=static)`` without the trace cache (programs XLA partitions over
    several devices: their export is not kept)."""
    return fn(*args, static=static)


def _programs(mesh: Optional[jax.sharding.Mesh]):
    """(whole run, start, segment) programs for a batch on ``mesh`` (None: one device).
    Several CPU devices get per-device loops (:func:`_per_device`); a batch placed over
    several GPUs gets the loops XLA partitions (the per-device programs crashed XLA's GPU
    compile on two H200s, jax 0.11.2: docs/benchmarks/sweeps.md, "CPU cores as devices"),
    which :func:`run_on` avoids by giving each GPU its own block (:func:`spread_of`)."""
    if mesh is None or mesh.devices.flat[0].platform != "cpu":
        return run_whole, start_batch, segment_batch
    if mesh not in _per_mesh:
        _check_cpu_pool(mesh)
        _per_mesh[mesh] = (_per_device(run_whole, mesh), _per_device(start_batch, mesh),
                           _per_device(segment_batch, mesh, replicated=1))
    return _per_mesh[mesh]


class _Route(NamedTuple):
    """How one batch's closed loop is called: its (whole run, start, segment) programs, the
    call that runs them (through :mod:`hlip_jax.runtime.trace_cache` or straight by jit) and, for the
    per-device programs of several CPU devices, the batch's split (None otherwise)."""
    whole: object
    start: object
    segment: object
    call: object
    split: Optional[jax.sharding.NamedSharding]


def _route(batch: Scenario) -> _Route:
    mesh = _mesh_of(batch)
    whole, start, segment = _programs(mesh)
    per_device = mesh is not None and mesh in _per_mesh
    call = trace_cache.call if mesh is None or per_device else _jitted_call
    split = jax.tree.leaves(batch)[0].sharding if per_device else None
    return _Route(whole, start, segment, call, split)


def run(batch: Scenario, static: Static):
    """Every scenario's closed loop (the batch on the devices it was placed on).

    Without ``static.progress`` the whole run is one compiled call.  With it the steps run in
    segments of :func:`segment_length` (one compiled program serves every segment: the step
    indices are data, and steps past ``n_steps`` are inactive), and every finished segment is
    reported to :func:`hlip_jax.runtime.progress.step_done` from Python — no host callback inside the
    compiled loop, so it stays cacheable on disk (:mod:`hlip_jax.runtime.compile_cache`; the traced
    programs too, :mod:`hlip_jax.runtime.trace_cache`).  Both give the same numbers: a segment
    boundary only splits the scan."""
    return run_each([batch], static)[0]


def run_each(batches: Sequence[Scenario], static: Static) -> list:
    """:func:`run` of several batches at once, each on its own device(s), each from its own
    thread: a GPU program with a while loop holds the thread that launched it until it ends
    (the loop's test is read back every trip), so calls from one thread run one device after
    the other (two H200s, 65,536 robots: no faster than one).  Each thread compiles its own
    executable (concurrently) and runs its batch's loop; the first batch's segments are the
    ones reported to :mod:`hlip_jax.runtime.progress`.  The matmul precision of the calling thread
    holds in every thread."""
    if len(batches) == 1:
        return [_run_one(batches[0], static, True)]
    from concurrent.futures import ThreadPoolExecutor
    precision = jax.config.jax_default_matmul_precision

    def one(i):
        with jax.default_matmul_precision(precision):
            return _run_one(batches[i], static, i == 0)
    with ThreadPoolExecutor(len(batches)) as pool:
        return list(pool.map(one, range(len(batches))))


def _run_one(batch: Scenario, static: Static, report: bool):
    """:func:`run` of one batch; its segments reported to :mod:`hlip_jax.runtime.progress` where
    ``report``."""
    r = _route(batch)
    if not static.progress:
        return r.call(r.whole, static, batch)
    K, L = static.n_steps, segment_length(static.n_steps)
    if r.call is trace_cache.call:
        _compile_ahead(r.start, r.segment, batch, static, L, r.split or _committed_to(batch))
    carry, ok0 = r.call(r.start, static, batch)
    outs = []
    for k0 in range(0, K, L):
        carry, out = _segment_call(r, static, batch, carry, k0, L)
        outs.append(out)
        jax.block_until_ready(carry)
        if report:
            progress.step_done(min(k0 + L, K) - 1, K)
    return finish_batch(jax.tree.map(lambda *a: jnp.concatenate(a, axis=1)[:, :K], *outs), ok0)


def _segment_call(route: _Route, static: Static, batch: Scenario, carry, k0: int, L: int):
    """Steps k0 … k0 + L − 1 of one batch: (carry, their outputs)."""
    if route.split is not None:
        # per-device programs: XLA returns their empty outputs whole on every device, and the
        # segment's executable, compiled ahead, expects every carry leaf split as the batch is
        carry = jax.device_put(carry, route.split)       # no copy where already split
    return route.call(route.segment, static, batch, carry, jnp.arange(k0, k0 + L))


#: how a batch on several devices runs (:func:`spread_of`)
SPREADS = ("program", "dispatch")


def spread_of(devices: Sequence) -> str:
    """How a batch runs on several ``devices``: ``"program"`` — one program split over them
    (:func:`place` and :func:`run`: per-device loops in one ``shard_map`` program, one compile
    for all), for CPU devices; ``"dispatch"`` — the batch cut into one block per device, each
    device running the one-device program on its block (:func:`run_blocks`), for GPUs: the
    split programs crashed XLA's GPU compile (two H200s, jax 0.11.2), and the program XLA
    partitions tests "any robot still stepping" across the devices every tick (no faster on
    two GPUs than on one: docs/benchmarks/sweeps.md).  Each GPU compiles its own executable,
    concurrently (:func:`run_each`)."""
    return "program" if list(devices)[0].platform == "cpu" else "dispatch"


def _local_blocks(n: int, devices: Sequence) -> list[tuple[object, slice]]:
    """(device, its scenarios) of this process's devices, the ``n`` scenarios cut into
    ``len(devices)`` equal blocks in the order of ``devices``."""
    b = n // len(devices)
    return [(d, slice(i * b, (i + 1) * b)) for i, d in enumerate(devices)
            if d.process_index == jax.process_index()]


def run_blocks(host: Scenario, static: Static, devices: Sequence) -> list:
    """The closed loop of this process's blocks of the host batch ``host`` (its length a
    multiple of ``len(devices)``), one block per device of this process, computed together
    (:func:`run_each`).  Returns the blocks' outputs (device arrays), in the order of
    ``devices``."""
    blocks = _local_blocks(len(jax.tree.leaves(host)[0]), devices)
    batches = [jax.device_put(jax.tree.map(lambda a: np.asarray(a)[s], host), d)
               for d, s in blocks]
    return run_each(batches, static)


def _gather_blocks(local: list, devices: Sequence):
    """The outputs of every process's blocks (:func:`run_blocks`; ``local`` this process's, as
    numpy trees) as one tree of numpy arrays, scenarios in the order of the blocks.  Every
    process must hold as many of ``devices`` as the others."""
    mine = jax.tree.map(lambda *a: np.concatenate(a), *local)
    if jax.process_count() == 1:
        return mine
    from jax.experimental import multihost_utils
    owners = [d.process_index for d in devices]
    counts = {p: owners.count(p) for p in set(owners)}
    if len(set(counts.values())) != 1:
        raise ValueError(f"devices: the processes hold different numbers of the devices "
                         f"({counts}); a run over several processes needs as many on each")
    every = multihost_utils.process_allgather(mine, tiled=False)     # (processes, ...)
    # gathered: process 0's blocks, then process 1's, ...; put them back in block order
    gathered = [i for p in sorted(counts) for i, o in enumerate(owners) if o == p]
    order = np.argsort(gathered)
    n_blocks = len(devices)

    def blocks_in_order(a):
        a = np.asarray(a).reshape((n_blocks, -1) + a.shape[2:])
        return a[order].reshape((-1,) + a.shape[2:])
    return jax.tree.map(blocks_in_order, every)


def scenario_sharding(devices=None):
    """Sharding that splits the leading (scenario) axis over ``devices`` (default: every
    device of every process, ``jax.devices()``): a 1-D ``Mesh`` with axis "scenarios".
    :func:`run` gives each device its own scenarios' loop (:func:`_per_device`)."""
    from jax.sharding import Mesh, NamedSharding, PartitionSpec
    devices = jax.devices() if devices is None else list(devices)
    return NamedSharding(Mesh(np.asarray(devices), ("scenarios",)), PartitionSpec("scenarios"))


def place(batch, sharding):
    """Put a host (numpy) batch on the mesh.  Each process builds the same batch from the
    same configs and contributes only the shards of its own devices, so this works
    unchanged after ``jax.distributed.initialize`` on several hosts."""
    def put(a):
        a = np.asarray(a)
        return jax.make_array_from_callback(a.shape, sharding, lambda idx: a[idx])
    return jax.tree.map(put, batch)


_barriers = itertools.count()


def _all_processes_arrive() -> None:
    """Wait (up to an hour) until every process of a ``jax.distributed`` run gets here.  The
    processes compile their programs separately and can finish minutes apart; the gather that
    follows uses the CPU collectives (Gloo), whose first use gives the others only 30 s to
    connect.  The coordination service's barrier has no such limit."""
    from jax._src import distributed          # the client jax.distributed.initialize started
    client = distributed.global_state.client
    if client is not None and jax.process_count() > 1:
        client.wait_at_barrier(f"hlip_jax_gather_{next(_barriers)}", 3_600_000)


def _to_host(a):
    if jax.process_count() > 1:
        from jax.experimental import multihost_utils
        return np.asarray(multihost_utils.process_allgather(a, tiled=True))
    return np.asarray(a)


def simulate_ticks(configs: Sequence[ScenarioConfig], index: int, *, n_samples: int = 2048,
                   dtype=None):
    """Re-simulate scenario ``index`` of ``configs`` (a Cassie sweep) alone, with the plant's
    per-tick log.  The array sizes are the whole sweep's (:func:`shapes_of`), so the run is the
    one the sweep made up to floating-point differences of a batch of one
    (:func:`simulate_chunk_ticks` repeats the sweep's own batch instead).  Returns (the step
    log as a dict of arrays (K, ...), the tick log (:class:`hlip_jax.plants.cassie.tick.TickLog`
    of arrays (K, ticks per step, ...)))."""
    configs = list(configs)
    return simulate_chunk_ticks([configs[index]], [0], n_samples=n_samples, dtype=dtype,
                                shapes=shapes_of(configs), devices=jax.devices()[:1])[0]


def _simulate_batch(configs, *, n_samples, pad_to, dtype, shapes, devices, keep_ticks,
                    spread=None):
    """:func:`simulate`'s run: (the host batch, the outputs of the first ``len(configs)``
    scenarios as numpy arrays), the tick log under "ticks" where ``keep_ticks``."""
    configs = list(configs)
    S = len(configs)
    devices = jax.devices() if devices is None else list(devices)
    n = max(pad_to or S, S)
    n = -(-n // len(devices)) * len(devices)
    padded = configs + [configs[-1]] * (n - S)
    host, static = build(padded, n_samples=n_samples, dtype=dtype, shapes=shapes)
    out = run_on(host, static._replace(progress=progress.active(), keep_ticks=keep_ticks),
                 devices, spread or spread_of(devices))
    return host, jax.tree.map(lambda a: a[:S], out)


def run_on(host: Scenario, static: Static, devices: Sequence, spread: str) -> dict:
    """Every scenario's closed loop of the host batch ``host`` (its length a multiple of
    ``len(devices)``) on ``devices``, shared as ``spread`` (:data:`SPREADS`,
    :func:`spread_of`) says, in every process of a ``jax.distributed`` run; the outputs as
    numpy arrays, scenarios in order."""
    devices = list(devices)
    if spread not in SPREADS:
        raise ValueError(f"spread: {spread!r} is not allowed; allowed: {', '.join(SPREADS)}")
    with jax.default_matmul_precision("highest"):
        if len(devices) > 1 and spread == "dispatch":
            local = run_blocks(host, static, devices)
            jax.block_until_ready(local)
            _all_processes_arrive()
            return _gather_blocks([jax.tree.map(np.asarray, o) for o in local], devices)
        # placed once: a host batch would be copied to the device again by every segment's call
        batch = (place(host, scenario_sharding(devices)) if len(devices) > 1
                 else jax.device_put(host, devices[0]))
        out = run(batch, static)
        jax.block_until_ready(out)
        _all_processes_arrive()
        return jax.tree.map(_to_host, out)


def simulate_chunk_ticks(configs: Sequence[ScenarioConfig], indices: Sequence[int], *,
                         n_samples: int = 2048, dtype=None, shapes: Shapes | None = None,
                         devices=None) -> list:
    """Simulate the batch ``configs`` exactly as :func:`simulate` does (the same padding to the
    devices, split and array sizes ``shapes``), with the plant's per-tick log, and return, for
    each scenario of ``indices``, its (step log as a dict of arrays (K, ...), tick log
    (:class:`hlip_jax.plants.cassie.tick.TickLog` of arrays (K, ticks per step, ...))).

    Given a sweep chunk's scenarios (:func:`hlip_jax.sweepio.runner.chunk_configs`) on the devices it
    ran on, this is the chunk's run: the tick log rides along with the same computation, and
    the step log comes out as the sweep stored it (checked bit for bit on a float32 chunk of 10
    pushed robots over two CPU devices: ``hlip_jax.presentation.tick_report`` compares it every replay).
    :func:`simulate_ticks` (a batch of one) is not: float32 rounding changes with the batch, and
    a run at the margin can walk alone and fall in its chunk."""
    configs = list(configs)
    for j in indices:
        check_keeps_ticks(configs[j], j)
    _, out = _simulate_batch(configs, n_samples=n_samples, pad_to=None, dtype=dtype,
                             shapes=shapes, devices=devices, keep_ticks=True)
    picked = []
    for j in indices:
        one = jax.tree.map(lambda a: np.asarray(a)[j], out)
        picked.append((one, one.pop("ticks")))
    return picked


def check_keeps_ticks(cfg: ScenarioConfig, index: int) -> None:
    """ValueError naming the plants that keep one unless scenario ``index`` (``cfg``) runs a
    plant with a per-tick log."""
    if plants.load(cfg.plant).step_with_log is None:
        raise ValueError(f"plant: scenario {index}'s plant {cfg.plant!r} keeps no per-tick log; "
                         f"plants that do: " + ", ".join(
                             repr(n) for n in plants.NAMES if plants.load(n).step_with_log))


def simulate(configs: Sequence[ScenarioConfig], *, n_samples: int = 2048, pad_to: int | None = None,
             dtype=None, shapes: Shapes | None = None, devices=None,
             spread: str | None = None) -> Log:
    """Run every scenario of ``configs`` in one compiled, vmapped call and return the Log
    (numpy arrays, scenarios in the order given).

    ``pad_to`` pads the batch (repeating the last scenario) and ``shapes`` (:func:`shapes_of`
    the whole sweep) fixes the array sizes, so chunks of a sweep share one compile; padding
    is dropped from the Log.  With several devices (``devices``, default all of
    ``jax.devices()``: GPUs, or the CPU's cores as :mod:`hlip_jax.runtime.xla_flags` sets them up)
    the batch is padded to a multiple of their number and split over them along the scenario
    axis, each running its own scenarios' loop, as ``spread`` says (:data:`SPREADS`; by default
    :func:`spread_of` the devices: one split program on CPU devices, one block per GPU).
    While someone listens (:func:`hlip_jax.runtime.progress.listening`) every finished walking step
    is reported."""
    configs = list(configs)
    S = len(configs)
    host, out = _simulate_batch(configs, n_samples=n_samples, pad_to=pad_to, dtype=dtype,
                                shapes=shapes, devices=devices, keep_ticks=False, spread=spread)
    valid = out["valid"]
    valid_w = valid & np.concatenate([valid[:, 1:], np.zeros((S, 1), bool)], axis=1)  # k, k+1
    out["w"] = np.where(valid_w[..., None, None], out["w"], np.nan)
    return Log(A=np.asarray(host.mpc.A)[:S], B=np.asarray(host.mpc.B)[:S],
               K_gain=np.asarray(host.gain)[:S], anchor=np.asarray(host.anchor)[:S], **out)
