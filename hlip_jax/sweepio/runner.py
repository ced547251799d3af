"""The run loop of a sweep: chunks of scenarios simulated one compiled call at a time, each
stored as soon as it is done (:mod:`hlip_jax.sweepio.store`), resume of an interrupted run, and the
progress line (scenarios done, rate, ETA, and the walking step reached inside the running
chunk through :mod:`hlip_jax.runtime.progress`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import math
import os
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np

from hlip_jax.runtime import impl, progress
from hlip_jax.analysis import metrics
from hlip_jax.sweepio import store
from hlip_jax.analysis import masks
from hlip_jax.analysis import settings as analysis_settings
from hlip_jax.sweepio import sweep as sweep_mod


@dataclasses.dataclass
class RunResult:
    out_dir: Path
    n_scenarios: int
    n_chunks: int
    chunks_run: int          # simulated in this call
    chunks_skipped: int      # already present (resume)
    complete: bool
    seconds: float
    #: wall seconds per stage of this call: "simulation" (compiles included), "analysis" (the
    #: chunks' per-scenario metrics), "summary.csv and coverage.csv", and where the closed loop
    #: reports its steps :data:`FIRST_SEGMENT` (part of "simulation")
    stages: dict = dataclasses.field(default_factory=dict)


class Progress:
    """Plain-text progress on a stream: scenarios done/total, rate, ETA."""

    def __init__(self, total: int, label: str, stream=None, enabled: bool = True):
        self.total, self.label, self.enabled = total, label, enabled
        self.stream = stream if stream is not None else sys.stderr
        self.t0 = time.monotonic()
        self.done0 = None
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()

    def note(self, text: str) -> None:
        """One line of news (a bad chunk found on resume) on the stream, even when the
        progress itself is off: a repair is worth saying."""
        self.stream.write(f"[{self.label}] {text}\n")
        self.stream.flush()

    def update(self, done: int, note: str = "", eta: float | None = None) -> None:
        """Progress after ``done`` scenarios; ``eta`` [s] (from inside a running chunk, see
        :func:`_step_news`) stands in for the ETA until finished chunks give a rate."""
        if not self.enabled:
            return
        if self.done0 is None:
            self.done0, self.t0 = done, time.monotonic()
            rate_s, eta_s = "-", "-"
        else:
            dt = time.monotonic() - self.t0
            rate = (done - self.done0) / dt if dt > 0 else 0.0
            rate_s = f"{rate:.2f}/s" if rate else "-"
            eta_s = f"{(self.total - done) / rate:.0f}s" if rate > 0 else "-"
        if eta is not None and eta_s == "-":
            eta_s = f"{eta:.0f}s"
        pct = 100.0 * done / max(self.total, 1)
        msg = (f"[{self.label}] {done}/{self.total} scenarios ({pct:3.0f}%)  rate {rate_s}  "
               f"ETA {eta_s}{'  ' + note if note else ''}")
        if self.tty:
            self.stream.write("\r" + msg.ljust(79))
            if done >= self.total:
                self.stream.write("\n")
        else:
            self.stream.write(msg + "\n")
        self.stream.flush()


def default_batch(n: int, cap: int | None = None) -> int:
    """Chunk size for ``n`` scenarios: at most ``cap`` (16 on CPU, 1024 on accelerators) and
    balanced, ceil(n / ceil(n / cap)), so the padded last chunk wastes little (20 → 10 + 10)."""
    if cap is None:
        try:
            import jax
            cap = 16 if jax.default_backend() == "cpu" else 1024
        except Exception:   # pragma: no cover
            cap = 16
    n_chunks = max(1, math.ceil(n / cap))
    return max(1, math.ceil(n / n_chunks))


def chunk_configs(configs: list, batch: int, i: int) -> list:
    """The scenarios chunk ``i`` of ``configs`` simulates: its own, padded to ``batch`` with
    its last one (so every chunk has the batch's shape and shares one compile)."""
    a, b = store.chunk_ranges(len(configs), batch)[i]
    return configs[a:b] + [configs[b - 1]] * (batch - (b - a))


def _default_simulate(configs):
    """The closed loop with sweep-wide array shapes, so every chunk reuses one compile."""
    from hlip_jax.simulation import arrays, execution
    shapes = arrays.shapes_of(configs)
    return functools.partial(execution.simulate, shapes=shapes)


def run_sweep(sw: "sweep_mod.Sweep", out_dir, *, batch: int | None = None, resume: bool = False,
              overwrite: bool = False, simulate: Callable | None = None,
              max_chunks: int | None = None, progress: bool = True, stream=None,
              with_coverage: bool = True) -> RunResult:
    """Simulate every scenario of ``sw`` chunk by chunk into ``out_dir``.

    Args:
      sw: the validated sweep (:func:`hlip_jax.sweepio.sweep.load_sweep`).
      out_dir: results directory (created).
      batch: scenarios per chunk (one ``simulate`` call); default :func:`default_batch`,
        capped at the number of scenarios.  On resume, the manifest's value unless given.
      resume: skip chunks already stored (config hash must match); every stored chunk is
        verified in full (:func:`store.chunk_problem`) and a bad one is simulated again, named on
        the progress stream.
      overwrite: discard an existing run in ``out_dir`` (its manifest, chunks, summary).
      simulate: ``configs -> Log`` (default :func:`hlip_jax.simulation.execution.simulate`).
      max_chunks: stop after simulating this many chunks (interruptions, tests).
      with_coverage: compute the invariant-set coverage metrics per scenario (≈ 30 ms per
        scenario on a CPU core after a one-time JIT warm-up; False leaves those columns NaN,
        for very large sweeps).  Part of the config hash.
    Raises:
      store.StoreError: the directory holds another run (or a different config, on resume), another
        process is running into it (:func:`store.results_lock`), or it cannot be created or written.
    """
    out = Path(out_dir)
    configs = list(sw.scenarios)
    if not configs:
        raise store.StoreError("the sweep expands to no scenarios")
    resolved = resolve_impl(sw)
    configs = impl.apply(configs, resolved.settings)
    _check_gains(sw, configs)
    bar = Progress(len(configs), sw.name, stream=stream, enabled=progress)
    if progress and any(c.plant == "cassie" for c in configs):
        bar.note(resolved.describe())
    with store.results_lock(out):
        return _run_locked(sw, out, configs, batch, resume, overwrite, simulate, max_chunks,
                           bar, with_coverage, resolved)


def _check_gains(sw, configs) -> None:
    """SweepError, before anything is written, for a scenario whose stepping gain is not
    finite: LQR weights inside their ranges whose Riccati solution overflows (``r = 1e-9``
    with ``q_* = 1e6``) would run the closed loop on NaN and fail in its analysis."""
    from hlip_jax.simulation import arrays
    seen = set()
    for c in configs:
        key = (c.hlip, c.gain, c.s2s)
        if key in seen:
            continue
        seen.add(key)
        if np.all(np.isfinite(arrays.stepping_gain(c))):
            continue
        g = c.gain
        design = (f"gain.type = 'lqr' with q_c = {g.q_c:g}, q_p = {g.q_p:g}, q_v = {g.q_v:g}, "
                  f"r = {g.r:g}" if g.type == "lqr" else f"gain.type = {g.type!r}")
        if c.s2s.model != "hlip":        # the gain is designed on the file's S2S map
            raise sweep_mod.SweepError(
                f"{sw.source}: scenario {c.name!r}: {design} on the S2S model of s2s.file "
                f"{c.s2s.file!r} gives no finite stepping gain; allowed: a model file of "
                "`hlip-sweep identify` whose map has a finite gain, or s2s.model = 'hlip'")
        raise sweep_mod.SweepError(
            f"{sw.source}: scenario {c.name!r}: {design} gives no finite stepping gain (the "
            "design's Riccati solution overflows); allowed: weights whose gain is finite "
            "(a larger gain.r or smaller gain.q_*)")


def _analysis_change(old: dict, sw) -> str | None:
    """Which ``[analysis]`` setting of the sweep differs from the one the interrupted run
    records (its manifest's ``analysis``), or None: the chunks to come would compute their
    coverage columns with another warm-up, and the report would still read the run's (a
    setting the manifest does not record, written by an earlier version, is not compared)."""
    before, now = old.get("analysis"), analysis_settings.to_dict(sw.analysis)
    if not isinstance(before, dict):
        return None
    key = next((k for k in now if k in before and before[k] != now[k]), None)
    if key is None:
        return None
    return (f"the sweep's [analysis] differs from the run's ({key}: {before.get(key)!r} in "
            f"{store.MANIFEST}, {now[key]!r} now)")


def resolve_impl(sw) -> "impl.Resolved":
    """The sweep's implementation profile (:mod:`hlip_jax.runtime.impl`) on this process's JAX
    backend; StoreError (one line) when the profile does not fit the backend."""
    import jax
    try:
        return impl.resolve(sw.impl_profile, jax.default_backend(), sw.impl_explicit,
                            impl.warp_available())
    except ValueError as err:
        raise store.StoreError(str(err)) from None


def _check_existing(out: Path, old: dict | None, resume: bool, overwrite: bool, chash: str,
                    size: tuple[int, int], with_coverage: bool) -> dict | None:
    """Refuse a run into a directory holding another one (or resuming a different config);
    with ``overwrite``, delete the old run.  ``size``: (chunk size, scenario count).  Returns
    the manifest to continue, or None."""
    batch, n = size
    if old is None and resume:
        raise store.StoreError(f"--resume: {out} holds no run to resume (no {store.MANIFEST}); "
                               "drop --resume to start one")
    if old is None:
        # the lock, and the private stores other processes of a --distributed run keep here
        prefix = store.PROCESS_STORE.format("")
        foreign = sorted(p.name for p in out.iterdir()
                         if p.name != store.LOCK and not p.name.startswith(prefix))
        if foreign:
            raise store.StoreError(f"--out {out}: a directory that is not a results directory "
                                   f"(no {store.MANIFEST}; it holds {foreign[0]!r}"
                                   f"{' and more' if len(foreign) > 1 else ''}); choose an empty "
                                   "or new directory")
    if old is not None and not (resume or overwrite):
        state = "complete" if old.get("status") == "complete" else "incomplete"
        raise store.StoreError(f"{out} already holds a run ({state}); pass --resume to continue it, "
                         f"--overwrite to discard it, or choose another --out")
    if old is not None and resume and old.get("config_hash") != chash:
        why = ("the chunk size differs (manifest batch "
               f"{old.get('batch')}, now {batch})" if old.get("batch") != batch
               else "the coverage setting differs (--no-coverage)"
               if old.get("with_coverage", True) != with_coverage
               else "the precision differs (JAX_ENABLE_X64)"
               if old.get("x64", _x64()) != _x64()
               else f"the scenario count differs (manifest {old.get('n_scenarios')}, now {n}: "
               "give the --limit of the interrupted run, or none)"
               if old.get("n_scenarios") != n
               else _numerics_change(old) or "the expanded sweep config differs")
        raise store.StoreError(f"refusing to resume {out}: {why}; config hash {chash[:12]} vs "
                         f"{str(old.get('config_hash'))[:12]} in {store.MANIFEST}")
    if old is not None and overwrite and not resume:
        _discard_run(out)
        return None
    return old if resume else None


def _numerics_change(old: dict) -> str | None:
    """Which process setting that changes the numbers (:func:`numerics`) differs from the
    interrupted run's, named by its environment variable; None when they agree or the run
    did not record them."""
    before = (old.get("run_identity") or {}).get("numerics")
    now = numerics()
    if not isinstance(before, dict) or before == now:
        return None
    if before.get("xla_flags") != now["xla_flags"]:
        return (f"XLA_FLAGS differs (the run's {' '.join(before.get('xla_flags') or []) or 'none'}"
                f", now {' '.join(now['xla_flags']) or 'none'}; it changes the numbers)")
    return (f"JAX's random numbers differ (JAX_DEFAULT_PRNG_IMPL {before.get('prng')}, now "
            f"{now['prng']}; jax_threefry_partitionable {before.get('threefry_partitionable')}, "
            f"now {now['threefry_partitionable']})")


def _refuse_changed_file(out: Path, old: dict, configs, files: dict) -> None:
    """Refuse to resume ``out`` when a data file the configs name (``files``: {path: SHA-256})
    holds other contents than when the run began (its manifest's ``run_identity``): the
    chunks to come would be computed with another W or model than those stored."""
    recorded = (old.get("run_identity") or {}).get("files") or {}
    if not isinstance(recorded, dict):
        return
    fields = sweep_mod.data_files(configs)
    for path, digest in files.items():
        before = recorded.get(path)
        if before is not None and before != digest:
            raise store.StoreError(
                f"refusing to resume {out}: {fields[path]} {path} changed since the run "
                f"(sha256 {digest[:12]} now, {str(before)[:12]} in {store.MANIFEST}); restore "
                "it, or rerun with --overwrite or another --out")


#: what a run and its report write into a results directory, besides the lock
RUN_FILES = ("chunks", "figures", "ticks", "summary.csv", "coverage.csv", "report.html",
             "report.md", "manifest.json")


def _discard_run(out: Path) -> None:
    """Remove everything an earlier run wrote in ``out`` (:data:`RUN_FILES`): its chunks,
    summaries, report, figures and per-tick logs; a symbolic link is removed, never followed."""
    import shutil
    for name in RUN_FILES:
        p = out / name
        if p.is_symlink() or p.is_file():
            p.unlink()
        elif p.is_dir():
            shutil.rmtree(p)


def sweep_layout(sw) -> dict:
    """The sweep's grid axes (values as written) and path names: how the report groups and
    labels the results (the manifest's ``axes`` and ``paths``)."""
    return {"axes": [{"fields": list(a.fields),
                      "values": [[sweep_mod.as_written(x) for x in v] for v in a.values],
                      "zipped": a.zipped} for a in sw.axes],
            "paths": list(sw.paths)}


def numerics() -> dict:
    """The process's settings besides the configs that change a chunk's numbers: the user's
    XLA flags (``XLA_FLAGS`` but the CPU device count the CLI sets per machine, e.g.
    ``--xla_cpu_enable_fast_math``) and JAX's random-number implementation
    (``JAX_DEFAULT_PRNG_IMPL``, ``jax_threefry_partitionable``)."""
    import jax

    from hlip_jax.runtime import xla_flags
    flags = sorted(f for f in os.environ.get("XLA_FLAGS", "").split()
                   if f.partition("=")[0] != xla_flags.DEVICES_FLAG)
    return {"xla_flags": flags, "prng": str(jax.config.jax_default_prng_impl),
            "threefry_partitionable": bool(getattr(jax.config, "jax_threefry_partitionable",
                                                   False))}


def _new_manifest(sw, configs, batch: int, n_chunks: int, chash: str, with_coverage: bool) -> dict:
    """The manifest of a fresh run (before the environment and status fields)."""
    return {
        "format": store.MANIFEST_FORMAT,
        "sweep_name": sw.name,
        "sweep_file": sw.source,
        "sweep_text": sw.text,
        "description": sw.description,
        "analysis": analysis_settings.to_dict(sw.analysis),
        **sweep_layout(sw),
        "n_scenarios": len(configs),
        "total_before_limit": sw.total,
        "batch": batch,
        "with_coverage": with_coverage,
        "n_chunks": n_chunks,
        "config_hash": chash,
        "x64": _x64(),
        "configs": [sweep_mod.config_to_dict(c) for c in configs],
    }


def _run_locked(sw, out: Path, configs, batch, resume, overwrite, simulate, max_chunks, bar,
                with_coverage, resolved) -> RunResult:
    """:func:`run_sweep` with the directory lock held."""
    n = len(configs)
    # lexists, not is_file: a manifest.json that is a FIFO, a directory or a dangling link is
    # named by read_manifest ("not a manifest"), never taken for a directory without one
    old = store.read_manifest(out) if os.path.lexists(out / store.MANIFEST) else None
    if batch is None:
        batch = int(old["batch"]) if (resume and old is not None) else default_batch(n)
    if isinstance(batch, bool) or not isinstance(batch, int) or batch < 1:
        raise store.StoreError(f"--batch: expected an integer >= 1, got {batch!r}")
    batch = min(batch, n)
    # everything that changes a chunk's numbers is in the run's identity: the configs, the
    # chunk size, the per-scenario metrics, the precision and the process's numerics; and the
    # sweep's axes and paths, which label the results in the report
    extra = store.legacy_identity(batch, _x64(), with_coverage)
    extra.update(numerics=numerics(), layout=store.layout_digest(sweep_layout(sw)))
    # and the contents of the data files they name (a hull W, an identified model)
    files = sweep_mod.file_digests(configs)
    if files:
        extra["files"] = files
    chash = sweep_mod.config_hash(configs, extra)
    if resume and old is not None and old.get("config_hash") != chash:
        _refuse_changed_file(out, old, configs, files)
    old = _check_existing(out, old, resume, overwrite, chash, (batch, n), with_coverage)
    why = _analysis_change(old, sw) if old is not None else None
    if why:
        raise store.StoreError(f"refusing to resume {out}: {why}; resume with the run's "
                               f"[analysis] (`hlip-sweep coverage {out} --q Q --warmup K` then "
                               "rewrites coverage.csv), or rerun with --overwrite")
    ranges = store.chunk_ranges(n, batch)
    man = dict(old) if old else _new_manifest(sw, configs, batch, len(ranges), chash,
                                              with_coverage)
    man.setdefault("run_identity", extra)   # what config_hash covers besides the configs
    man["impl"] = resolved._asdict()
    man.update({"versions": store.package_versions(), "jax": store.jax_info(), "git_commit": store.git_commit(),
                "start_time": man.get("start_time") or store.utc_now(), "end_time": None,
                "status": "running"})
    man.setdefault("resumed_at", [])
    if old:
        man["resumed_at"].append(store.utc_now())
    try:
        (out / store.CHUNK_DIR).mkdir(parents=True, exist_ok=True)
        store.write_manifest(out, man)
    except OSError as err:
        where = f" ({err.filename})" if err.filename else ""
        raise store.StoreError(f"--out {out}: cannot write the results directory{where}: "
                               f"{err.strerror or err}") from None

    sim = simulate if simulate is not None else _default_simulate(configs)
    t0 = time.monotonic()
    good = _verify_stored(out, ranges, bar, chash)
    done = sum(b - a for i, (a, b) in enumerate(ranges) if i in good)
    bar.update(done, "resuming" if done else "compiling")
    ran = skipped = 0
    stages = {"simulation": 0.0, "analysis": 0.0}
    try:
        ran, skipped, done = _run_chunks(out, configs, ranges, batch, sim, bar, done, max_chunks,
                                         with_coverage, good, chash, sw.analysis.warmup, stages)
    except BaseException:
        # interrupted or failed: finished chunks stay; the manifest says the run is incomplete
        man.update(status="incomplete", end_time=store.utc_now(),
                   seconds=man.get("seconds", 0.0) + (time.monotonic() - t0))
        with contextlib.suppress(OSError):    # e.g. the disk is full: the first error counts
            store.write_manifest(out, man)
        raise
    complete = len(good) == len(ranges)
    man.update(status="complete" if complete else "incomplete", end_time=store.utc_now(),
               seconds=man.get("seconds", 0.0) + (time.monotonic() - t0))
    store.write_manifest(out, man)
    if complete:
        t1 = time.monotonic()
        with on_host():
            store.write_summary(out)
            store.write_coverage(out)
        stages["summary.csv and coverage.csv"] = time.monotonic() - t1
    return RunResult(out, n, len(ranges), ran, skipped, complete, time.monotonic() - t0,
                     _in_order(stages))


def _in_order(stages: dict) -> dict:
    """``stages`` with :data:`FIRST_SEGMENT` right after "simulation", the stage it is part of."""
    order = ["simulation", FIRST_SEGMENT]
    return {k: stages[k] for k in order + [k for k in stages if k not in order] if k in stages}


def _verify_stored(out: Path, ranges, bar, run_id: str) -> set[int]:
    """Indices of the stored chunks that are sound and of the run ``run_id``
    (:func:`store.chunk_problem`); each stored but bad chunk is named on the progress stream
    and will be simulated again."""
    good = set()
    for i, (a, b) in enumerate(ranges):
        p = store.chunk_path(out, i)
        if not p.is_file():
            continue
        why = store.chunk_problem(p, a, b, run_id)
        if why is None:
            good.add(i)
        else:
            bar.note(f"{p.name}: {why}; simulating it again")
    return good


@contextlib.contextmanager
def on_host():
    """Run the analysis (invariant sets, coverage, report) on the host CPU.  Its arrays are
    tiny and their shapes change from scenario to scenario (the number of valid steps), so
    on an accelerator every call pays a kernel launch and often a compile: on an H100 the
    analysis of one 624-scenario chunk ran for minutes after its simulation had ended."""
    import jax
    with jax.default_device(jax.local_devices(backend="cpu")[0]):
        yield


def _step_news(bar, done: int, chunk: int, n_chunks: int, duration: float = 0.0,
               later: int | None = None, every: float = 5.0, step_period: float = 0.0):
    """A :mod:`hlip_jax.runtime.progress` listener: the walking step reached inside the running chunk
    and about how much of the chunk's longest ``duration`` [s] that simulates (k steps of
    ``step_period`` [s], at most ``duration``; k/n of it without a period), on the progress
    line at most every ``every`` seconds.  From the second news on it also gives an ETA that leaves
    the compile out: with r the steps per second since the first news (which arrives after the
    compile), the rest of this chunk takes (n − k)/r and each of the ``later`` chunks still
    to run after it (default: every later chunk) n/r (their programs are compiled already)."""
    later = n_chunks - chunk - 1 if later is None else later
    last = [-math.inf]
    first: list = []

    def hear(k: int, n_steps: int) -> None:
        now = time.monotonic()
        if not first:
            first.extend((now, k))
        if now - last[0] < every and k != n_steps:
            return
        last[0] = now
        dt, dk = now - first[0], k - first[1]
        eta = None
        if dt > 0 and dk > 0:
            per_step = dt / dk
            eta = per_step * ((n_steps - k) + n_steps * later)
        t = min(duration, k * step_period) if step_period > 0 else duration * k / n_steps
        sim = f" (≈ {t:.1f} of {duration:g} s simulated)" if duration > 0 else ""
        bar.update(done, f"chunk {chunk + 1}/{n_chunks}: step {k}/{n_steps}{sim}", eta=eta)
    return hear


#: the stage that times a run's first simulated segment from the start of its chunk
FIRST_SEGMENT = "first segment (compile included)"


def _first_news(listener, stages: dict, t0: float):
    """``listener``, and the first news of the run's first chunk timed into ``stages`` as
    :data:`FIRST_SEGMENT` (seconds since ``t0``, the chunk's start: mostly the compile)."""
    def hear(k: int, n_steps: int) -> None:
        stages.setdefault(FIRST_SEGMENT, time.monotonic() - t0)
        listener(k, n_steps)
    return hear


def _chunk_news(bar, done, i, ranges, chunk_cfgs, good, budget):
    """The :func:`_step_news` listener of chunk ``i``: its longest duration and step period,
    and the chunks still to run after it (not stored yet, at most ``budget`` more when
    ``--max-chunks`` limits the run)."""
    later = sum(j not in good for j in range(i + 1, len(ranges)))
    later = later if budget is None else max(0, min(later, budget))
    return _step_news(bar, done, i, len(ranges), max(c.duration for c in chunk_cfgs), later,
                      step_period=max(c.hlip.t_ssp + c.hlip.t_dsp for c in chunk_cfgs))


def _x64() -> bool:
    import jax
    return bool(jax.config.jax_enable_x64)


def _run_chunks(out, configs, ranges, batch, sim, bar, done, max_chunks, with_coverage, good,
                run_id: str, warmup: int, stages: dict):
    """Simulate and store every chunk not in ``good`` (verified stored chunk indices, which
    grows as chunks are written); returns (chunks run, chunks skipped, scenarios done).
    ``warmup``: the sweep's ``[analysis]`` warm-up, for the summary's coverage metrics;
    ``stages``: its "simulation" and "analysis" wall seconds grow by each chunk's."""
    ran = skipped = 0
    for i, (a, b) in enumerate(ranges):
        p = store.chunk_path(out, i)
        if i in good:
            skipped += 1
            continue
        if max_chunks is not None and ran >= max_chunks:
            break
        chunk_cfgs = chunk_configs(configs, batch, i)
        try:
            budget = None if max_chunks is None else max_chunks - ran - 1
            # listened to with or without --quiet, so that the loop runs the same segmented
            # program either way: the progress output must not change the numbers
            t_sim = time.monotonic()
            news = _chunk_news(bar, done, i, ranges, chunk_cfgs, good, budget)
            with progress.listening(_first_news(news, stages, t_sim) if ran == 0 else news):
                log = sim(chunk_cfgs)
            stages["simulation"] += time.monotonic() - t_sim
        except (ImportError, NotImplementedError) as err:
            plants = sorted({c.plant for c in chunk_cfgs})
            raise store.StoreError(f"the closed loop for plant {', '.join(plants)} is not available: "
                             f"{type(err).__name__}: {err}") from None
        arrays = store.log_to_arrays(log, b - a)
        arrays["index"] = np.arange(a, b, dtype=np.int64)
        arrays[store.RUN_ID] = np.full(b - a, run_id)
        t_met = time.monotonic()
        mets = chunk_metrics(arrays, [metrics.push_windows(c) for c in chunk_cfgs[:b - a]],
                             with_coverage, warmup=warmup)
        stages["analysis"] += time.monotonic() - t_met
        for k in metrics.SUMMARY_METRICS:
            arrays[f"metric.{k}"] = np.asarray([m[k] for m in mets], np.float64)
        store.save_npz_atomic(p, arrays)
        good.add(i)
        ran += 1
        done += b - a
        bar.update(done)
    return ran, skipped, done


def chunk_metrics(arrays: dict, pushes: list, with_coverage: bool,
                  warmup: int = masks.WARMUP) -> list[dict]:
    """Summary metrics of every scenario of a stored chunk, in scenario order
    (:func:`hlip_jax.analysis.metrics.chunk_metrics`): the coverage columns' mRPI sets of the
    whole chunk built per closed-loop matrix and their membership tests batched per facet
    template, on JAX's default device (the accelerator that simulated the chunk, if any)."""
    return metrics.chunk_metrics(arrays, pushes, with_coverage, warmup)
