"""benchmarks/compare_runs.py: Fisher's exact test against hand-counted hypergeometric sums,
and the per-set table on two small runs."""

import math

import pytest

from support import load_benchmark

compare_runs = load_benchmark("compare_runs")


@pytest.mark.parametrize("table, p", [
    # Fisher's tea tasting: margins 4/4 of 8; the tables x = 0, 1, 3, 4 are no more probable
    # than x = 3 (probabilities 1, 16, 16, 1 of 70)
    ((3, 1, 1, 3), 34 / 70),
    ((4, 0, 0, 4), 2 / 70),
    # a perfect split of 16: the two extreme tables of C(16, 8)
    ((8, 0, 0, 8), 2 / math.comb(16, 8)),
    # the same counts in both rows: every table is as probable or less, p = 1
    ((12, 4, 12, 4), 1.0),
    ((16, 0, 16, 0), 1.0),
])
def test_fisher_exact_matches_closed_forms(table, p):
    # exact rational sums: the only error is float division, far below 1e-12
    assert compare_runs.fisher_exact(*table) == pytest.approx(p, rel=1e-12)


def test_table_counts_each_set_and_names_the_differences(tmp_path):
    names = [f"push-100-left-8.{i:02d}" for i in range(4)] + ["noise-line-seed1", "circle-r1-v1"]
    a = {n: True for n in names}
    b = dict(a, **{"push-100-left-8.02": False, "circle-r1-v1": False})
    rows = compare_runs.table(a, b, ("a", "b"))
    by_set = {r.split(" | ")[0].lstrip("| "): r for r in rows[2:]}
    assert "4/4" in by_set["pushes 100 N towards +y"] and "3/4" in by_set["pushes 100 N towards +y"]
    assert by_set["pushes 100 N towards +y"].endswith("push-100-left-8.02 |")
    assert "pushes 200 N towards +y" not in by_set             # a set with no runs is left out
    assert "6/6" in by_set["all runs"] and "4/6" in by_set["all runs"]
    f = tmp_path / "s.csv"
    f.write_text("index,name,status\n0,noise-line-seed1,ok\n1,circle-r1-v1,fell\n")
    assert compare_runs.read(f) == {"noise-line-seed1": True, "circle-r1-v1": False}
