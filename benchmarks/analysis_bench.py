"""Wall time of the per-scenario analysis that follows every chunk's simulation
(:func:`hlip_jax.analysis.metrics.scenario_metrics`: tracking metrics and the invariant-set coverage
columns of summary.csv), on the stored chunks of a results directory.

    python benchmarks/analysis_bench.py RESULTS_DIR [--chunks 3]

The first chunk's scenarios warm the compiled kernels up and are not counted; the others are
timed scenario by scenario and the mean is printed [s per scenario].
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hlip_jax.analysis import metrics
from hlip_jax.sweepio import store  # noqa: E402


def push_windows(cfg: dict) -> list:
    """A stored scenario's acting pushes as (start [s], duration [s]), read from the manifest's
    plain dict, so that code of other versions can time the same directory."""
    return [(p["time"], p["duration"]) for p in cfg.get("disturbance", {}).get("pushes", [])
            if p.get("force", 0) > 0 and p.get("duration", 0) > 0]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results")
    ap.add_argument("--chunks", type=int, default=3, help="chunks timed after the warm-up one")
    a = ap.parse_args(argv)
    cfgs = store.read_manifest(a.results)["configs"]
    files = store.chunk_files(a.results)[: a.chunks + 1]
    times = []
    for n, f in enumerate(files):
        z = store.load_chunk(f)
        for j, i in enumerate(z["index"]):
            t0 = time.perf_counter()
            metrics.scenario_metrics(z, j, True, push_windows(cfgs[int(i)]))
            if n:
                times.append(time.perf_counter() - t0)
    print(f"{len(times)} scenarios: {sum(times) / max(len(times), 1):.3f} s per scenario")
    return 0


if __name__ == "__main__":
    sys.exit(main())
