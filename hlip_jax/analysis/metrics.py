"""Per-scenario metrics of a closed-loop run, from its step log (:mod:`hlip_jax.core.steplog`).

They fill ``summary.csv`` (:func:`hlip_jax.sweepio.store.write_summary`); each is computed over the
scenario's valid pre-impact samples k, i.e. the steps before any failure.


* ``rms_track_err``, ``max_track_err`` [m]: distance of the robot COM c_k (x–y) to the path,
  taken as the polyline through the reference positions r(t_j) of that scenario (the
  step-sampled path; chord error ≈ L²/(8R), ~3 mm for 0.2 m steps on a 2 m circle).
* ``rms_pos_err`` [m]: RMS of |c_k − r(t_k)| (time-indexed tracking error, includes lag).
* ``final_pos_err`` [m]: |c_k − r(t_k)| at the last valid step.
* ``emax_{x,y}_{c,p,v}``: max |e| per plane and component [m, m, m/s].
* ``place_err_rms`` [m]: RMS over valid steps of |δu_k|, the foot-placement error (executed
  step minus the stepping law's step u_HLIP + K e at the same pre-impact error;
  :func:`hlip_jax.core.invariant.placement_errors`); ``place_err_along`` [m]: its mean along the path
  heading (a systematic over- (> 0) or under-step).  0 on the H-LIP plant without step noise.
* ``cov_{x,y}_inner`` / ``cov_{x,y}_outer``: in-sample coverage bracket of the kept errors
  (the analysis pipeline's run, :func:`hlip_jax.analysis.runs.run_errors`: after the sweep's
  warm-up, default :data:`hlip_jax.analysis.masks.WARMUP`, outside push windows) in the mRPI set E of
  ``e⁺ = (A + BK) e + d`` (the ``box`` estimator) with W the box of every disturbance the run
  met while walking outside push windows, d = w + B δu (the S2S disturbance plus the
  foot-placement error; the warm-up's too, since they drive the kept errors): the errors obey
  this recursion exactly, so a run started at e = 0 is covered in-sample whenever its W
  contains the origin, and the held-out figure is the test; the state is [c, p, v] when the
  gain acts on c, else [p, v].
* ``cov_{x,y}_heldout``: W and E from the first half of the kept steps, coverage (outer set)
  of the kept errors in the second half (:func:`hlip_jax.analysis.splits.time_halves`).
* The coverage and E-size metrics are per plane of the scenario's :func:`analysis_frame`:
  x = sagittal (along the path heading θ_d(t_k)) and y = lateral when the gain is the same in
  both planes (errors and disturbances rotated step by step,
  :func:`hlip_jax.core.invariant.heading_frame`), world x and y otherwise.  ``emax_*`` stay in the
  world frame.
* ``e_size_{x,y}``: volume of that in-sample E (outer set; [m²·m/s] on [c, p, v], [m·m/s] on
  [p, v]): the size of the error tube a gain earns on this run.
* ``push_peak_err`` [m]: largest COM-to-path distance from the first push's start on
  (NaN without a push).
* ``push_recovery_steps``: steps from the first pre-impact sample at or after the first push's
  start until the COM-to-path distance is within ``RECOVERY_TOL`` (0.15 m) and stays within it
  to the end of the run (0 if it never left; NaN without a push, after a failure, or when it is
  not back by the end).
* ``qp_failures``: valid steps whose MPC QP status is not 1 (solved).
* ``min_clearance`` [m]: min obstacle clearance over valid steps (inf without obstacles).
* ``min_feet_gap``, ``min_leg_gap`` [m]: smallest clearance between the two feet, and between
  any two lower-leg links of opposite legs, over the valid steps (the step log's ``leg_gap``;
  inf on the point-foot H-LIP plant).  ``collision_steps``: valid steps whose lower-leg
  clearance went below zero — the simulated legs pass through each other where a real robot's
  would collide (:mod:`hlip_jax.plants.cassie.collisions`).
* ``est_err_p`` [m], ``est_err_v`` [m/s]: RMS over the valid steps and both planes of the
  controller's estimate minus the truth at SSP⁻ (the step log's ``x_est − x_robot``) for p and
  v: how far off the state the stepping law acted on was (0 where the plant senses perfectly;
  NaN for results written before the estimate was logged).
"""

from __future__ import annotations

import math

import numpy as np

from hlip_jax.core import box_mrpi
from hlip_jax.core import invariant as inv
from hlip_jax.core import steplog
from hlip_jax.analysis import estimators, masks, runs, splits
from hlip_jax.analysis.errors import W_MIN_HALFWIDTH, placement

SUMMARY_METRICS = (
    "steps", "rms_track_err", "max_track_err", "rms_pos_err", "final_pos_err",
    "emax_x_c", "emax_x_p", "emax_x_v", "emax_y_c", "emax_y_p", "emax_y_v",
    "cov_x_inner", "cov_x_outer", "cov_x_heldout", "cov_y_inner", "cov_y_outer", "cov_y_heldout",
    "qp_failures", "min_clearance", "e_size_x", "e_size_y", "push_peak_err",
    "push_recovery_steps", "place_err_rms", "place_err_along", "min_feet_gap", "min_leg_gap",
    "collision_steps", "est_err_p", "est_err_v",
)

#: COM-to-path distance a pushed robot must return to and stay within [m] (the paper's push
#: acceptance: back within 0.15 m of the path)
RECOVERY_TOL = 0.15



def _seg_dist(P: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Distance of each point P (n, 2) to the polyline through R (m, 2) [same units]."""
    if R.shape[0] == 1:
        return np.linalg.norm(P - R[0], axis=1)
    a, b = R[:-1], R[1:]                       # (m-1, 2)
    ab = b - a
    L2 = np.maximum(np.sum(ab * ab, axis=1), 1e-300)
    ap = P[:, None, :] - a[None]               # (n, m-1, 2)
    s = np.clip(np.sum(ap * ab[None], axis=2) / L2[None], 0.0, 1.0)
    d = ap - s[..., None] * ab[None]
    return np.sqrt(np.min(np.sum(d * d, axis=2), axis=1))


def _walked_rows(log: dict, s: int, pushes, warmup: int) -> list[tuple]:
    """Scenario ``s``'s two planes as (A_cl (n, n), W samples, points) twice each: the
    in-sample row (W from the disturbances d_k with k, k+1 both walked outside push windows,
    points the kept errors) and the held-out row (W from the first half of the kept steps,
    points the errors of the second half)."""
    Acl, _, run = runs.run_errors(log, s, pushes, warmup)
    m = run.masks
    walked = m.alive & ~m.push_window
    early, late = splits.time_halves(m.kept)
    out = []
    for p in range(2):
        for steps, pts in ((walked, run.kept_e(p)), (early, run.e[late, p])):
            out.append((np.ascontiguousarray(Acl[p], np.float64),
                        run.d[steps[1:] & steps[:-1], p], pts))
    return out


def _box_brackets(rows: list[tuple]):
    """The box estimator's brackets of ``rows`` (A_cl, W samples, points), batched per A_cl
    (:func:`hlip_jax.core.box_mrpi.box_sets`): a list of (ok, coverage inner, outer, volume)."""
    out = [(False, math.nan, math.nan, math.nan)] * len(rows)
    by_a: dict = {}
    for i, (A, d, _) in enumerate(rows):
        if len(d) and inv.schur_stable(A):
            by_a.setdefault(A.tobytes(), []).append(i)
    for ix in by_a.values():
        W = [estimators.box_w(rows[i][1]) for i in ix]
        bs = box_mrpi.box_sets(rows[ix[0]][0], np.stack([w.lo for w in W]),
                               np.stack([w.hi for w in W]), W_MIN_HALFWIDTH)
        cov = box_mrpi.coverage(bs, [rows[i][2] for i in ix])
        for j, i in enumerate(ix):
            out[i] = (bool(bs.ok[j]), cov.inner[j], cov.outer[j], bs.volume[j])
    return out


def coverage_columns(log: dict, scenarios, pushes: list, warmup: int) -> list[dict]:
    """The in-sample and time-split coverage columns (module doc) of ``scenarios`` of a log,
    ``pushes`` their push windows: every scenario's sets and membership tests batched by
    closed-loop matrix, the same sets as :func:`hlip_jax.core.sets.mrpi` of each box."""
    rows = [r for s, w in zip(scenarios, pushes) for r in _walked_rows(log, s, w, warmup)]
    fits = _box_brackets(rows)
    out = []
    for k in range(len(scenarios)):
        m = {key: math.nan for plane in "xy" for key in (
            f"cov_{plane}_inner", f"cov_{plane}_outer", f"cov_{plane}_heldout", f"e_size_{plane}")}
        for p, plane in enumerate("xy"):
            (ok, inner, outer, vol), (ok_early, _, heldout, _) = fits[4 * k + 2 * p:4 * k + 2 * p + 2]
            if ok:
                m.update({f"cov_{plane}_inner": inner, f"cov_{plane}_outer": outer,
                          f"e_size_{plane}": vol,
                          f"cov_{plane}_heldout": heldout if ok_early else math.nan})
        out.append(m)
    return out


def push_recovery(d_path: np.ndarray, t: np.ndarray, t_push: float, failed: bool,
                  tol: float = RECOVERY_TOL) -> tuple[float, float]:
    """(peak distance, steps to recover) after a push starting at ``t_push`` [s], from the
    COM-to-path distances ``d_path`` [m] at the valid pre-impact times ``t`` [s] (module
    docstring); ``failed``: the run ended in a failure (no recovery counted)."""
    after = np.flatnonzero(t >= t_push - 1e-9)
    if after.size == 0:
        return math.nan, math.nan
    d = d_path[after]
    peak = float(np.max(d))
    if failed:
        return peak, math.nan
    out = np.flatnonzero(d > tol)
    if out.size == 0:
        return peak, 0.0
    if out[-1] == d.size - 1:             # still outside at the end of the run
        return peak, math.nan
    return peak, float(out[-1] + 1)


def scenario_metrics(log: dict, s: int, with_coverage: bool = True, pushes=(),
                     warmup: int = masks.WARMUP) -> dict:
    """Summary metrics of scenario ``s`` of a log dict (see the module docstring); ``pushes``:
    the scenario's acting pushes as (start [s], duration [s]) (:func:`push_windows`);
    ``warmup``: the steps the coverage metrics leave out at the start (the sweep's
    ``[analysis] warmup``)."""
    push_time = min(t for t, _ in pushes) if len(pushes) else None
    mask = steplog.alive(log["valid"][s])       # steps before any failure
    n = int(mask.sum())
    m = {k: math.nan for k in SUMMARY_METRICS}
    m["steps"] = n
    m["qp_failures"] = int(np.sum(mask & (np.asarray(log["qp_status"][s]) != 1)))
    clr = np.asarray(log["clearance"][s], np.float64)[mask]
    m["min_clearance"] = float(np.min(clr)) if clr.size else math.inf
    gap = np.asarray(log["leg_gap"][s], np.float64)[mask]              # (n, 2) feet, legs
    m["min_feet_gap"], m["min_leg_gap"] = ((float(np.min(gap[:, 0])), float(np.min(gap[:, 1])))
                                           if n else (math.inf, math.inf))
    m["collision_steps"] = int(np.sum(gap[:, 1] < 0.0))
    if n == 0:
        return m
    c = np.asarray(log["x_robot"][s], np.float64)[mask][:, :, 0]   # (n, 2) COM x, y
    r = np.asarray(log["ref_pos"][s], np.float64)[mask]
    d_time = np.linalg.norm(c - r, axis=1)
    d_path = _seg_dist(c, r)
    m["rms_track_err"] = float(np.sqrt(np.mean(d_path ** 2)))
    m["max_track_err"] = float(np.max(d_path))
    m["rms_pos_err"] = float(np.sqrt(np.mean(d_time ** 2)))
    m["final_pos_err"] = float(d_time[-1])
    if push_time is not None:
        t = np.asarray(log["t_plant"][s], np.float64)[mask]        # pushes act on the plant clock
        m["push_peak_err"], m["push_recovery_steps"] = push_recovery(
            d_path, t, push_time, failed=int(np.asarray(log["status"][s])) != 0)
    du_all = placement(log, s)                                       # (K, 2)
    du = du_all[mask]
    h = np.asarray(log["ref_heading"][s], np.float64)[mask]
    m["place_err_rms"] = float(np.sqrt(np.mean(np.sum(du ** 2, axis=1))))
    m["place_err_along"] = float(np.mean(np.cos(h) * du[:, 0] + np.sin(h) * du[:, 1]))
    if "x_est" in log:
        de = (np.asarray(log["x_est"][s], np.float64) - np.asarray(log["x_robot"][s], np.float64))[mask]
        m["est_err_p"], m["est_err_v"] = (float(np.sqrt(np.mean(de[:, :, j] ** 2))) for j in (1, 2))
    e = np.abs(np.asarray(log["e"][s], np.float64)[mask])            # (n, 2, 3)
    for p, plane in enumerate("xy"):
        for j, comp in enumerate("cpv"):
            m[f"emax_{plane}_{comp}"] = float(np.max(e[:, p, j]))
    if with_coverage:
        m.update(coverage_columns(log, [s], [pushes], warmup)[0])
    return m


def chunk_metrics(log: dict, pushes: list, with_coverage: bool = True,
                  warmup: int = masks.WARMUP) -> list[dict]:
    """:func:`scenario_metrics` of every scenario of a log dict (leading axis: the scenarios,
    ``pushes`` one list of push windows each), the coverage columns of all of them in one batch
    (:func:`coverage_columns`)."""
    out = [scenario_metrics(log, s, False, w, warmup) for s, w in enumerate(pushes)]
    if with_coverage:
        for m, c in zip(out, coverage_columns(log, range(len(pushes)), pushes, warmup)):
            m.update(c)
    return out



def active_pushes(cfg) -> list:
    """The scenario's pushes that act (positive force and duration)."""
    return [p for p in cfg.disturbance.pushes if p.force > 0 and p.duration > 0]


def push_windows(cfg) -> list[tuple[float, float]]:
    """The scenario's acting pushes as (start [s], duration [s]) on the plant's clock."""
    return [(float(p.time), float(p.duration)) for p in active_pushes(cfg)]
