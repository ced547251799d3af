"""Held-out coverage of error sets, over runs first: the rows of ``coverage.csv``.

Per group of runs that share the S2S model and gain (:func:`hlip_jax.sweepio.store.coverage_rows`),
per split (:mod:`hlip_jax.analysis.splits`), per plane and per method
(:mod:`hlip_jax.analysis.estimators`), two rows:

``level = "run"`` (the headline)
    A test run is *covered* when it did not fall and every kept error of it
    (:mod:`hlip_jax.analysis.masks`) lies in E.  coverage = covered runs / test runs, with the
    Clopper–Pearson 95 % interval over runs (:func:`hlip_jax.analysis.stats.clopper_pearson`):
    runs are independent, their steps are not.
``level = "step"``
    coverage = kept test errors inside E / kept test errors, with a 95 % run-cluster bootstrap
    interval (:func:`hlip_jax.analysis.stats.cluster_bootstrap`: whole runs resampled).

Beside each, per state coordinate (c, p in m, v in m/s): E's half-width ``e_half_*``, and the
test runs' own largest |error| — its q-quantile over the test runs ``err_q_*`` and its maximum
``err_max_*`` — so that conservatism (E many times the errors) is visible next to the
coverage it buys.  On the [p, v] state E does not bound c (``e_half_c`` NaN) while the c
errors are still reported.  The push-window errors are counted apart (``push_*``: recovery,
never used for W).
"""

from __future__ import annotations

import math
from typing import NamedTuple, Sequence

import numpy as np

from hlip_jax.core import invariant as inv
from hlip_jax.analysis import estimators, splits, stats
from hlip_jax.analysis.settings import DEFAULT_METHODS
from hlip_jax.analysis.runs import RunErrors

#: plane column values per analysis frame (:func:`hlip_jax.analysis.errors.analysis_frame`):
#: the heading frame's sagittal and lateral planes, or the world's x and y; defined with the
#: frames in :data:`hlip_jax.core.invariant.PLANES`
PLANES = inv.PLANES

#: coverage.csv columns, in order: level = "run" or "step"; q = the method's level (NaN for
#: box and hull); split and assumption (:mod:`hlip_jax.analysis.splits`); train_runs /
#: test_runs and the falls among them; train_samples = disturbance samples W came from;
#: test_samples = test runs (run level) or kept test errors (step level); covered and
#: coverage of them with ci_low, ci_high (95 %); insample_coverage = the training side in the
#: same E at the same level; push_test_runs, push_test_samples, push_coverage = the test
#: errors inside push windows (recovery); w_lo, w_hi = W's bounding box (state order,
#: space-separated); e_half_* / err_q_* / err_max_* per coordinate [m, m, m/s]; state =
#: "[c, p, v]" or "[p, v]"; note = why a row has no statistic.
COLUMNS = ("group", "plane", "w_method", "level", "q", "split", "assumption", "train_runs",
           "test_runs", "train_fell", "test_fell", "train_samples", "test_samples", "covered",
           "coverage", "ci_low", "ci_high", "insample_coverage", "push_test_runs",
           "push_test_samples", "push_coverage", "w_lo", "w_hi", "e_half_c", "e_half_p",
           "e_half_v", "err_q_c", "err_q_p", "err_q_v", "err_max_c", "err_max_p", "err_max_v",
           "state", "note")



def _inside(E, pts: np.ndarray) -> np.ndarray:
    """Bool per point (k, n) of E, with the membership tolerance of float32 logs."""
    if len(pts) == 0:
        return np.zeros(0, bool)
    return np.asarray(E.contains(np.asarray(pts, np.float64), 1e-6), bool)


def _hits(E, parts: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Membership of each part's points (k_i, n) in E, tested in one call (one facet set for
    all of them) and split back per part."""
    if not parts:
        return []
    inside = _inside(E, np.concatenate(parts))
    return np.split(inside, np.cumsum([len(x) for x in parts])[:-1])


def _run_hits(E, runs: Sequence[RunErrors], p: int) -> list[np.ndarray]:
    return _hits(E, [r.kept_e(p) for r in runs])


def _run_covered(hits: list[np.ndarray], runs: Sequence[RunErrors]) -> np.ndarray:
    return np.array([(not r.fell) and bool(np.all(h)) for h, r in zip(hits, runs)])


def _err_stats(runs: Sequence[RunErrors], p: int, dim: int, q: float) -> dict:
    """err_q_* (q-quantile over runs of each run's largest kept |error|) and err_max_*."""
    out = {}
    for j, nm in enumerate("cpv"):
        per_run = [np.max(np.abs(r.kept_ec(p) if nm == "c" else r.kept_e(p)[:, j - 3 + dim]))
                   for r in runs if r.masks.kept.any() and (nm == "c" or j >= 3 - dim)]
        out[f"err_q_{nm}"] = float(np.quantile(per_run, q)) if per_run else math.nan
        out[f"err_max_{nm}"] = float(np.max(per_run)) if per_run else math.nan
    return out


def _sizes(W, E, dim: int) -> dict:
    names = ("c", "p", "v")[3 - dim:]
    half = estimators.half_widths(E, dim)
    lo = np.asarray(W.support(-np.eye(dim)), np.float64) * -1.0
    hi = np.asarray(W.support(np.eye(dim)), np.float64)
    out = {"e_half_c": math.nan, "w_lo": " ".join(f"{v:.6g}" for v in lo),
           "w_hi": " ".join(f"{v:.6g}" for v in hi)}
    out.update({f"e_half_{nm}": float(h) for nm, h in zip(names, half)})
    return out


def _level_rows(E, train, test, p: int) -> tuple[dict, dict]:
    """The run-level and step-level statistics of one E."""
    hits_te, hits_tr = _run_hits(E, test, p), _run_hits(E, train, p)
    cov_te, cov_tr = _run_covered(hits_te, test), _run_covered(hits_tr, train)
    k, n = int(cov_te.sum()), len(test)
    lo, hi = stats.clopper_pearson(k, n)
    push = [r for r in test if (r.masks.push_window & r.masks.alive).any()]
    push_hits = _hits(E, [r.window_e(p) for r in push])
    run = {"test_samples": n, "covered": k, "coverage": k / n, "ci_low": lo, "ci_high": hi,
           "insample_coverage": float(cov_tr.mean()), "push_test_runs": len(push),
           "push_test_samples": len(push),
           "push_coverage": (float(np.mean([(not r.fell) and h.all()
                                            for r, h in zip(push, push_hits)]))
                             if push else math.nan)}
    ks = int(sum(h.sum() for h in hits_te))
    ns = int(sum(h.size for h in hits_te))
    slo, shi = stats.cluster_bootstrap(hits_te)
    ntr = sum(h.size for h in hits_tr)
    n_push = int(sum(h.size for h in push_hits))
    step = {"test_samples": ns, "covered": ks, "coverage": ks / ns if ns else math.nan,
            "ci_low": slo, "ci_high": shi,
            "insample_coverage": sum(h.sum() for h in hits_tr) / ntr if ntr else math.nan,
            "push_test_runs": len(push), "push_test_samples": n_push,
            "push_coverage": (sum(h.sum() for h in push_hits) / n_push if n_push
                              else math.nan)}
    return run, step


def _pooled(runs, p: int, which: str) -> np.ndarray:
    parts = [r.kept_d(p) if which == "d" else r.kept_e(p) for r in runs]
    return np.concatenate(parts) if parts else np.zeros((0, 1))


def fit(name: str, A_cl, train: Sequence[RunErrors], p: int, q: float) -> estimators.Fitted:
    """Method ``name``'s sets on plane p (A_cl (n, n)) from the training runs
    (:func:`hlip_jax.analysis.estimators.fit`)."""
    return estimators.fit(name, A_cl, [r.kept_d(p) for r in train],
                          [r.kept_e(p) for r in train], [r.fell for r in train], q)


def plane_rows(A_cl, train, test, p: int, name: str, q: float) -> list[dict]:
    """The run-level and step-level rows' statistics of plane p, one method (the shared
    columns filled by :func:`group_rows`)."""
    dim = A_cl.shape[-1]
    f = fit(name, A_cl, train, p, q)
    W, E = f.W, f.E
    common = {"train_samples": f.samples, "state": "[c, p, v]" if dim == 3 else "[p, v]",
              **_sizes(W, E, dim), **_err_stats(test, p, dim, q)}
    run, step = _level_rows(E, train, test, p)
    return [dict(common, level="run", **run), dict(common, level="step", **step)]


class PlaneConsistency(NamedTuple):
    """One plane of :func:`consistency`: W (box), E its mRPI bracket, its terms ``s`` and
    ``alpha``, E's volume, the in-sample coverage of the kept errors (inner–outer bracket), and
    the held-out coverage (W from alternate runs, the others' kept errors; None for one run)."""
    W: object
    E: object
    s: int
    alpha: float
    volume: float
    coverage: object
    heldout: object


class Consistency(NamedTuple):
    """``planes``: (sagittal or world x, lateral or world y) :class:`PlaneConsistency`."""
    planes: tuple


def consistency(A_cl, runs: Sequence[RunErrors]) -> Consistency:
    """The report's per-path consistency view: per plane the box W of every run's kept
    disturbances (runs that fell included: this is the in-sample view), its mRPI set E, and
    the coverage of the kept errors by E; with two or more runs also the held-out coverage of
    alternate runs (:func:`hlip_jax.analysis.splits.interleave` over the run order).
    ValueError where W cannot be formed (no kept disturbance) or A_cl is not Schur stable."""
    held = splits.interleave(list(range(len(runs)))) if len(runs) >= 2 else None
    planes = []
    for p in range(A_cl.shape[0]):
        W, E = estimators.fit("box", A_cl[p], [r.kept_d(p) for r in runs],
                              [r.kept_e(p) for r in runs], [False] * len(runs), 0.5)[:2]
        heldout = None
        if held is not None:
            train = [runs[i] for i in held[0]]
            E_tr = estimators.fit("box", A_cl[p], [r.kept_d(p) for r in train],
                                  [r.kept_e(p) for r in train], [False] * len(train), 0.5).E
            heldout = inv.coverage(E_tr, _pooled([runs[i] for i in held[1]], p, "e"))
        planes.append(PlaneConsistency(W, E, E.s, E.alpha, float(E.volume()),
                                       inv.coverage(E, _pooled(runs, p, "e")), heldout))
    return Consistency(tuple(planes))


#: the calibrated set the report draws beside the box W's mRPI set
FIGURE_CALIBRATED = "conformal_box"


def fitted_sets(A_cl, runs: Sequence[RunErrors], keys: Sequence, q: float):
    """For the report's figures: per plane (E of the box W, E_q of
    :data:`FIGURE_CALIBRATED` or None when it cannot be formed, the kept errors of the test
    runs (k, n)), the runs split as :func:`group_rows` splits them (alternate values of
    ``keys``)."""
    tr, te = splits.interleave(keys)
    train, test = [runs[i] for i in tr], [runs[i] for i in te]
    out = []
    for p in range(A_cl.shape[0]):
        E_box = fit("box", A_cl[p], train, p, q).E
        try:
            E_q = fit(FIGURE_CALIBRATED, A_cl[p], train, p, q).E
        except ValueError:
            E_q = None
        out.append((E_box, E_q, _pooled(test, p, "e")))
    return out


def _empty(base: dict, planes, why: str) -> list[dict]:
    return [dict({c: math.nan for c in COLUMNS}, **base, plane=pl, w_method="", level="run",
                 note=why) for pl in planes]


def group_rows(group: str, A_cl, runs: Sequence[RunErrors], keys: Sequence, planes,
               split: splits.Split, q: float, methods: Sequence[str] = DEFAULT_METHODS,
               train_values=None) -> list[dict]:
    """coverage.csv rows of one group under one split: ``keys`` the runs' values of the
    split's field; alternate values train (:func:`hlip_jax.analysis.splits.interleave`), or
    the values in ``train_values``.  A row whose statistic cannot be formed keeps NaN and
    says why in ``note``."""
    base = {"group": group, "split": split.name, "assumption": split.assumption}
    try:
        tr, te = (splits.interleave(keys) if train_values is None
                  else splits.by_values(keys, train_values))
    except ValueError as err:
        return _empty(base, planes, f"split {split.name!r} ({split.field}): {err}")
    train, test = [runs[i] for i in tr], [runs[i] for i in te]
    base.update(train_runs=len(train), test_runs=len(test),
                train_fell=sum(r.fell for r in train), test_fell=sum(r.fell for r in test))
    if not train or not test:
        return _empty(base, planes, "no training run" if not train else "no test run")
    rows = []
    for p, plane in enumerate(planes):
        for name in methods:
            m = estimators.method(name)
            head = dict({c: math.nan for c in COLUMNS}, **base, plane=plane, w_method=name,
                        q=q if m.uses_q else math.nan, note="")
            try:
                rows += [dict(head, **r) for r in plane_rows(A_cl[p], train, test, p, name, q)]
            except ValueError as err:
                rows += [dict(head, level=lv, note=str(err)) for lv in ("run", "step")]
    return rows
