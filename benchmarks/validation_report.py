"""Validation tables of the Cassie controller (docs/cassie_protocol) from results directories.

    python benchmarks/validation_report.py VALIDATION_DIR [SPEEDS_DIR] --figure FIG.png

VALIDATION_DIR holds a run of sweeps/cassie_validation.toml (or of a sweep that extends it with a
grid: ``--variants`` then prints the tables and a comparison per grid point), SPEEDS_DIR one of
docs/experiments/cassie_speeds_val.toml.  Prints Markdown: success rates with 95 % Clopper–Pearson
intervals (pushes by force and side, with recovery = back within 0.15 m of the path within 10
steps and staying there; noisy runs by path; the speed × radius envelope), and for the
speed runs the mean forward speed on the plant's clock over the constant-speed part against
the command.  ``--figure`` draws the envelope's success map.
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

from hlip_jax.sweepio import store  # noqa: E402
from hlip_jax.analysis.stats import rate_text  # noqa: E402

PUSH = re.compile(r"push-(?P<force>[\d.]+)-(?P<side>left|right)-(?P<t>[\d.]+)$")
NOISE = re.compile(r"noise-(?P<path>.+)-seed(?P<seed>\d+)$")
CIRCLE = re.compile(r"circle-r(?P<r>[\d.]+)-v(?P<v>[\d.]+)$")
RECOVERY_STEPS = 10


def _ok(row) -> bool:
    return row["status"] == "ok"


def _recovered(row) -> bool:
    steps = float(row["push_recovery_steps"] or "nan")
    return _ok(row) and not math.isnan(steps) and steps <= RECOVERY_STEPS


def push_table(rows) -> list[str]:
    out = ["| push | walked 14 s | recovered (≤ 10 steps) | peak distance to path [m], median |",
           "|---|---|---|---|"]
    groups: dict[tuple, list] = {}
    for r in rows:
        if (m := PUSH.match(r["path"])):
            groups.setdefault((float(m["force"]), m["side"]), []).append(r)
    for (force, side), rs in sorted(groups.items()):
        peak = np.nanmedian([float(r["push_peak_err"] or "nan") for r in rs])
        out.append(f"| {force:g} N towards {'+y' if side == 'left' else '−y'} | "
                   f"{rate_text(sum(map(_ok, rs)), len(rs))} | "
                   f"{rate_text(sum(map(_recovered, rs)), len(rs))} | {peak:.3f} |")
    return out


def noise_table(rows) -> list[str]:
    out = ["| path (noise_v 0.03 m/s, step_error 0.015 m) | walked 20 s | RMS distance to path [m], median |",
           "|---|---|---|"]
    groups: dict[str, list] = {}
    for r in rows:
        if (m := NOISE.match(r["path"])):
            groups.setdefault(m["path"], []).append(r)
    everything = [r for rs in groups.values() for r in rs]
    for name, rs in list(groups.items()) + [("all", everything)]:
        err = np.nanmedian([float(r["rms_track_err"] or "nan") for r in rs if _ok(r)] or [np.nan])
        out.append(f"| {name} | {rate_text(sum(map(_ok, rs)), len(rs))} | {err:.3f} |")
    return out


def envelope(rows):
    """{(radius, speed): row} of the circle runs."""
    return {(float(m["r"]), float(m["v"])): r for r in rows if (m := CIRCLE.match(r["path"]))}


def envelope_table(env) -> list[str]:
    radii = sorted({k[0] for k in env})
    speeds = sorted({k[1] for k in env})
    out = ["| radius \\ peak speed | " + " | ".join(f"{v:g} m/s" for v in speeds) + " |",
           "|---" * (len(speeds) + 1) + "|"]
    for R in radii:
        cells = []
        for v in speeds:
            r = env[(R, v)]
            rate = math.degrees(v / R)
            cells.append(f"{'walks' if _ok(r) else 'falls'} ({rate:.0f}°/s, "
                         f"{float(r['rms_track_err'] or 'nan'):.2f} m)")
        out.append(f"| {R:g} m | " + " | ".join(cells) + " |")
    n_ok = sum(map(_ok, env.values()))
    out.append("")
    out.append(f"All circles: {rate_text(n_ok, len(env))}; cells give the turn rate v / R and "
               "the RMS COM distance to the path.")
    return out


def line_speed(log, s) -> tuple[float, float]:
    """Scenario ``s`` of a log: (mean forward COM speed over the constant-speed part [m/s],
    the command [m/s]); the speed is NaN where no part holds the command."""
    v = np.asarray(log["valid"][s], bool)
    t = np.asarray(log["t_plant"][s])[v]
    c = np.asarray(log["x_robot"][s])[v][:, :, 0]
    ref_v = np.linalg.norm(np.asarray(log["ref_vel"][s])[v], axis=1)
    cmd = float(np.max(ref_v)) if ref_v.size else 0.0
    hold = np.flatnonzero(ref_v >= 0.999 * cmd)
    if hold.size < 2:
        return math.nan, cmd
    a, b = hold[0], hold[-1]
    return float(np.linalg.norm(c[b] - c[a]) / (t[b] - t[a])), cmd


def speed_table(speeds_dir) -> list[str]:
    rows = store.read_summary(speeds_dir)
    log = store.load_log(speeds_dir)
    out = ["| scenario | walked | mean speed over the constant-speed part [m/s] | command [m/s] | within ±10 % |",
           "|---|---|---|---|---|"]
    for s, r in enumerate(rows):
        speed, cmd = line_speed(log, s)
        if not r["path"].startswith("line") or math.isnan(speed):
            out.append(f"| {r['path']} | {'yes' if _ok(r) else 'no'} | – | – | – |")
            continue
        ok = abs(speed - cmd) <= 0.1 * cmd
        out.append(f"| {r['path']} | {'yes' if _ok(r) else 'no'} | {speed:.3f} | {cmd:g} | "
                   f"{'yes' if ok and _ok(r) else 'no'} |")
    return out


def figure(env, path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 4))
    for (R, v), r in env.items():
        ax.scatter(v, math.degrees(v / R), marker="o" if _ok(r) else "x", s=60,
                   c="tab:green" if _ok(r) else "tab:red")
    ax.set_yscale("log")
    ax.set_xlabel("peak speed [m/s]")
    ax.set_ylabel("turn rate v / R [deg/s]")
    ax.axhline(45, ls=":", c="grey")
    ax.axvline(1.0, ls=":", c="grey")
    ax.set_title("Circles: walked 20 s (o) or fell (x)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def variants(rows) -> dict[str, list]:
    """{grid point: its rows}: a scenario's name is ``path/axis=value,...`` under a grid."""
    out: dict[str, list] = {}
    for r in rows:
        path, _, point = r["name"].partition("/")
        out.setdefault(point, []).append(dict(r, path=path))
    return out


def inside_envelope(row) -> bool:
    """A circle within the paper's envelope: peak speed <= 1 m/s, turn rate <= 45 deg/s."""
    m = CIRCLE.match(row["path"])
    return bool(m) and float(m["v"]) <= 1.0 and math.degrees(float(m["v"]) / float(m["r"])) <= 45.0


def rule_row(point: str, rows) -> str:
    """One line of the comparison: walked per set, 200 N per side, returns, noisy tracking."""
    def walked(pred):
        sel = [r for r in rows if pred(r)]
        return f"{sum(map(_ok, sel))}/{len(sel)}"
    push = lambda f, side=None: (lambda r: (m := PUSH.match(r["path"])) is not None
                                 and float(m["force"]) == f and side in (None, m["side"]))
    noisy = [r for r in rows if NOISE.match(r["path"])]
    rms = np.nanmedian([float(r["rms_track_err"] or "nan") for r in noisy if _ok(r)] or [np.nan])
    back = sum(_recovered(r) for r in rows if PUSH.match(r["path"]))
    return (f"| {point} | {walked(push(100.0))} | {walked(push(200.0, 'left'))} | "
            f"{walked(push(200.0, 'right'))} | {walked(lambda r: r in noisy)} | "
            f"{walked(inside_envelope)} | {walked(lambda r: True)} | {back} | {rms:.3f} |")


def comparison(groups) -> list[str]:
    return ["| grid point | 100 N | 200 N +y | 200 N −y | noise | circles in envelope | all | "
            "pushes back ≤ 10 steps | noisy median RMS [m] |", "|---" * 9 + "|"] + [
        rule_row(point, rows) for point, rows in groups.items()]


def tables(rows) -> list[str]:
    env = envelope(rows)
    lines = ["### Pushes (line at 0.5 m/s)", ""] + push_table(rows)
    lines += ["", "### Step noise", ""] + noise_table(rows)
    return lines + ["", "### Speed × turn rate (circles, 20 s)", ""] + envelope_table(env)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("validation", type=pathlib.Path)
    ap.add_argument("speeds", type=pathlib.Path, nargs="?")
    ap.add_argument("--figure", type=pathlib.Path)
    ap.add_argument("--variants", action="store_true",
                    help="the run holds a grid over the validation set: compare its points")
    a = ap.parse_args(argv)
    if a.variants:  # the summary table alone (a device's results come back without chunks)
        with open(a.validation / "summary.csv", newline="") as f:
            groups = variants(list(csv.DictReader(f)))
        lines = ["### Comparison", ""] + comparison(groups)
        for point, rs in groups.items():
            lines += ["", f"## {point}", ""] + tables(rs)
        print("\n".join(lines))
        return 0
    rows = store.read_summary(a.validation)
    env = envelope(rows)
    lines = ["### Pushes (line at 0.5 m/s)", ""] + push_table(rows)
    lines += ["", "### Step noise", ""] + noise_table(rows)
    lines += ["", "### Speed × turn rate (circles, 20 s)", ""] + envelope_table(env)
    if a.speeds:
        lines += ["", "### Straight lines, in place, turning in place", ""] + speed_table(a.speeds)
    print("\n".join(lines))
    if a.figure:
        figure(env, a.figure)
    return 0


if __name__ == "__main__":
    sys.exit(main())
