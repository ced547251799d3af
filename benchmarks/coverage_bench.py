"""Time the work after a simulation on a stored results directory: ``coverage.csv``'s rows and
the report, each in one process and with the worker processes (:mod:`hlip_jax.runtime.workers`), in
this one process run; the rows and report.md must come out the same.

Usage::

    python benchmarks/coverage_bench.py results/val      # a copy is analysed, DIR is not touched
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import math
import pathlib
import shutil
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hlip_jax.presentation import report
from hlip_jax.sweepio import store  # noqa: E402
from hlip_jax.analysis import settings as analysis_settings  # noqa: E402


def _same(a: list[dict], b: list[dict]) -> bool:
    def eq(x, y):
        return x == y or (isinstance(x, float) and isinstance(y, float) and math.isnan(x)
                          and math.isnan(y))
    return len(a) == len(b) and all(eq(r[k], s[k]) for r, s in zip(a, b) for k in r)


def _timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", type=pathlib.Path)
    a = ap.parse_args(argv)
    work = pathlib.Path(tempfile.mkdtemp()) / "r"
    shutil.copytree(a.results, work, ignore=shutil.ignore_patterns("figures", "report.*",
                                                                    "videos", ".lock"))
    s = dataclasses.replace(store.analysis_settings(work),
                            methods=analysis_settings.DEFAULT_METHODS)
    one, t_one = _timed(lambda: store.coverage_rows(work, s, workers=1))
    many, t_many = _timed(lambda: store.coverage_rows(work, s))
    print(f"coverage.csv rows ({len(one)}): one process {t_one:.1f} s, workers {t_many:.1f} s, "
          f"same rows: {_same(one, many)}")
    store.write_coverage_rows(work, one)
    digests = []
    for per_worker in (10 ** 9, report.REPORT_RUNS_PER_WORKER):
        report.REPORT_RUNS_PER_WORKER = per_worker
        _, t = _timed(lambda: report.write_report(work))
        digests.append(hashlib.sha256((work / "report.md").read_bytes()).hexdigest())
        print(f"report: {'one process' if per_worker == 10 ** 9 else 'workers'} {t:.1f} s")
    print(f"report.md the same: {digests[0] == digests[1]}")
    shutil.rmtree(work.parent)
    return 0


if __name__ == "__main__":
    sys.exit(main())
