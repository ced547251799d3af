"""Interval estimates for the success rates and coverages the evaluation reports.

The unit of independence is the run: a proportion over runs gets the Clopper–Pearson interval
below; a proportion over the steps of several runs (steps of one run are serially correlated)
gets the run-cluster bootstrap (:func:`cluster_bootstrap`).

Clopper–Pearson ("exact") interval of a binomial proportion: with k successes in n trials and
level 1 − α, the bounds are the α/2 and 1 − α/2 quantiles of Beta distributions,

    lower = B⁻¹(α/2; k, n − k + 1)        (0 when k = 0)
    upper = B⁻¹(1 − α/2; k + 1, n − k)    (1 when k = n),

so that P(p < lower) ≤ α/2 and P(p > upper) ≤ α/2 for every true p (conservative coverage).
Closed forms at the ends: k = 0 gives upper = 1 − (α/2)^(1/n), k = n gives lower = (α/2)^(1/n).
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from scipy import stats as _st


def clopper_pearson(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """(lower, upper) of the exact ``level`` interval for k successes in n trials."""
    if not (isinstance(n, int) and n >= 1):
        raise ValueError(f"n: expected an integer >= 1, got {n!r}")
    if not (isinstance(k, int) and 0 <= k <= n):
        raise ValueError(f"k: expected an integer in [0, {n}], got {k!r}")
    if not 0.0 < level < 1.0:
        raise ValueError(f"level: expected a number in (0, 1), got {level!r}")
    a = 1.0 - level
    lo = 0.0 if k == 0 else float(_st.beta.ppf(a / 2, k, n - k + 1))
    hi = 1.0 if k == n else float(_st.beta.ppf(1 - a / 2, k + 1, n - k))
    return lo, hi


def rate_text(k: int, n: int, level: float = 0.95) -> str:
    """"k/n = p % [lo, hi]" with the Clopper–Pearson interval, for tables."""
    lo, hi = clopper_pearson(k, n, level)
    return f"{k}/{n} = {100 * k / n:.0f} % [{100 * lo:.0f}, {100 * hi:.0f}]"


def cluster_bootstrap(hits: Sequence[np.ndarray], level: float = 0.95, n_boot: int = 2000,
                      seed: int = 0) -> tuple[float, float]:
    """Percentile interval of a pooled proportion whose trials come in correlated clusters.

    ``hits``: one bool array per cluster (a run's kept steps, True = covered).  The statistic
    is the pooled fraction Σ_i k_i / Σ_i n_i; each of ``n_boot`` resamples draws the clusters
    with replacement (whole runs, never single steps, so the serial correlation inside a run
    stays in every resample), and the interval is the (α/2, 1 − α/2) percentiles of the
    resampled statistic.  Clusters without trials are dropped; (nan, nan) when none is left.
    The resampling is seeded (``seed``), so a results directory's figures are reproducible.
    When every trial is a success (or every one a failure) no resample can differ and the
    percentile interval would collapse to a point; the interval is then Clopper–Pearson over
    the clusters, each counted as one trial (every step of a run covered is at least as likely
    as the run being covered), e.g. [(α/2)^(1/m), 1] for m clusters without a failure."""
    if not 0.0 < level < 1.0:
        raise ValueError(f"level: expected a number in (0, 1), got {level!r}")
    k = np.array([np.sum(h) for h in hits if np.size(h)], np.float64)
    n = np.array([np.size(h) for h in hits if np.size(h)], np.float64)
    if n.size == 0:
        return math.nan, math.nan
    if k.sum() in (0.0, n.sum()):
        m = n.size
        return clopper_pearson(m if k.sum() else 0, m, level)
    idx = np.random.default_rng(seed).integers(0, n.size, size=(n_boot, n.size))
    frac = k[idx].sum(axis=1) / n[idx].sum(axis=1)
    a = 1.0 - level
    lo, hi = np.quantile(frac, [a / 2, 1 - a / 2])
    return float(lo), float(hi)
