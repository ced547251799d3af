"""Random search of Cassie gait presets on the training set (docs/cassie_protocol).

Writes a sweep file: the scenarios of ``sweeps/cassie_train.toml`` × ``--sets`` gait sets as
one zipped grid axis (every gait field is per-scenario data, so the whole search is one
compile).  Set 0 is the current "paper" preset; the others are drawn uniformly (log-uniformly
where marked) over :data:`RANGES` with ``numpy.random.default_rng(--seed)``, or, with
``--around``, within ±``--spread`` of each range around a given set.  Run the file with
``hlip-sweep run`` (a GPU job) and rank the sets with ``--rank RESULTS_DIR``: per set the
number of training scenarios walked without a fall, then the mean pre-impact distance to the
path.  Only the training set is ever searched; the validation sweeps are run once, after.

    python benchmarks/cassie_gait_search.py --sets 48 --duration 8 --out search.toml
    hlip-sweep run search.toml --out results/search --batch 768
    python benchmarks/cassie_gait_search.py --rank results/search
"""

from __future__ import annotations

import argparse
import csv
import json
import pathlib
import sys

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hlip_jax.plants.cassie import gaits  # noqa: E402

# dotted field: (lo, hi, log-scale)
RANGES = {
    "hlip.t_ssp": (0.22, 0.40, False), "hlip.t_dsp": (0.02, 0.10, False),
    "hlip.z0": (0.75, 0.90, False), "mpc.step_width_min": (0.10, 0.20, False),
    "gain.q_v": (0.1, 2.0, True), "gain.r": (0.5, 10.0, True),
    "cassie.clearance": (0.05, 0.15, False), "cassie.strike": (0.0, 0.02, False),
    "cassie.reach": (0.7, 1.0, False), "cassie.early_contact": (0.5, 0.9, False),
    "cassie.omega_pelvis": (2.0, 15.0, True), "cassie.omega_height": (1.5, 15.0, True),
    "cassie.omega_swing": (4.0, 40.0, True), "cassie.omega_yaw": (3.0, 15.0, True),
    "cassie.weight_pelvis": (1.0, 8.0, True),
}


def draw(n: int, seed: int, around: dict | None, spread: float) -> dict[str, list]:
    """Set 0: the centre (``around`` or the "paper" preset); sets 1..n-1 random."""
    rng = np.random.default_rng(seed)
    centre = around or {k: gaits.PRESETS["paper"][k] for k in RANGES}
    cols = {k: [float(centre[k])] for k in RANGES}
    for _ in range(n - 1):
        for k, (lo, hi, log) in RANGES.items():
            a, b = (np.log(lo), np.log(hi)) if log else (lo, hi)
            if around is not None:
                c = np.log(centre[k]) if log else centre[k]
                a, b = max(a, c - spread * (b - a)), min(b, c + spread * (b - a))
            v = rng.uniform(a, b)
            cols[k].append(round(float(np.exp(v) if log else v), 4))
    return cols


def write(cols: dict, duration: float, out: pathlib.Path) -> None:
    text = (ROOT / "sweeps" / "cassie_train.toml").read_text()
    text = text.replace('name = "cassie_train"', 'name = "cassie_gait_search"')
    text = text.replace("duration = 12.0", f"duration = {duration}")
    zips = "\n".join(f'"{k}" = {json.dumps(v)}' for k, v in cols.items())
    out.write_text(text + f"\n[[grid.zip]]\n{zips}\n")


def rank(results: pathlib.Path, top: int) -> None:
    rows = list(csv.DictReader(open(results / "summary.csv")))
    by_set: dict[tuple, list] = {}
    for r in rows:
        key = tuple(r[k] for k in RANGES)
        by_set.setdefault(key, []).append(r)
    scored = []
    for key, rs in by_set.items():
        ok = sum(r["status"] == "ok" for r in rs)
        err = np.nanmean([float(r.get("rms_track_err") or "nan") for r in rs])
        scored.append((-ok, err, key, [r["swept"] if "swept" in r else r.get("path") for r in rs
                                       if r["status"] != "ok"]))
    scored.sort(key=lambda s: (s[0], s[1]))
    for s in scored[:top]:
        print(f"walked {-s[0]:2d}/{len(by_set[s[2]])}  rms track err {s[1]:.3f} m  "
              + ", ".join(f"{k}={v}" for k, v in zip(RANGES, s[2])))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sets", type=int, default=48)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--duration", type=float, default=8.0)
    ap.add_argument("--around", help="JSON {dotted field: value} to sample near")
    ap.add_argument("--spread", type=float, default=0.15)
    ap.add_argument("--out", type=pathlib.Path, default=pathlib.Path("cassie_gait_search.toml"))
    ap.add_argument("--rank", type=pathlib.Path, help="results directory of a search to rank")
    ap.add_argument("--top", type=int, default=10)
    a = ap.parse_args(argv)
    if a.rank:
        rank(a.rank, a.top)
        return 0
    around = json.loads(a.around) if a.around else None
    write(draw(a.sets, a.seed, around, a.spread), a.duration, a.out)
    print(f"wrote {a.out}: {a.sets} sets x 16 training scenarios")
    return 0


if __name__ == "__main__":
    sys.exit(main())
