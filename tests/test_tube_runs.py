"""benchmarks/tube_runs.py on a small H-LIP tube sweep: the share of disturbances outside a
hull W and its gauge against the closed forms of a box (conv of a box's corners)."""

import itertools

import numpy as np

from hlip_jax.sweepio import runner, store, sweep

from support import load_benchmark

tube_runs = load_benchmark("tube_runs")

SWEEP = """
name = "tube_runs"
[base]
plant = "hlip"
duration = 4.0
[base.mpc]
w_frame = "world"
w_c_1 = 0.01
w_p_1 = 0.01
w_v_1 = 0.05
w_c_2 = 0.01
w_p_2 = 0.01
w_v_2 = 0.05
[base.disturbance]
noise_p = 0.01
noise_v = 0.05
[[paths]]
name = "line"
shape = "line"
[[paths.overrides.obstacles]]
x = 1.0
y = 0.3
radius = 0.1
[grid.product]
"mpc.robust" = [false, true]
seed = [1, 2]
"""


def _box_hull(path, h):
    """A hull W file whose points are the corners of the box [−h, h] (both planes)."""
    rows = ["plane,c,p,v"]
    for plane in (1, 2):
        for s in itertools.product((-1, 1), repeat=3):
            rows.append(f"{plane}," + ",".join(repr(float(a * b)) for a, b in zip(s, h[plane - 1])))
    path.write_text("\n".join(rows) + "\n")


def test_outside_share_and_gauge_match_the_box_closed_forms(tmp_path):
    """For W = a box, a sample is outside iff some |d_i| > h_i and its gauge is max_i |d_i| / h_i;
    the facets of scipy's hull must give the same to round-off (1e-9)."""
    out = tmp_path / "r"
    runner.run_sweep(sweep.parse_sweep(SWEEP), out, progress=False)
    names = [c["name"] for c in store.read_manifest(out)["configs"]]
    tube = [i for i, n in enumerate(names) if "mpc.robust=True" in n]
    assert len(tube) == 2
    samples = [np.concatenate(s) for s in zip(*(store.disturbance_samples(out, [i])[1]
                                                for i in tube))]
    extent = np.stack([np.abs(s).max(axis=0) for s in samples])           # (2, 3)
    for scale in (0.5, 2.0):
        h = extent * scale
        _box_hull(tmp_path / "w.csv", h)
        k, n, worst = tube_runs.outside_hull(str(out), str(tmp_path / "w.csv"))
        outside = np.zeros(len(samples[0]), bool)
        for p in range(2):
            outside |= (np.abs(samples[p]) > h[p]).any(axis=1)
        assert (k, n) == (int(outside.sum()), len(outside))
        np.testing.assert_allclose(worst, [(np.abs(s) / hp).max() for s, hp in zip(samples, h)],
                                   rtol=1e-9)
    assert k == 0                                                          # the 2× box holds all
    rows = tube_runs.table(str(out))
    assert any(r.startswith("| tube | all | 2/2 |") for r in rows)
    assert any(r.startswith("| nominal | all | 2/2 |") for r in rows)
