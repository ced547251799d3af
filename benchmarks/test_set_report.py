"""Tables of the Cassie controller's test set (docs/cassie_protocol, "Test set") from a run.

    python benchmarks/test_set_report.py RESULTS_DIR

RESULTS_DIR holds a run of `docs/cassie_protocol/cassie_test.toml` (225 robots).  Prints
Markdown against the acceptance of the recovery work, each rate with its exact 95 %
Clopper–Pearson interval over runs: the 200 N pushes per direction, the 100 N pushes, the
return to within 0.15 m of the path (the paper push and the survived sideways 200 N pushes:
median and worst steps), the noisy runs, the straight lines' mean forward speed over their
constant-speed part against the command (needs the chunks), turning in place, and the paper's
four paths with each gain (RMS COM distance to the path, which bounds the mean distance from
above).  Written before the test set was run; it reads results, it decides nothing.
"""

from __future__ import annotations

import argparse
import csv
import math
import pathlib
import re
import sys

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))   # its sibling validation_report, run or loaded

from hlip_jax.analysis.stats import rate_text  # noqa: E402
from hlip_jax.sweepio import store  # noqa: E402
from validation_report import line_speed  # noqa: E402

PUSH200 = re.compile(r"push-200-(?P<side>fwd|back|left|right)-[\d.]+$")
PUSH100 = re.compile(r"push-100-dir(?P<deg>[+-]\d+)-[\d.]+$")
NOISE = re.compile(r"noise-(?P<path>.+)-seed\d+$")
LINE = re.compile(r"line-(?P<v>[\d.]+)(-rep\d+)?$")
TURN = re.compile(r"turn-in-place-(?P<dir>ccw|cw)-45dps(-rep\d+)?$")
PAPER = re.compile(r"paper-(?P<path>circle|sinusoid|square|cardioid)-(?P<gain>preset|deadbeat3|deadbeat)"
                   r"(-rep\d+)?$")
RETURN_TOL, MEDIAN_STEPS, WORST_STEPS = 0.15, 10, 14


def ok(r) -> bool:
    return r["status"] == "ok"


def num(r, key) -> float:
    return float(r.get(key) or "nan")


def rate(rows) -> str:
    return rate_text(sum(map(ok, rows)), len(rows)) if rows else "–"


def grouped(rows, pattern, key):
    out: dict[str, list] = {}
    for r in rows:
        if (m := pattern.match(r["name"])):
            out.setdefault(m[key], []).append(r)
    return out


def push_tables(rows) -> list[str]:
    lines = ["| 200 N × 0.1 s push from | walked 16 s (target ≥ 75 %) | back within 0.15 m, steps: median / worst (walked runs) |",
             "|---|---|---|"]
    for side, rs in grouped(rows, PUSH200, "side").items():
        lines.append(f"| {side} | {rate(rs)} | {steps_text([r for r in rs if ok(r)])} |")
    every = [r for rs in grouped(rows, PUSH100, "deg").values() for r in rs]
    lines += ["", "| 100 N × 0.1 s push from | walked (target 100 %) |", "|---|---|"]
    for deg, rs in sorted(grouped(rows, PUSH100, "deg").items(), key=lambda kv: int(kv[0])):
        lines.append(f"| {int(deg):+d}° | {rate(rs)} |")
    lines.append(f"| all eight directions | {rate(every)} |")
    return lines


def steps_text(rows) -> str:
    """Median and worst steps back within 0.15 m; a run not back by its end counts as worst."""
    if not rows:
        return "–"
    s = np.array([num(r, "push_recovery_steps") for r in rows])
    s = np.where(np.isnan(s), np.inf, s)
    med, worst = float(np.median(s)), float(np.max(s))
    fmt = lambda x: "not back" if math.isinf(x) else f"{x:g}"
    return f"{fmt(med)} / {fmt(worst)} ({int(np.sum(s <= MEDIAN_STEPS))} of {len(rows)} within {MEDIAN_STEPS})"


def return_table(rows) -> list[str]:
    paper = [r for r in rows if r["name"] == "paper-line-push"]
    side = [r for r in rows if (m := PUSH200.match(r["name"])) and m["side"] in ("left", "right")
            and ok(r)]
    return ["| pushes | walked | back within 0.15 m, steps: median / worst (targets ≤ 10 / ≤ 14) |",
            "|---|---|---|",
            f"| the paper's push (200 N towards +y at 10 s) | {rate(paper)} | {steps_text([r for r in paper if ok(r)])} |",
            f"| survived 200 N sideways pushes | {len(side)} | {steps_text(side)} |"]


def noise_table(rows) -> list[str]:
    groups = grouped(rows, NOISE, "path")
    every = [r for rs in groups.values() for r in rs]
    lines = ["| noisy path (noise_v 0.03 m/s, step_error 0.015 m) | walked 20 s (target ≥ 97 % overall) | median RMS distance [m] |",
             "|---|---|---|"]
    for name, rs in list(groups.items()) + [("all", every)]:
        d = np.nanmedian([num(r, "rms_track_err") for r in rs if ok(r)] or [np.nan])
        lines.append(f"| {name} | {rate(rs)} | {d:.3f} |")
    return lines


def speed_table(rows, out) -> list[str]:
    lines = ["| line | walked 20 s | mean speed / command, per run (target within ±10 %) |",
             "|---|---|---|"]
    groups = grouped(rows, LINE, "v")
    log = None
    if store.chunk_files(out):
        log = store.load_log(out, [int(r["index"]) for rs in groups.values() for r in rs])
        pos = {int(i): j for j, i in enumerate(log["index"])}
    for v, rs in sorted(groups.items(), key=lambda kv: float(kv[0])):
        cells = []
        for r in rs:
            if log is None or not ok(r):
                cells.append("–" if ok(r) else "fell")
                continue
            speed, cmd = line_speed(log, pos[int(r["index"])])
            within = abs(speed - cmd) <= 0.1 * cmd
            cells.append(f"{speed:.3f}/{cmd:g}{'' if within else ' (outside)'}")
        lines.append(f"| {v} m/s | {rate(rs)} | {', '.join(cells)} |")
    turns = grouped(rows, TURN, "dir")
    lines += ["", "| turning in place at 45°/s | walked 20 s |", "|---|---|"]
    lines += [f"| {d} | {rate(rs)} |" for d, rs in turns.items()]
    return lines


def paper_table(rows) -> list[str]:
    lines = ["| paper path (0.5 m/s, 40 s) | gain | walked | RMS COM distance to the path, walked runs [m] (target: mean ≤ 0.10) |",
             "|---|---|---|---|"]
    groups: dict[tuple, list] = {}
    for r in rows:
        if (m := PAPER.match(r["name"])):
            groups.setdefault((m["path"], m["gain"]), []).append(r)
    for (path, gain), rs in groups.items():
        d = ", ".join(f"{num(r, 'rms_track_err'):.3f}" for r in rs if ok(r)) or "–"
        lines.append(f"| {path} | {gain} | {rate(rs)} | {d} |")
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("results", type=pathlib.Path)
    a = ap.parse_args(argv)
    with open(a.results / "summary.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    lines = [f"All {len(rows)} test runs walked: {rate(rows)}", "",
             "### Pushes", ""] + push_tables(rows)
    lines += ["", "### Return to the path", ""] + return_table(rows)
    lines += ["", "### Step noise", ""] + noise_table(rows)
    lines += ["", "### Speeds and turning in place", ""] + speed_table(rows, a.results)
    lines += ["", "### The paper's paths", ""] + paper_table(rows)
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
