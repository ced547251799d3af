"""How far the passive stance foot moves during single support.

The H-LIP state's p is measured from the stance ankle (the centre of pressure of a
zero-torque foot).  If the passive foot rolled onto its toe or heel, or slid, during SSP, the
pivot would move and p would be biased.  This re-simulates one scenario of a sweep with the
controller's 1 kHz log (:func:`hlip_jax.simulation.execution.simulate_ticks`) and reports, per walking
step, the stance foot centre's displacement from the first to the last SSP tick (horizontal
and vertical) and its largest horizontal excursion::

    python benchmarks/cassie_stance_foot.py --sweep paper --scenario 0 --duration 12

The stance foot of a step is the foot whose centre moves least over its SSP (the swing foot
moves by the step length).
"""

from __future__ import annotations

import argparse

import numpy as np


def stance_motion(feet: np.ndarray, phase: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Rows (step, foot, dx, dy, excursion, dz) [m] of the stance foot over each valid step's
    SSP; ``feet`` (K, ticks, 2, 3) foot centres, ``phase`` (K, ticks) 1 in SSP."""
    rows = []
    for k in np.flatnonzero(valid):
        ssp = np.flatnonzero(phase[k] == 1)
        if ssp.size < 2:
            continue
        f = feet[k, ssp]                                              # (n, 2, 3)
        st = int(np.argmin(np.linalg.norm(f[-1, :, :2] - f[0, :, :2], axis=-1)))
        d = f[-1, st] - f[0, st]
        excursion = np.max(np.linalg.norm(f[:, st, :2] - f[0, st, :2], axis=-1))
        rows.append((k, st, d[0], d[1], excursion, d[2]))
    return np.asarray(rows, np.float64).reshape(-1, 6)


def main(argv=None) -> None:
    from hlip_jax.simulation import execution
    from hlip_jax.sweepio import sweep
    from hlip_jax.presentation.cli import resolve_sweep
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sweep", default="paper", help="sweep file or shipped sweep name")
    ap.add_argument("--scenario", type=int, default=0, help="index of the scenario")
    ap.add_argument("--duration", type=float, default=12.0, help="simulated time [s]")
    args = ap.parse_args(argv)
    sw = sweep.load_sweep(resolve_sweep(args.sweep), duration=args.duration)
    configs = list(sw.scenarios)
    log, ticks = execution.simulate_ticks(configs, args.scenario)
    r = stance_motion(np.asarray(ticks.feet, np.float64), np.asarray(ticks.phase),
                      np.asarray(log["valid"], bool))
    mm = 1e3
    horiz = np.hypot(r[:, 2], r[:, 3])
    print(f"{configs[args.scenario].name}: {len(r)} steps; stance foot centre over SSP [mm]: "
          f"mean |d_xy| {mm * horiz.mean():.2f}, max {mm * horiz.max():.2f}, "
          f"largest excursion {mm * r[:, 4].max():.2f}, mean d_z {mm * r[:, 5].mean():.3f}")
    for foot in (0, 1):
        m = r[:, 1] == foot
        if m.any():
            dx, dy = mm * r[m, 2:4].mean(axis=0)
            print(f"  foot {foot}: {int(m.sum())} steps, mean dx {dx:.2f}, dy {dy:.2f}")


if __name__ == "__main__":
    main()
