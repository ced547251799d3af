"""Robustness map of H-LIP stepping on a non-ideal Cassie from a results directory of
``sweeps/cassie_robustness.toml`` (or its CPU size).

    python benchmarks/robustness_report.py RESULTS_DIR [--figure FIG.png]

One row per level of the sweep's one-factor grid (the ``realism.*`` fields that differ from
the ideal plant name it, with any other swept field but the seed and the path after them):
runs that walked the whole scenario, with the 95 % Clopper–Pearson
interval; the median RMS COM-to-path distance of those runs; and the error-invariant set E of
the level — W the box of the S2S residuals of half of the seeds (pushes excluded; both paths
pooled: they share A, B and K), E = mRPI(A + BK, W), its half-extent on the global position c
per plane [m] — with the across-seed coverage of the other half; the leg-overlap events; and
the median error of the controller's own state estimate at SSP⁻ (p and v: what the stepping
law acted on, against the truth).  Prints Markdown;
``--figure`` draws success rate and E's extent per level.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import pathlib
import sys

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hlip_jax.sweepio import store, sweep  # noqa: E402
from hlip_jax.analysis import coverage as cov, masks, runs, splits  # noqa: E402
from hlip_jax.simulation.config import RealismConfig  # noqa: E402
from hlip_jax.analysis.stats import clopper_pearson, rate_text  # noqa: E402

IDEAL = RealismConfig()


def level_label(cfg) -> str:
    """The realism fields of a scenario that differ from the ideal plant (or "ideal"), followed
    by any other swept field but the seed and the path (paths are pooled): a second axis, e.g.
    ``cassie.height_reference``."""
    diff = [f"{f.name}={getattr(cfg.realism, f.name)}" for f in dataclasses.fields(IDEAL)
            if getattr(cfg.realism, f.name) != getattr(IDEAL, f.name)]
    other = [f"{k}={v}" for k, v in cfg.swept.items()
             if k not in ("seed", "path") and not k.startswith("realism.")]
    return ", ".join((diff or ["ideal"]) + other)


def collect(out_dir):
    """{level: {"rows": summary rows, "runs": RunErrors, "seeds": seeds, "Acl": A + BK}} in
    the sweep's order of first appearance."""
    configs = [sweep.config_from_dict(d) for d in store.read_manifest(out_dir)["configs"]]
    summary = {int(r["index"]): r for r in store.read_summary(out_dir)}
    levels: dict = {}
    for f in store.chunk_files(out_dir):
        z = store.load_chunk(f)
        for j, i in enumerate(z["index"]):
            cfg = configs[int(i)]
            lv = levels.setdefault(level_label(cfg), {"rows": [], "runs": [], "seeds": [], "Acl": None})
            lv["rows"].append(summary[int(i)])
            if store.steplog.alive(z["valid"][j]).any():
                pushes = [(p.time, p.duration) for p in cfg.disturbance.pushes if p.force > 0]
                Acl, frame, run = runs.run_errors(z, j, pushes, masks.WARMUP)
                lv["Acl"] = Acl
                lv["runs"].append(run)
                lv["seeds"].append(cfg.swept.get("seed", int(i)))
    order = {level_label(c): k for k, c in reversed(list(enumerate(configs)))}
    return dict(sorted(levels.items(), key=lambda kv: order[kv[0]]))


def e_extent(lv) -> dict:
    """{plane: (E's half-width on c [m], run-level coverage over held-out seeds, its CI)} of a
    level (box W's mRPI set)."""
    out = {}
    if lv["Acl"] is None or len(set(lv["seeds"])) < 2:
        return out
    for r in cov.group_rows("", lv["Acl"], lv["runs"], lv["seeds"], ("sagittal", "lateral"),
                            splits.split("seed"), q=0.9, methods=("box",)):
        if r["level"] == "run":
            out[r["plane"]] = (r["e_half_c"], r["coverage"], r["ci_low"], r["ci_high"])
    return out


def _leg_events(rows) -> tuple[str, str]:
    """(runs with a step whose lower legs overlapped / runs, smallest leg clearance [m]) of a
    level, from summary.csv's collision columns ('–' for results written before them)."""
    if not rows or "collision_steps" not in rows[0]:
        return "–", "–"
    hits = sum(float(r["collision_steps"] or 0) > 0 for r in rows)
    gaps = [float(r["min_leg_gap"]) for r in rows if r["min_leg_gap"] not in ("", "nan")]
    return f"{hits}/{len(rows)}", (f"{min(gaps):.3f}" if gaps else "–")


def _estimate_error(rows) -> str:
    """Median over a level's runs of the controller's state-estimate error at SSP⁻, p [m] and
    v [m/s] (summary.csv's est_err_p / est_err_v; '–' for results written before them)."""
    if not rows or "est_err_p" not in rows[0]:
        return "–"
    cell = lambda v: math.nan if v in ("", None) else float(v)
    med = [np.nanmedian([cell(r[k]) for r in rows]) for k in ("est_err_p", "est_err_v")]
    return f"{med[0]:.4f} / {med[1]:.3f}"


def table(levels) -> list[str]:
    out = ["| level | walked the scenario | RMS distance to path [m], median | E on c, sagittal / lateral [m] | across-seed coverage, sagittal / lateral | runs with leg overlap | smallest leg clearance [m] | estimate error p [m] / v [m/s], median |",
           "|---|---|---|---|---|---|---|---|"]
    for name, lv in levels.items():
        rows = lv["rows"]
        ok = [r for r in rows if r["status"] == "ok"]
        rms = np.median([float(r["rms_track_err"]) for r in ok]) if ok else math.nan
        e = e_extent(lv)
        ext = " / ".join(f"{e[p][0]:.3f}" if p in e else "–" for p in ("sagittal", "lateral"))
        cv = " / ".join(f"{e[p][1]:.2f} [{e[p][2]:.2f}, {e[p][3]:.2f}]" if p in e else "–"
                        for p in ("sagittal", "lateral"))
        hits, gap = _leg_events(rows)
        out.append(f"| {name} | {rate_text(len(ok), len(rows))} | {rms:.3f} | {ext} | {cv} | {hits} | {gap} "
                   f"| {_estimate_error(rows)} |")
    return out


def figure(levels, path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(levels)
    y = np.arange(len(names))[::-1]
    fig, ax = plt.subplots(1, 2, figsize=(12, 0.32 * len(names) + 1.5), sharey=True)
    for yi, name in zip(y, names):
        rows = levels[name]["rows"]
        k, n = sum(r["status"] == "ok" for r in rows), len(rows)
        lo, hi = clopper_pearson(k, n)
        ax[0].errorbar(k / n, yi, xerr=[[k / n - lo], [hi - k / n]], fmt="o", color="C0", capsize=3)
        e = e_extent(levels[name])
        for p, plane in enumerate(("sagittal", "lateral")):
            if plane in e and np.isfinite(e[plane][0]):
                ax[1].plot(e[plane][0], yi + 0.12 * (p - 0.5), "os"[p], color=f"C{p + 1}",
                           label=plane if yi == y[0] else None)
    short = [n if len(n) <= 60 else n.split(",")[0] + ", …" for n in names]
    ax[0].set_yticks(y, short, fontsize=7)
    ax[0].set_xlabel("walked the scenario (95 % Clopper–Pearson)")
    ax[0].set_xlim(-0.02, 1.02)
    ax[1].set_xscale("log")
    ax[1].set_xlabel("E's half-extent on the global position c [m]")
    ax[1].legend(fontsize=8)
    for a in ax:
        a.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results")
    ap.add_argument("--figure")
    args = ap.parse_args(argv)
    levels = collect(args.results)
    print("\n".join(table(levels)))
    if args.figure:
        figure(levels, args.figure)
    return 0


if __name__ == "__main__":
    sys.exit(main())
