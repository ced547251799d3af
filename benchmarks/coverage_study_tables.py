"""Markdown tables of a coverage-study results directory (docs/coverage_study.md).

Usage::

    python benchmarks/coverage_study_tables.py results/cov

Prints two tables:

* which robots walked, per path × peak speed: walked / runs with the exact 95 % Clopper–Pearson
  interval (:func:`hlip_jax.analysis.stats.clopper_pearson`), the median RMS COM distance to the path
  (``rms_track_err``) of the walkers, and the range of steps at which the others fell;
* one headline line per split (:func:`headline`), then per split the run-level rows of
  ``coverage.csv`` (:func:`coverage_table`): training / test runs (with their falls), runs
  covered with the Clopper–Pearson interval over runs, steps covered with the run-cluster
  bootstrap interval, E's half-width along the COM position c beside the q-quantile and the
  maximum of the test runs' largest |e_c| (metres).
"""

from __future__ import annotations

import argparse
import csv
import pathlib
import statistics
from collections import defaultdict

from hlip_jax.sweepio import store
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


def _read(path: pathlib.Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _f(v: str, nd: int) -> str:
    return "–" if v in ("", "nan") else f"{float(v):.{nd}f}"


def _ci(r: dict) -> str:
    if r["coverage"] in ("", "nan"):
        return "– (" + r["note"] + ")"
    return (f"{r['covered']}/{r['test_samples']} = {float(r['coverage']):.3f} "
            f"[{float(r['ci_low']):.3f}, {float(r['ci_high']):.3f}]")


W_NAMES = {"box": "mRPI, box W", "hull": "mRPI, hull W", "conformal_step": "mRPI, step q-box",
           "conformal_run": "E_q, mRPI shape", "conformal_box": "E_q, box"}

#: the methods the tables show (the step q-box stays in coverage.csv)
TABLE_METHODS = ("box", "conformal_run", "conformal_box")


def coverage_table(path: pathlib.Path, split: str) -> list[str]:
    """The run-level rows of ``coverage.csv`` at ``path`` for one split and the methods of
    :data:`TABLE_METHODS`, with the step-level coverage beside them and E's half-width along c
    against the test runs' largest |e_c|."""
    rows = [r for r in _read(path) if r["w_method"] in TABLE_METHODS]
    steps = {(r["group"], r["plane"], r["w_method"]): r for r in rows
             if r["level"] == "step" and r["split"] == split}
    out = ["| group | plane | E | train (fell) / test (fell) runs | runs covered [95 % CI] | "
           "steps covered [95 % CI, runs resampled] | E along c / q-quantile / largest test "
           "\\|e_c\\| [m] | E along c ÷ largest |",
           "|---|---|---|---|---|---|---|---:|"]
    for r in rows:
        if r["level"] != "run" or r["split"] != split:
            continue
        st = steps[(r["group"], r["plane"], r["w_method"])]
        ratio = ("–" if r["e_half_c"] in ("", "nan") else
                 f"{float(r['e_half_c']) / float(r['err_max_c']):.1f}")
        out.append(
            f"| {r['group']} | {r['plane']} | {W_NAMES[r['w_method']]} | {r['train_runs']} "
            f"({r['train_fell']}) / {r['test_runs']} ({r['test_fell']}) | {_ci(r)} | {_ci(st)} | "
            f"{_f(r['e_half_c'], 2)} / {_f(r['err_q_c'], 2)} / {_f(r['err_max_c'], 2)} | {ratio} |")
    return out


def headline(path: pathlib.Path, q: float = 0.9) -> list[str]:
    """One line per split and method of :data:`TABLE_METHODS` (calibrated sets first): the range
    of the run-level coverage, how many rows lie in [q − 0.05, q + 0.08], and the range of E's
    c half-width over the largest held-out |e_c|."""
    rows = [r for r in _read(path) if r["level"] == "run" and r["coverage"] not in ("", "nan")]
    out = []
    for split in dict.fromkeys(r["split"] for r in rows):
        for m in reversed(TABLE_METHODS):
            sel = [r for r in rows if r["split"] == split and r["w_method"] == m]
            if not sel:
                continue
            cov = [float(r["coverage"]) for r in sel]
            ratio = [float(r["e_half_c"]) / float(r["err_max_c"]) for r in sel]
            inside = sum(q - 0.05 <= c <= q + 0.08 for c in cov)
            out.append(f"- split {split}, {W_NAMES[m]}: run-level coverage {min(cov):.3f}–"
                       f"{max(cov):.3f}, mean {statistics.fmean(cov):.3f} ({inside} of "
                       f"{len(sel)} rows in [{q - 0.05:.2f}, {q + 0.08:.2f}]); E along c ÷ "
                       f"largest held-out |e_c| {min(ratio):.1f}–{max(ratio):.1f}")
    return out


def figure(results: pathlib.Path, group: str, png: str) -> None:
    """The report's figure (:func:`hlip_jax.presentation.report.fig_coverage_sets`) of one group of the seed
    split: held-out errors against the box W's mRPI set and the run-calibrated box E_q."""
    from hlip_jax.presentation import report
    from hlip_jax.analysis import coverage
    found = {label: (frame, sets_) for label, frame, sets_ in store.coverage_sets(results)}
    if group not in found:
        raise SystemExit(f"--figure: group {group!r}; allowed: {', '.join(found)}")
    frame, sets_ = found[group]
    report.fig_coverage_sets(coverage.PLANES[frame], sets_, pathlib.Path(png),
                             f"{group} (seed split)")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", type=pathlib.Path, help="results directory of a coverage study")
    ap.add_argument("--headline-only", action="store_true",
                    help="the walked table and the headline lines, no per-split tables")
    ap.add_argument("--figure", nargs=2, metavar=("GROUP", "PNG"),
                    help="also draw the report's figure of GROUP (seed split) into PNG")
    a = ap.parse_args(argv)
    if a.figure:
        figure(a.results, *a.figure)
    lines = walked_table(store.read_summary(a.results)) + [""]
    lines += headline(a.results / "coverage.csv") + [""]
    if a.headline_only:
        print("\n".join(lines))
        return
    for split in dict.fromkeys(r["split"] for r in _read(a.results / "coverage.csv")):
        lines += [f"### Split: {split}", ""]
        lines += coverage_table(a.results / "coverage.csv", split) + [""]
    print("\n".join(lines))


if __name__ == "__main__":
    main()
