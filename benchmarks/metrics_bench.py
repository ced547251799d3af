"""Time the per-scenario summary metrics of one stored chunk (what ``hlip-sweep run`` computes
after each simulated chunk: :func:`hlip_jax.sweepio.runner.chunk_metrics`), with the coverage columns,
in one process and with the runner's worker processes, and check both give the same numbers.

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

import numpy as np  # noqa: E402

from hlip_jax.analysis import metrics
from hlip_jax.sweepio import runner, store, sweep  # noqa: E402


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
    rows = {}
    for workers in (1, runner.metric_workers(n)):
        t = time.perf_counter()
        rows[workers] = runner.chunk_metrics(arrays, pushes, True, workers=workers, warmup=warmup)
        print(f"{n} scenarios, {workers} process(es): {time.perf_counter() - t:.1f} s", flush=True)
    a_, b_ = rows.values()
    same = all(math.isclose(x[k], y[k], rel_tol=1e-12) or (math.isnan(x[k]) and math.isnan(y[k]))
               for x, y in zip(a_, b_) for k in x)
    print("same numbers:", same)
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
