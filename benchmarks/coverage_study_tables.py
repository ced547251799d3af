"""Markdown tables of a coverage-study results directory (docs/coverage_study.md).

Usage::

    python benchmarks/coverage_study_tables.py results/cov

Prints two tables:

* which robots walked, per path × peak speed: walked / runs with the exact 95 % Clopper–Pearson
  interval (:func:`hlip_jax.analysis.stats.clopper_pearson`), the median RMS COM distance to the path
  (``rms_track_err``) of the walkers, and the range of steps at which the others fell;
* the across-run coverage of ``coverage.csv`` per (path, plane, W method): training / test runs
  (with how many of them fell), test samples, coverage and its interval, E's half-extent along
  the COM position c and the largest test |e_c| (both in metres).
"""

from __future__ import annotations

import argparse
import csv
import pathlib
import statistics
from collections import defaultdict

from hlip_jax import store
from hlip_jax.analysis import stats


def walked_table(rows: list[dict]) -> list[str]:
    """Path × peak speed table of the summary rows ``rows``."""
    cells: dict[tuple[str, float], list[dict]] = defaultdict(list)
    for r in rows:
        cells[(r["path"], float(r["path.peak_speed"]))].append(r)
    paths = list(dict.fromkeys(p for p, _ in cells))
    speeds = sorted({v for _, v in cells})
    out = ["| path \\ peak speed | " + " | ".join(f"{v:g} m/s" for v in speeds) + " |",
           "|---" * (len(speeds) + 1) + "|"]
    for p in paths:
        out.append(f"| {p} | " + " | ".join(_walked_cell(cells[(p, v)]) for v in speeds) + " |")
    total = sum(r["status"] == "ok" for r in rows)
    out += ["", f"{total} of {len(rows)} walked."]
    return out


def _walked_cell(rows: list[dict]) -> str:
    ok = [r for r in rows if r["status"] == "ok"]
    lo, hi = stats.clopper_pearson(len(ok), len(rows))
    text = f"{len(ok)}/{len(rows)} [{lo:.2f}, {hi:.2f}]"
    if ok:
        text += f", {statistics.median(float(r['rms_track_err']) for r in ok):.2f} m"
    fell = sorted(int(r["fail_step"]) for r in rows if r["status"] != "ok")
    if fell:
        text += f"; fell at {fell[0]}–{fell[-1]}" if len(fell) > 1 else f"; fell at {fell[0]}"
    return text


def coverage_table(path: pathlib.Path) -> list[str]:
    """The rows of ``coverage.csv`` at ``path``."""
    out = ["| path | plane | W | train (fell) / test (fell) runs | test samples | coverage | "
           "95 % interval | E half-extent in c [m] | largest test \\|e_c\\| [m] |",
           "|---|---|---|---|---:|---:|---|---:|---:|"]
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            w = "box" if r["w_method"] == "box" else f"quantile q={float(r['q']):g}"
            out.append(
                f"| {r['group']} | {r['plane']} | {w} | {r['train_runs']} ({r['train_fell']}) / "
                f"{r['test_runs']} ({r['test_fell']}) | {r['test_samples']} | "
                f"{float(r['coverage']):.3f} | "
                f"[{float(r['ci_low']):.3f}, {float(r['ci_high']):.3f}] | "
                f"{float(r['e_c_max']):.2f} | {float(r['err_c_max']):.2f} |")
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", type=pathlib.Path, help="results directory of a coverage study")
    a = ap.parse_args(argv)
    lines = walked_table(store.read_summary(a.results)) + [""]
    lines += coverage_table(a.results / "coverage.csv")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
