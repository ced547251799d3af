"""Per-path table of a tube sweep's results and the share of its tube steps whose disturbance
lies outside a hull W (docs/robust_mpc.md, attempts 4 and 5).

    python benchmarks/tube_runs.py RESULTS_DIR docs/experiments/data/cassie_tube_hull.csv

Rows: nominal / tube (the scenario's ``mpc.robust``) × path (× peak speed where swept): runs
that walked, runs whose COM entered a disc at an impact (``min_clearance`` < 0), the smallest
clearance [m], the median RMS distance to the path [m] and the runs' MPC QPs not solved to
tolerance.  Then, over
the tube runs' steps, how many have a disturbance outside conv(±points) in either plane
(facets of scipy's convex hull: a point is outside when it violates one) and the largest
gauge, the factor by which W would have to grow to hold every sample.
"""

from __future__ import annotations

import csv
import os
import sys
from collections import defaultdict

import numpy as np


def _configs(out_dir: str) -> list[dict]:
    """The results directory's scenario configs, in order (its manifest)."""
    from hlip_jax.sweepio import store
    return store.read_manifest(out_dir)["configs"]


def _group(config: dict) -> str:
    """The path's name, and the peak speed where the sweep varies it."""
    speed = config.get("swept", {}).get("path.peak_speed")
    return config["name"].split("/")[0] + ("" if speed is None else f" at {speed:g} m/s")


def table(out_dir: str) -> list[str]:
    """Markdown rows, one per (MPC, path, swept speed) and one per MPC for all together."""
    with open(os.path.join(out_dir, "summary.csv"), newline="") as f:
        rows = list(csv.DictReader(f))
    configs = {c["name"]: c for c in _configs(out_dir)}
    groups = defaultdict(list)
    for r in rows:
        c = configs[r["name"]]
        mpc = "tube" if c["mpc"]["robust"] else "nominal"
        groups[(mpc, _group(c))].append(r)
        groups[(mpc, "all")].append(r)
    lines = []
    for (mpc, path), rs in sorted(groups.items()):
        clear = np.array([float(r["min_clearance"]) for r in rs])
        walked = sum(r["status"] != "fell" for r in rs)
        rms = np.median([float(r["rms_track_err"]) for r in rs])
        qp = sum(int(r["qp_failures"]) for r in rs)
        lines.append(f"| {mpc} | {path} | {walked}/{len(rs)} | {int((clear < 0).sum())}/{len(rs)} "
                     f"| {clear.min():.3f} | {rms:.3f} | {qp} |")
    return lines


def outside_hull(out_dir: str, hull_file: str) -> tuple[int, int, list[float]]:
    """(tube steps with a disturbance outside the hull W in either plane, tube steps, largest
    gauge per plane)."""
    from scipy.spatial import ConvexHull

    from hlip_jax.core import robust
    from hlip_jax.sweepio import store
    tube = [i for i, c in enumerate(_configs(out_dir)) if c["mpc"]["robust"]]
    facets = [ConvexHull(np.concatenate([v, -v])).equations for v in robust.read_hull(hull_file)]
    outside, total, worst = 0, 0, [0.0, 0.0]
    for i in tube:
        _, samples, _ = store.disturbance_samples(out_dir, [i])
        out = np.zeros(len(samples[0]), bool)
        for p, eq in enumerate(facets):
            normal, offset = eq[:, :3], eq[:, 3]            # inside: normal·d + offset ≤ 0
            worst[p] = max(worst[p], float((samples[p] @ normal.T / -offset).max()))
            out |= (samples[p] @ normal.T + offset > 1e-12).any(axis=1)
        outside, total = outside + int(out.sum()), total + len(out)
    return outside, total, worst


def main(argv=None) -> None:
    out_dir, hull_file = (argv or sys.argv[1:])[:2]
    print("| MPC | path | walked | entered a disc | smallest clearance [m] | median RMS distance "
          "[m] | MPC QPs not solved |")
    print("|---|---|---|---|---:|---:|---:|")
    print("\n".join(table(out_dir)))
    k, n, worst = outside_hull(out_dir, hull_file)
    print(f"tube steps with a disturbance outside the hull W: {k}/{n} = {k / max(n, 1):.1%}; "
          f"largest gauge per plane {worst[0]:.2f}, {worst[1]:.2f}")


if __name__ == "__main__":
    main()
