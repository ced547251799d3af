"""Across-run coverage of error-invariant sets: W from training runs, E tested on other runs.

Per group of runs that share the S2S model and gain (same path, plant, A, B, K; the grouping of
:func:`hlip_jax.store.write_coverage`) and per plane, with the error system
e⁺ = A_cl e + d (d = w + B δu, the S2S residual plus the foot-placement error; see
:mod:`hlip_jax.invariant`):

1. Split the runs into train and test (:func:`split_by_replicate`: by replicate key, i.e. the
   swept ``seed`` value, so that no replicate is on both sides; ``split = "seed"``; when the
   seed is not swept, each run is its own replicate, ``split = "run"``; or by the values of a
   field, :func:`split_by_value`).  A group of one run falls back to a time split of that
   run (:func:`time_halves`), labelled ``split = "time"``: it measures whether one run's
   extremes are stationary, not whether E predicts other runs.
2. W from the disturbance samples d of the training runs that walked to the end
   (:func:`box_w`, :func:`conformal_box_w`), E = mRPI(A_cl, W) (:func:`hlip_jax.invariant.mrpi`,
   outer set F_s/(1−α)).  A run that fell is left out of W (``train_fell`` counts them): its
   last steps are the controller's failure, not a disturbance the stepping law met while
   walking, and a single fall would otherwise set W (and E) for every run of its group.  The
   test runs keep their falls: a test run's errors count up to its fall (``test_fell``), so a
   fall that leaves E lowers the coverage.
   Push steps (a step k whose interval [t_k, t_{k+1}] overlaps a configured push) are left out
   of W by default ("box", "quantile"); "box_with_push" keeps them.  The test errors at or
   after a run's first push are also counted on their own (``push_coverage``).
3. Coverage = k / n, k = number of the test runs' error samples e_k inside E, n = number of
   test samples, with the Clopper–Pearson interval (:func:`hlip_jax.stats.clopper_pearson`).
   The interval treats the n samples as independent Bernoulli trials; errors of one run are
   serially correlated, so it is narrower than an interval over runs would be (the number of
   runs is reported beside it).
4. E where it is read: the half-extent of E along each state axis, max(h_E(u_j), h_E(−u_j)),
   c and p in metres, v in m/s (``e_*_max``; per coordinate, so no mixed units), beside the
   largest measured |error| of the test samples in that coordinate (``err_*_max``).  On the
   [p, v] state (a gain without a c term) E does not bound c: ``e_c_max`` is NaN while
   ``err_c_max`` still reports the measured COM position error.

Split-conformal quantile box (:func:`conformal_box_w`), level q: per coordinate j,
r_j = |d_j|_(m), the m-th smallest of the n training values |d_j|, m = ⌈(n+1) q⌉ (defined for
m ≤ n, i.e. n ≥ q / (1 − q)), and W = [−r, r].  Guarantee: if a new sample d* is exchangeable
with the n training samples, P(|d*_j| ≤ r_j) ≥ q for each coordinate j separately (marginal over
the training draw and d*; ≤ q + 1/(n+1) without ties).  Not guaranteed: joint coverage of all
coordinates (only ≥ 1 − dim·(1 − q) by the union bound), coverage of the errors by E (an error
sums many disturbances, so E from a q-box covers errors at a level the theorem does not give),
or a box centred anywhere but 0 (W is symmetric about the origin; a biased disturbance widens
it).  Exchangeability of single steps holds for i.i.d. step noise (the H-LIP plant's uniform
S2S noise); on a robot whose steps are serially correlated it is an assumption: independent
replicate runs are exchangeable as runs, their pooled steps need not be.
"""

from __future__ import annotations

import math
from typing import NamedTuple, Sequence

import numpy as np

from hlip_jax import invariant as inv
from hlip_jax import stats

__all__ = ["RunSamples", "conformal_rank", "conformal_box_w", "box_w", "split_by_replicate",
           "split_by_value", "time_halves", "coverage_ci", "plane_row", "group_rows",
           "COLUMNS", "W_METHODS", "PLANES"]

#: w_method values: "box" = per-axis min/max of the training samples outside push steps;
#: "box_with_push" = the same including push steps (written only when training has push steps);
#: "quantile" = split-conformal box at level q, push steps excluded.
W_METHODS = ("box", "box_with_push", "quantile")

#: plane column values per analysis frame (planes 1, 2): the heading frame's sagittal and
#: lateral planes, or the world's x and y (:func:`hlip_jax.metrics.analysis_frame`)
PLANES = {"heading": ("sagittal", "lateral"), "world": ("world x", "world y")}

#: coverage.csv columns, in order: train_runs / test_runs = runs on each side, train_fell /
#: test_fell = those that fell (the training ones are left out of W); train_samples =
#: disturbance samples W was estimated from
#: (push steps left out unless w_method = "box_with_push"); test_samples = test errors; covered
#: = those inside E; ci_low, ci_high = 95 % Clopper–Pearson; insample_coverage = the training
#: errors in the same E (consistency); push_* = test errors at or after a push; w_lo, w_hi =
#: the W box (space-separated, state order); e_*_max / err_*_max = E's half-extent / the
#: largest |test error| per state coordinate [m, m, m/s]; state = "[c, p, v]" or "[p, v]".
COLUMNS = ("group", "plane", "w_method", "q", "split", "train_runs", "test_runs",
           "train_fell", "test_fell", "train_samples", "test_samples", "covered", "coverage",
           "ci_low", "ci_high", "insample_coverage", "push_test_samples", "push_coverage",
           "w_lo", "w_hi", "e_c_max", "err_c_max", "e_p_max", "err_p_max", "e_v_max",
           "err_v_max", "state", "note")


class RunSamples(NamedTuple):
    """One run's samples in its analysis frame and state (n = 3: [c, p, v]; n = 2: [p, v]).

    e (K, 2, n) errors; emask (K,) counted errors (alive); epush (K,) errors at or after the
    run's first push; d (K−1, 2, n) error-system disturbances, e_{k+1} = A_cl e_k + d_k;
    dmask (K−1,) counted disturbances (both ends alive); dpush (K−1,) steps whose interval
    [t_k, t_{k+1}] overlaps a push; ec (K, 2) the COM position error c [m] (kept when n = 2);
    fell: the run fell (its step log ends before the run's duration)."""
    e: np.ndarray
    emask: np.ndarray
    epush: np.ndarray
    d: np.ndarray
    dmask: np.ndarray
    dpush: np.ndarray
    ec: np.ndarray
    fell: bool = False


def conformal_rank(n: int, q: float) -> int:
    """m = ⌈(n+1) q⌉, the order statistic of the split-conformal bound; ValueError when m > n
    (too few samples for level q: n ≥ q / (1 − q) needed)."""
    if not 0.0 < q < 1.0:
        raise ValueError(f"q: expected a level in (0, 1), got {q!r}")
    m = math.ceil((n + 1) * q - 1e-12)
    if m > n:
        raise ValueError(f"conformal level q = {q}: needs n ≥ {math.ceil(q / (1 - q) - 1e-9)} "
                         f"samples, got {n}")
    return max(m, 1)


def conformal_box_w(samples: np.ndarray, q: float) -> tuple[np.ndarray, np.ndarray]:
    """Split-conformal box W = [−r, r] (module docstring): r_j the ⌈(n+1) q⌉-th smallest of
    |samples[:, j]|.  samples (n, dim); returns (lo, hi) (dim,)."""
    P = np.abs(np.asarray(samples, np.float64).reshape(-1, np.shape(samples)[-1]))
    m = conformal_rank(P.shape[0], q)
    r = np.sort(P, axis=0)[m - 1]
    return -r, r


def box_w(samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis (min, max) box of samples (n, dim); ValueError without samples."""
    P = np.asarray(samples, np.float64).reshape(-1, np.shape(samples)[-1])
    if P.shape[0] == 0:
        raise ValueError("box_w: no samples")
    return P.min(axis=0), P.max(axis=0)


def split_by_replicate(keys: Sequence, train_fraction: float = 0.5):
    """(train, test) run indices: the sorted distinct replicate keys, the first
    ⌈train_fraction · n_keys⌉ (at most n_keys − 1) for training, the rest for testing; every
    run of a key goes to that key's side, so no key is on both sides.  ValueError with fewer
    than 2 distinct keys."""
    if not 0.0 < train_fraction < 1.0:
        raise ValueError(f"train_fraction: expected a number in (0, 1), got {train_fraction!r}")
    ks = list(keys)
    uniq = sorted(set(ks), key=lambda k: (str(type(k)), k))
    if len(uniq) < 2:
        raise ValueError(f"split_by_replicate: needs ≥ 2 distinct replicate keys, got {len(uniq)}")
    n_tr = min(max(math.ceil(train_fraction * len(uniq)), 1), len(uniq) - 1)
    tr_keys = set(uniq[:n_tr])
    train = np.array([i for i, k in enumerate(ks) if k in tr_keys], int)
    test = np.array([i for i, k in enumerate(ks) if k not in tr_keys], int)
    return train, test


def split_by_value(values: Sequence, train_values: Sequence):
    """(train, test) run indices: runs whose value is in ``train_values`` train, the others
    test (e.g. W from the circles, tested on the sinusoids)."""
    want = set(train_values)
    train = np.array([i for i, v in enumerate(values) if v in want], int)
    test = np.array([i for i, v in enumerate(values) if v not in want], int)
    return train, test


def time_halves(run: RunSamples) -> tuple[RunSamples, RunSamples]:
    """A single run split in time: training disturbances d_k with k + 1 < h and errors k < h,
    test errors k ≥ h, h = half the counted errors (the per-run held-out split of
    :mod:`hlip_jax.store`).  A fall is the run's last step, so only the test half holds it."""
    h = int(run.emask.sum()) // 2
    kd = np.arange(run.dmask.size)
    ke = np.arange(run.emask.size)
    train = run._replace(dmask=run.dmask & (kd + 1 < h), emask=run.emask & (ke < h), fell=False)
    test = run._replace(dmask=run.dmask & False, emask=run.emask & (ke >= h))
    return train, test


def coverage_ci(E, points: np.ndarray, level: float = 0.95):
    """(covered k, samples n, k/n, ci_low, ci_high) of ``points`` (n, dim) in E (outer set of
    an :class:`hlip_jax.invariant.MRPI`, or any set with ``contains``), with the
    Clopper–Pearson interval at ``level``; n = 0 gives (0, 0, nan, nan, nan)."""
    P = np.asarray(points, np.float64).reshape(-1, E.dim)
    if P.shape[0] == 0:
        return 0, 0, math.nan, math.nan, math.nan
    c = inv.coverage(E, P)
    k = int(round(c.outer * c.n))
    lo, hi = stats.clopper_pearson(k, c.n, level)
    return k, c.n, k / c.n, lo, hi


def _pool(runs, p: int, which: str, extra=None):
    """Stack plane p of the counted samples of ``runs``: which = "d" or "e"; extra: a mask
    name ("dpush", "epush") and the value it must take, or None."""
    out = []
    for r in runs:
        m = r.dmask.copy() if which == "d" else r.emask.copy()
        if extra is not None:
            m &= getattr(r, extra[0]) == extra[1]
        out.append((r.d if which == "d" else r.e)[m, p])
    dim = runs[0].e.shape[-1]
    return np.concatenate(out) if out else np.zeros((0, dim))


def _axis_max(E, dim: int) -> np.ndarray:
    """max(h_E(u_j), h_E(−u_j)) per coordinate j: the half-extent of E along each axis."""
    D = np.concatenate([np.eye(dim), -np.eye(dim)])
    h = np.asarray(E.support(D), np.float64)
    return np.maximum(h[:dim], h[dim:])


def _w_box(method: str, train, p: int, q: float):
    """(lo, hi, number of samples) of W by ``method`` (:data:`W_METHODS`) from plane p."""
    d = _pool(train, p, "d") if method == "box_with_push" else \
        _pool(train, p, "d", ("dpush", False))
    lo, hi = conformal_box_w(d, q) if method == "quantile" else box_w(d)
    return lo, hi, d.shape[0]


def _sizes(E, test, p: int, dim: int) -> dict:
    """E's half-extent per state coordinate [m, m, m/s] beside the largest measured |error| of
    the test samples; c of E is NaN on the [p, v] state (c is not bounded there)."""
    names = ("c", "p", "v")[3 - dim:]
    ext = _axis_max(E, dim)
    err = np.abs(_pool(test, p, "e"))
    out = {"e_c_max": math.nan}
    for j, nm in enumerate(names):
        out[f"e_{nm}_max"] = float(ext[j])
        if nm != "c":       # c's error comes from every run's c error, on either state
            out[f"err_{nm}_max"] = float(err[:, j].max()) if err.size else math.nan
    ec = [np.abs(r.ec[r.emask, p]) for r in test]
    ec = np.concatenate(ec) if ec else np.zeros(0)
    out["err_c_max"] = float(ec.max()) if ec.size else math.nan
    return out


def plane_row(A_cl, train, test, p: int, method: str, q: float, min_halfwidth) -> dict:
    """One coverage.csv row's statistics (plane p, one W method): W from ``train``
    (:class:`RunSamples`), E = mRPI(A_cl, W), coverage of ``test``'s errors with their
    interval, in-sample coverage of ``train``'s errors (a consistency check: ≈ 1 for the box),
    coverage of the test errors after a push, and E's extent beside the measured errors."""
    dim = train[0].e.shape[-1]
    lo, hi, n_w = _w_box(method, train, p, q)
    E = inv.mrpi(A_cl, inv.Box(lo, hi), min_halfwidth=min_halfwidth)
    k, n, cov, cl, ch = coverage_ci(E, _pool(test, p, "e"))
    _, _, ins, _, _ = coverage_ci(E, _pool(train, p, "e"))
    _, n_push, cov_push, _, _ = coverage_ci(E, _pool(test, p, "e", ("epush", True)))
    row = {"train_samples": n_w, "test_samples": n,
           "covered": k, "coverage": cov, "ci_low": cl, "ci_high": ch, "insample_coverage": ins,
           "push_test_samples": n_push, "push_coverage": cov_push,
           "w_lo": " ".join(f"{v:.6g}" for v in lo), "w_hi": " ".join(f"{v:.6g}" for v in hi),
           "state": "[c, p, v]" if dim == 3 else "[p, v]", "note": ""}
    row.update(_sizes(E, test, p, dim))
    return row


def group_rows(group: str, A_cl, runs: Sequence[RunSamples], keys: Sequence, planes,
               q: float = 0.9, min_halfwidth=None, split_name: str = "seed",
               train_values: Sequence | None = None) -> list[dict]:
    """coverage.csv rows of one group: per plane (names ``planes``, A_cl (2, n, n)) and W
    method.  ``train_values`` None: runs split by replicate ``keys``
    (:func:`split_by_replicate`; the ``split`` column says ``split_name``, what the keys are:
    "seed" or "run"), or in time when the group has one replicate (``split`` = "time").
    ``train_values`` given: ``keys`` are the values of a field (``split_name``, e.g. "path")
    and the runs with a value in ``train_values`` train, the others test
    (:func:`split_by_value`).  A row whose statistic cannot be formed (no samples, too few for
    level q, unstable A_cl) keeps NaN values and says why in ``note``."""
    if train_values is not None:
        tr, te = split_by_value(keys, train_values)
        train, test = [runs[i] for i in tr], [runs[i] for i in te]
        split = split_name
    elif len(set(keys)) >= 2:
        tr, te = split_by_replicate(keys)
        train, test = [runs[i] for i in tr], [runs[i] for i in te]
        split = split_name
    else:
        halves = [time_halves(r) for r in runs]
        train, test = [h[0] for h in halves], [h[1] for h in halves]
        split = "time"
    walked = [r for r in train if not r.fell]
    base = {"group": group, "split": split, "train_runs": len(train), "test_runs": len(test),
            "train_fell": len(train) - len(walked), "test_fell": sum(bool(r.fell) for r in test)}
    why = ("no training run" if not train else "no test run" if not test else
           "every training run fell: no W" if not walked else None)
    if why is not None:
        return [dict({c: math.nan for c in COLUMNS}, **base, plane=plane, w_method="box",
                     note=why) for plane in planes]
    train = walked
    has_push = any((r.dmask & r.dpush).any() for r in train)
    methods = [m for m in W_METHODS if m != "box_with_push" or has_push]
    rows = []
    for p, plane in enumerate(planes):
        for method in methods:
            row = {c: math.nan for c in COLUMNS}
            row.update(base, plane=plane, w_method=method,
                       q=q if method == "quantile" else math.nan)
            try:
                if not inv.schur_stable(A_cl[p]):
                    raise ValueError("A + BK is not Schur stable: no bounded E")
                row.update(plane_row(A_cl[p], train, test, p, method, q, min_halfwidth))
            except ValueError as err:
                row["note"] = str(err)
            rows.append(row)
    return rows
