"""The identified S2S map in the loop against the H-LIP's, on the validation set
(docs/coverage_study.md, "Identified S2S map").

Usage::

    hlip-sweep run sweeps/cassie_validation.toml --out results/vp --no-report
    hlip-sweep run docs/experiments/cassie_validation_identified.toml --out results/vi --no-report
    python benchmarks/s2s_identified.py results/vp results/vi docs/experiments/data/cassie_train_s2s.npz

Prints three tables: which robots walked per part of the validation set (Clopper–Pearson 95 %
intervals over runs); the model's residual on the H-LIP runs' step pairs (which the fit never
saw) against the H-LIP's w, spread = 1st to 99th percentile; and on the 64 noisy runs of each
directory (alternate runs train, the others test) the box W's mRPI set and the run-calibrated
box E_q, each directory's sets built on the S2S map it ran with (E against E_id).
"""

from __future__ import annotations

import argparse
import collections
import pathlib

import numpy as np

from hlip_jax.core import s2s_fit, s2s_model
from hlip_jax.sweepio import store
from hlip_jax.analysis import coverage, estimators, masks, splits, stats

PARTS = ("push-100", "push-200", "noise", "circle")


def _part(name: str) -> str:
    return next(p for p in PARTS if name.startswith(p))


def walked(d: pathlib.Path) -> dict:
    """{part: (walked, runs)} of a results directory."""
    out: dict = collections.defaultdict(lambda: [0, 0])
    for r in store.read_summary(d):
        c = out[_part(r["name"])]
        c[0] += r["status"] == "ok"
        c[1] += 1
    return out


def _ci(k: int, n: int) -> str:
    lo, hi = stats.clopper_pearson(k, n)
    return f"{k}/{n} [{lo:.2f}, {hi:.2f}]"


def residual_rows(d: pathlib.Path, model: s2s_model.Model) -> list[str]:
    log = store.load_log(d)
    ok = [i for i in range(log["valid"].shape[0]) if log["fail_step"][i] < 0]
    r_id = s2s_model.residuals(log, ok, model)
    r_h = s2s_fit.residuals(log, ok, None, hlip=s2s_fit.hlip_rows(log["A"][ok[0]], log["B"][ok[0]]))

    def spread(r):
        return np.percentile(r, 99, axis=0) - np.percentile(r, 1, axis=0)

    out = [f"{len(ok)} runs that walked, {len(r_id)} step pairs", "",
           "| plane | w spread p, v (H-LIP) | spread p, v (identified) | ratio p, v |",
           "|---|---|---|---|"]
    for j, plane in enumerate(("sagittal", "lateral")):
        h, i = spread(r_h[:, j]), spread(r_id[:, j])
        out.append(f"| {plane} | {h[0]:.4f}, {h[1]:.3f} | {i[0]:.4f}, {i[1]:.3f} | "
                   f"{h[0] / i[0]:.2f}, {h[1] / i[1]:.2f} |")
    return out


def set_rows(d: pathlib.Path, label: str, q: float = 0.9) -> list[str]:
    """E of the box W and the box E_q on the noisy runs of ``d``: alternate runs train."""
    configs = store.read_manifest(d)["configs"]
    found = [(Acl, run) for i, cfg, _, Acl, _, run in store.analysed_runs(d, masks.WARMUP)
             if _part(configs[i]["name"]) == "noise"]
    Acl = found[0][0]
    tr, te = splits.interleave(list(range(len(found))))
    train, test = [found[i][1] for i in tr], [found[i][1] for i in te]
    out = []
    for p, plane in enumerate(coverage.PLANES["heading"]):
        for name in ("box", "conformal_box"):
            E = coverage.fit(name, Acl[p], train, p, q).E
            half = estimators.half_widths(E, Acl.shape[-1])
            cov = sum((not r.fell) and bool(np.all(E.contains(r.kept_e(p), 1e-6))) for r in test)
            out.append(f"| {label} | {plane} | {name} | {half[0]:.3f}, {half[1]:.3f}, "
                       f"{half[2]:.3f} | {_ci(cov, len(test))} |")
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("hlip_dir", type=pathlib.Path, help="validation run with the H-LIP map")
    ap.add_argument("identified_dir", type=pathlib.Path, help="the same with the identified map")
    ap.add_argument("model", type=pathlib.Path, help="the identified model file")
    a = ap.parse_args(argv)
    w_h, w_i = walked(a.hlip_dir), walked(a.identified_dir)
    lines = ["| part | H-LIP map | identified map |", "|---|---|---|"]
    lines += [f"| {p} | {_ci(*w_h[p])} | {_ci(*w_i[p])} |" for p in PARTS]
    tot_h = [sum(v[k] for v in w_h.values()) for k in (0, 1)]
    tot_i = [sum(v[k] for v in w_i.values()) for k in (0, 1)]
    lines += [f"| all | {_ci(*tot_h)} | {_ci(*tot_i)} |", ""]
    lines += residual_rows(a.hlip_dir, s2s_model.read(a.model)) + [""]
    lines += ["| map | plane | E | half-widths c, p, v [m, m, m/s] | test runs covered [95 % CI] |",
              "|---|---|---|---|---|"]
    lines += set_rows(a.hlip_dir, "H-LIP") + set_rows(a.identified_dir, "identified")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
