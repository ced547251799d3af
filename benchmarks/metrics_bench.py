"""Time the per-scenario summary metrics of one stored chunk (what ``hlip-sweep run`` computes
after each simulated chunk: :func:`hlip_jax.sweepio.runner.chunk_metrics`), coverage columns
included, three ways in this one process: the per-set reference (each scenario's four box
mRPI sets built and tested one at a time: ``estimators.fit``, ``invariant.coverage``, the path
before the batch), the batch with its membership kernels on the host CPU, and the batch on
JAX's default device when that is an accelerator, each with the facet templates built afresh
and again with them cached (as a run's later chunks find them); and check they give the same
numbers.

Usage::

    python benchmarks/metrics_bench.py results/val [--chunk 0] [--scenarios N]
"""

from __future__ import annotations

import argparse
import math
import pathlib
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import jax  # noqa: E402
import numpy as np  # noqa: E402

from hlip_jax.analysis import estimators, metrics, runs, splits  # noqa: E402
from hlip_jax.core import invariant as inv, sets  # noqa: E402
from hlip_jax.sweepio import runner, store, sweep  # noqa: E402


def _box_E(A_cl, run, p: int, steps):
    d = run.d[steps[1:] & steps[:-1], p]
    return estimators.fit("box", A_cl, [d], [np.zeros((0, d.shape[-1]))], [False], 0.5).E


def reference_columns(log: dict, s: int, pushes, warmup: int) -> dict:
    """The coverage columns of scenario ``s`` one set at a time (the per-set path)."""
    out = {k: math.nan for plane in "xy" for k in (
        f"cov_{plane}_inner", f"cov_{plane}_outer", f"cov_{plane}_heldout", f"e_size_{plane}")}
    Acl, _, run = runs.run_errors(log, s, pushes, warmup)
    m = run.masks
    early, late = splits.time_halves(m.kept)
    for p, plane in enumerate("xy"):
        try:
            E = _box_E(Acl[p], run, p, m.alive & ~m.push_window)
        except ValueError:
            continue
        c = inv.coverage(E, run.kept_e(p))
        out.update({f"cov_{plane}_inner": c.inner, f"cov_{plane}_outer": c.outer,
                    f"e_size_{plane}": float(E.volume())})
        try:
            out[f"cov_{plane}_heldout"] = inv.coverage(_box_E(Acl[p], run, p, early),
                                                       run.e[late, p]).outer
        except ValueError:
            pass
    return out


def _differences(a: list[dict], b: list[dict]) -> int:
    return sum(not (math.isclose(x[k], y[k], rel_tol=1e-9) or (math.isnan(x[k]) and math.isnan(y[k])))
               for x, y in zip(a, b) for k in y)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("dir", type=pathlib.Path)
    p.add_argument("--chunk", type=int, default=0)
    p.add_argument("--scenarios", type=int, default=None, help="the first N of the chunk")
    a = p.parse_args(argv)
    man = store.read_manifest(a.dir)
    arrays = dict(np.load(store.chunk_path(a.dir, a.chunk), allow_pickle=False))
    n = len(arrays["index"]) if a.scenarios is None else a.scenarios
    arrays = {k: v[:n] for k, v in arrays.items()}
    cfgs = [sweep.config_from_dict(man["configs"][int(i)]) for i in arrays["index"]]
    pushes = [metrics.push_windows(c) for c in cfgs]
    warmup = int(man.get("analysis", {}).get("warmup", 4))
    cpu = jax.local_devices(backend="cpu")[0]
    print(f"{n} scenarios; default device {jax.devices()[0].platform}", flush=True)
    sets.box_sum_template.cache_clear()
    t = time.perf_counter()
    with jax.default_device(cpu):
        ref = [reference_columns(arrays, s, w, warmup) for s, w in enumerate(pushes)]
    print(f"per-set reference, host CPU: {time.perf_counter() - t:.1f} s", flush=True)
    devices = [("host CPU", cpu)] + ([("default device", None)] if jax.devices()[0] != cpu else [])
    worst = 0
    for name, dev in devices:
        for attempt in ("templates built", "templates cached"):
            if attempt == "templates built":
                sets.box_sum_template.cache_clear()
            t = time.perf_counter()
            if dev is None:
                rows = runner.chunk_metrics(arrays, pushes, True, warmup=warmup)
            else:
                with jax.default_device(dev):
                    rows = runner.chunk_metrics(arrays, pushes, True, warmup=warmup)
            print(f"batch, {name}, {attempt}: {time.perf_counter() - t:.1f} s", flush=True)
        worst = max(worst, _differences(rows, ref))
    print(f"coverage entries differing from the reference: {worst} of {n * 8}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
