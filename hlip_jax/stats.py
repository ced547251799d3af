"""Interval estimates for the success rates the evaluation reports.

Clopper–Pearson ("exact") interval of a binomial proportion: with k successes in n trials and
level 1 − α, the bounds are the α/2 and 1 − α/2 quantiles of Beta distributions,

    lower = B⁻¹(α/2; k, n − k + 1)        (0 when k = 0)
    upper = B⁻¹(1 − α/2; k + 1, n − k)    (1 when k = n),

so that P(p < lower) ≤ α/2 and P(p > upper) ≤ α/2 for every true p (conservative coverage).
Closed forms at the ends: k = 0 gives upper = 1 − (α/2)^(1/n), k = n gives lower = (α/2)^(1/n).
"""

from __future__ import annotations

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
