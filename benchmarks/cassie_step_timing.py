"""Step timing and step placement of the walking Cassie against the H-LIP it is planned with.

Walks robots from standing along straight orbits (no MPC: :func:`orbits.walk_orbits`, the
"paper" gait preset and its LQR stepping gain) and prints, per step k:

- the step's duration on the plant clock against the H-LIP period T = T_SSP + T_DSP and the
  touchdown the swing profile predicts, T_DSP + s* T_SSP (:func:`outputs.landing_fraction`);
- the executed step u_k (ankle to ankle at SSP⁻_k) against the stepping law evaluated at the
  robot's own pre-impact state, u_H,k + K (x_R,k − x_H,k);
- the S2S residual w_k = x_R,k+1 − A x_R,k − B u_k (sagittal plane).

    python benchmarks/cassie_step_timing.py --speeds 0.5 --steps 12
"""

from __future__ import annotations

import argparse
import pathlib
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))   # the repository root

from hlip_jax.plants.cassie import gaits, outputs  # noqa: E402
from tests.support import cassie_orbits as orbits  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--speeds", type=float, nargs="+", default=[0.5], help="forward speeds [m/s]")
    ap.add_argument("--steps", type=int, default=12)
    args = ap.parse_args()
    P = gaits.preset("paper")
    z0, ts, td = P["hlip.z0"], P["hlip.t_ssp"], P["hlip.t_dsp"]
    k = np.asarray(orbits.lqr_step_gain(z0, ts, td, P["gain.q_c"], P["gain.q_v"], P["gain.r"]))
    s_star = float(outputs.landing_fraction(P["cassie.clearance"], P["cassie.strike"]))
    n, B = args.steps, len(args.speeds)
    log, _ = orbits.walk_orbits(args.speeds, [0.0] * B, [0.0] * B, n, z0=z0, t_ssp=ts, t_dsp=td,
                                width=0.2, gain=np.tile(k, (2, 1)))
    print(f"H-LIP period T = {ts + td:.4f} s; profile touchdown T_DSP + s* T_SSP = "
          f"{td + s_star * ts:.4f} s (s* = {s_star:.4f}); gain K = {np.round(k, 4)}")
    for i, v in enumerate(args.speeds):
        print(f"\nforward {v} m/s\n step  duration [s]  u exec  u law [m]  w = [c, p, v]")
        excess = []
        for j in range(1, n):
            xr, xh = log.x_robot[i, j, 0], log.x_hlip[i, j, 0]
            law = log.u_hlip[i, j, 0] + k @ (xr - xh)
            u = log.u_robot[i, j, 0]
            w = log.w[i, j - 1, 0]          # walk_orbits' residual of step j (from step 1 on)
            dur = log.time[i, j + 1] - log.time[i, j]
            excess.append(u - law)
            print(f" {j:4d}  {dur:11.3f}  {u:6.3f}  {law:9.3f}  {np.round(w, 3)}")
        durs = np.diff(log.time[i, 1:])
        c = log.x_robot[i, :, 0, 0]
        print(f" mean duration {durs.mean():.4f} s; mean u exec − u law {np.mean(excess):+.4f} m; "
              f"COM speed over steps 1..{n} {(c[n] - c[1]) / (log.time[i, n] - log.time[i, 1]):.3f} "
              f"m/s (H-LIP orbit {v} m/s)")


if __name__ == "__main__":
    main()
