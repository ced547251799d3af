"""The identified S2S map against the H-LIP's on held-out runs (docs/coverage_study.md).

Usage::

    python benchmarks/s2s_heldout.py RESULTS_DIR

Per path of a results directory with swept seeds: the least-squares map
[p, v]+ = Â [p, v] + B̂ u + ĉ(stance) per plane (:func:`hlip_jax.core.s2s_fit.fit`) fitted on the odd
seeds, and the residuals of the even seeds under it and under the planner's H-LIP
(:func:`hlip_jax.core.s2s_fit.residuals`): RMS and the 1st-99th percentile spread, p [m] and
v [m/s], and their ratio (H-LIP over identified).
"""

from __future__ import annotations

import argparse
import pathlib
from collections import defaultdict

import numpy as np

from hlip_jax.core import s2s_fit
from hlip_jax.sweepio import store


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", type=pathlib.Path)
    a = ap.parse_args(argv)
    man = store.read_manifest(a.results)
    log = store.load_log(a.results)
    by_path = defaultdict(lambda: ([], []))
    for s, i in enumerate(log["index"]):
        sw = man["configs"][int(i)]["swept"]
        by_path[sw.get("path", "")][int(sw["seed"]) % 2 == 0].append(s)
    print("| path | plane | n train / test pairs | w spread p, v (H-LIP) | spread p, v "
          "(identified) | ratio p, v | RMS p, v (H-LIP) | RMS p, v (identified) |")
    print("|---|---|---|---|---|---|---|---|")
    A3, B3 = np.asarray(log["A"][0]), np.asarray(log["B"][0])
    for path, (train, test) in by_path.items():
        model = s2s_fit.fit(log, train)
        r_id = s2s_fit.residuals(log, test, model)
        r_h = s2s_fit.residuals(log, test, None, hlip=s2s_fit.hlip_rows(A3, B3))
        for j, plane in enumerate(("sagittal", "lateral")):
            spread = [np.percentile(r[:, j], 99, axis=0) - np.percentile(r[:, j], 1, axis=0)
                      for r in (r_h, r_id)]
            rms = [np.sqrt(np.mean(r[:, j] ** 2, axis=0)) for r in (r_h, r_id)]
            f = lambda v: f"{v[0]:.4f}, {v[1]:.3f}"  # noqa: E731
            print(f"| {path} | {plane} | {model.n} / {len(r_id)} | {f(spread[0])} | "
                  f"{f(spread[1])} | {spread[0][0] / spread[1][0]:.1f}, "
                  f"{spread[0][1] / spread[1][1]:.1f} | {f(rms[0])} | {f(rms[1])} |")


if __name__ == "__main__":
    main()
