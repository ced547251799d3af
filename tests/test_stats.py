"""Clopper–Pearson intervals against their closed forms and a brute-force binomial check."""

import numpy as np
import pytest
from scipy import stats as st

from hlip_jax.analysis.stats import clopper_pearson, rate_text


def test_ends_match_closed_forms():
    """k = 0: upper = 1 − (α/2)^(1/n); k = n: lower = (α/2)^(1/n) (float round-off, 1e-12)."""
    for n in (1, 5, 16, 64):
        lo, hi = clopper_pearson(0, n)
        assert lo == 0.0 and abs(hi - (1 - 0.025 ** (1 / n))) < 1e-12
        lo, hi = clopper_pearson(n, n)
        assert hi == 1.0 and abs(lo - 0.025 ** (1 / n)) < 1e-12


@pytest.mark.parametrize("k,n", [(3, 10), (12, 16), (62, 64)])
def test_bounds_are_where_the_binomial_tails_reach_alpha_half(k, n):
    """The defining property, checked with the binomial distribution itself (an independent
    route from the Beta quantiles): P(X ≥ k | p = lower) = P(X ≤ k | p = upper) = α/2 (1e-9)."""
    lo, hi = clopper_pearson(k, n)
    assert abs(st.binom.sf(k - 1, n, lo) - 0.025) < 1e-9
    assert abs(st.binom.cdf(k, n, hi) - 0.025) < 1e-9
    assert lo < k / n < hi


def test_bad_input_names_the_argument():
    for args, name in (((1, 0), "n"), ((5, 4), "k"), ((-1, 4), "k"), ((1, 4, 1.0), "level")):
        with pytest.raises(ValueError, match=f"^{name}:"):
            clopper_pearson(*args)
    assert rate_text(16, 16).startswith("16/16 = 100 % [79, 100]")
    assert np.isclose(clopper_pearson(8, 16)[0], 1 - clopper_pearson(8, 16)[1])
