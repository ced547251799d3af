"""Idle ticks and fallen robots in a batch: wall time and step logs of a small closed loop.

Four Cassies walk a line for 3 s (the `paper` preset of sweeps/paper.toml); the last is knocked
over by a 600 N lateral push at 1 s.  Prints the compile + first call and the second call's wall
time [s] and the statuses, and saves the step log (every Log field) to OUT.npz.  Run it in two
checkouts (``ROOT``) to compare a change: the valid steps' arrays must be equal and the second
call's time is the figure.

    python benchmarks/cassie_idle_ticks.py . new.npz
    python benchmarks/cassie_idle_ticks.py /path/to/other/checkout old.npz
"""

import dataclasses
import json
import sys
import time

import numpy as np

ROOT = sys.argv[1] if len(sys.argv) > 1 else "."
OUT = sys.argv[2] if len(sys.argv) > 2 else "cassie_idle_ticks.npz"
sys.path.insert(0, ROOT)

from hlip_jax.simulation import arrays, execution
from hlip_jax.sweepio import sweep  # noqa: E402
from hlip_jax.simulation.config import PathConfig, PushConfig  # noqa: E402


def configs():
    base = sweep.load_sweep(f"{ROOT}/sweeps/paper.toml").scenarios[0]
    out = []
    for i, v in enumerate([0.3, 0.5, 0.4, 0.5]):
        pushes = (PushConfig(time=1.0, duration=0.1, force=600.0, direction=90.0),) if i == 3 else ()
        out.append(dataclasses.replace(
            base, name=f"s{i}", duration=3.0, seed=i, obstacles=(),
            path=PathConfig(shape="line", params=dict(peak_speed=v, length=5.0, accel=0.25)),
            disturbance=dataclasses.replace(base.disturbance, pushes=pushes)))
    return out


def main():
    cfgs = configs()
    shapes = arrays.shapes_of(cfgs)
    t0 = time.time()
    execution.simulate(cfgs, shapes=shapes)
    t1 = time.time()
    log = execution.simulate(cfgs, shapes=shapes)
    t2 = time.time()
    fields = {k: np.asarray(getattr(log, k)) for k in log._fields if getattr(log, k) is not None}
    np.savez(OUT, **fields)
    print(json.dumps(dict(first=round(t1 - t0, 2), second=round(t2 - t1, 2),
                          status=arrays["status"].tolist(),
                          fail_step=arrays["fail_step"].tolist())))


if __name__ == "__main__":
    main()
