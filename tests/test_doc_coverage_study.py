"""Every number docs/coverage_study.md states about coverage against the CSV it came from: the
table rows (runs and steps covered with their intervals, E's half-width beside the test errors)
and the headline ranges, read back from the markdown and recomputed from
docs/coverage_study_data/*_coverage.csv.  Every section that has tables lists every run-level
row of the shown methods.  Rounding tolerance: half a unit of the last printed digit."""

from __future__ import annotations

import csv
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "coverage_study.md"
DATA = ROOT / "docs" / "coverage_study_data"
NAMES = {"mRPI, box W": "box", "mRPI, hull W": "hull", "mRPI, step q-box": "conformal_step",
         "E_q, mRPI shape": "conformal_run", "E_q, box": "conformal_box"}
SECTIONS = {"Test set": "gpu_test_coverage.csv", "Validation set": "gpu_val_coverage.csv",
            "CPU size": "cpu_coverage.csv"}
#: sections with per-split tables (the validation set states its headline only)
TABLES = ("Test set", "CPU size")


def _rows(name: str) -> list[dict]:
    with open(DATA / name, newline="") as f:
        return list(csv.DictReader(f))


def _sections() -> dict[str, str]:
    text = DOC.read_text()
    parts = re.split(r"^## ", text, flags=re.M)
    return {title: body for title in SECTIONS for body in parts if body.startswith(title)}


def _close(printed: str, value: float) -> bool:
    digits = len(printed.split(".")[1]) if "." in printed else 0
    return abs(float(printed) - value) <= 0.5 * 10 ** -digits + 1e-12


def _check_fraction(cell: str, r: dict) -> None:
    m = re.fullmatch(r"(\d+)/(\d+) = ([\d.]+) \[([\d.]+), ([\d.]+)\]", cell.strip())
    assert m, cell
    assert (m[1], m[2]) == (r["covered"], r["test_samples"])
    for printed, col in zip(m.groups()[2:], ("coverage", "ci_low", "ci_high")):
        assert _close(printed, float(r[col])), (cell, col, r[col])


@pytest.mark.parametrize("section", TABLES)
def test_table_rows_match_the_csv(section):
    body = _sections()[section]
    rows = _rows(SECTIONS[section])
    by = {(r["split"], r["group"], r["plane"], r["w_method"], r["level"]): r for r in rows}
    checked = 0
    for split_body in re.split(r"^### Split: ", body, flags=re.M)[1:]:
        split = split_body.split()[0]
        for line in split_body.splitlines():
            cells = [c.strip() for c in line.strip().strip("|").split("|")]
            if len(cells) != 8 or cells[2] not in NAMES:
                continue
            key = (split, cells[0], cells[1], NAMES[cells[2]])
            run, step = by[key + ("run",)], by[key + ("step",)]
            assert cells[3] == (f"{run['train_runs']} ({run['train_fell']}) / "
                                f"{run['test_runs']} ({run['test_fell']})")
            _check_fraction(cells[4], run)
            _check_fraction(cells[5], step)
            e, q, mx = cells[6].split(" / ")
            for printed, col in ((e, "e_half_c"), (q, "err_q_c"), (mx, "err_max_c")):
                assert _close(printed, float(run[col])), (key, col)
            assert _close(cells[7], float(run["e_half_c"]) / float(run["err_max_c"]))
            checked += 1
    shown = set(NAMES.values()) - {"conformal_step"}
    assert checked == sum(r["level"] == "run" and r["coverage"] != "nan" and
                          r["w_method"] in shown for r in rows)


@pytest.mark.parametrize("section", list(SECTIONS))
def test_headline_ranges_match_the_csv(section):
    body = _sections()[section]
    rows = [r for r in _rows(SECTIONS[section]) if r["level"] == "run" and r["coverage"] != "nan"]
    pat = (r"- split (\w+), (.+?): run-level coverage ([\d.]+)–([\d.]+), mean ([\d.]+) \((\d+) of "
           r"(\d+) rows in \[0\.85, 0\.98\]\); E along c ÷ largest held-out \|e_c\| "
           r"([\d.]+)–([\d.]+)")
    found = re.findall(pat, body)
    shown = set(NAMES.values()) - {"conformal_step"}
    assert len(found) == len({(r["split"], r["w_method"]) for r in rows if r["w_method"] in shown})
    for split, name, lo, hi, mean, inside, n, rlo, rhi in found:
        sel = [r for r in rows if r["split"] == split and r["w_method"] == NAMES[name]]
        cov = [float(r["coverage"]) for r in sel]
        ratio = [float(r["e_half_c"]) / float(r["err_max_c"]) for r in sel]
        assert int(n) == len(sel) and int(inside) == sum(0.85 <= c <= 0.98 for c in cov)
        assert _close(lo, min(cov)) and _close(hi, max(cov))
        assert _close(mean, sum(cov) / len(cov))
        assert _close(rlo, min(ratio)) and _close(rhi, max(ratio))
