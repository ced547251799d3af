"""Two runs of the Cassie validation set side by side: walking rates per set, Fisher's test.

    python benchmarks/compare_runs.py A_SUMMARY.csv B_SUMMARY.csv [--labels A B]

Each argument is a ``summary.csv`` (or ``.csv.gz``) of a run of ``sweeps/cassie_validation.toml``
or a file extending it.  The sets are those of docs/cassie_validation: pushes by force and
side, the noisy paths, the circles, and all runs.  Prints a Markdown table: each run's robots
that walked to the end with the 95 % Clopper–Pearson interval, the two-sided Fisher exact p of
the 2 × 2 table, and the scenarios whose outcome differs.
"""

from __future__ import annotations

import argparse
import csv
import gzip
import math
import pathlib
import re
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hlip_jax.analysis.stats import rate_text  # noqa: E402

SETS = (
    ("pushes 100 N towards +y", re.compile(r"push-100-left-")),
    ("pushes 100 N towards −y", re.compile(r"push-100-right-")),
    ("pushes 200 N towards +y", re.compile(r"push-200-left-")),
    ("pushes 200 N towards −y", re.compile(r"push-200-right-")),
    ("step noise, 20 s", re.compile(r"noise-")),
    ("circles, 20 s", re.compile(r"circle-")),
    ("all runs", re.compile(r"")),
)


def fisher_exact(a: int, b: int, c: int, d: int) -> float:
    """Two-sided Fisher exact p of the table [[a, b], [c, d]]: the total hypergeometric
    probability of the tables with the same margins that are no more probable than this one
    (with a relative slack of 1e-7 for ties in floating point)."""
    row, col, n = a + b, a + c, a + b + c + d
    prob = lambda x: math.comb(col, x) * math.comb(n - col, row - x) / math.comb(n, row)
    p0 = prob(a)
    lo, hi = max(0, row + col - n), min(row, col)
    return min(1.0, sum(p for p in map(prob, range(lo, hi + 1)) if p <= p0 * (1 + 1e-7)))


def read(path: pathlib.Path) -> dict[str, bool]:
    """Scenario name → walked to the end (status "ok")."""
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt", newline="") as f:
        return {r["name"]: r["status"] == "ok" for r in csv.DictReader(f)}


def table(a: dict[str, bool], b: dict[str, bool], labels=("A", "B")) -> list[str]:
    """The Markdown rows (header first) comparing runs ``a`` and ``b`` on their common names."""
    names = sorted(set(a) & set(b))
    out = [f"| set | {labels[0]} | {labels[1]} | two-sided Fisher exact p | outcome differs |",
           "|---|---|---|---:|---|"]
    for title, pattern in SETS:
        sel = [n for n in names if pattern.match(n)]
        if not sel:
            continue
        ka, kb = sum(a[n] for n in sel), sum(b[n] for n in sel)
        p = fisher_exact(ka, len(sel) - ka, kb, len(sel) - kb)
        diff = [n for n in sel if a[n] != b[n]] if title != "all runs" else []
        out.append(f"| {title} | {rate_text(ka, len(sel))} | {rate_text(kb, len(sel))} | "
                   f"{p:.2f} | {', '.join(diff) or '–'} |")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("a", type=pathlib.Path)
    ap.add_argument("b", type=pathlib.Path)
    ap.add_argument("--labels", nargs=2, default=("A", "B"))
    args = ap.parse_args(argv)
    print("\n".join(table(read(args.a), read(args.b), args.labels)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
