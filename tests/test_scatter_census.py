"""benchmarks/scatter_census.py counts a function's scatter equations by primitive and line."""

import inspect
import sys
from pathlib import Path

import jax
import jax.numpy as jnp

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import scatter_census  # noqa: E402


def _f(x, i):
    y = jax.ops.segment_sum(x, i, 3)                     # one scatter-add
    z = jnp.zeros(4).at[1].set(x[0])                      # one scatter
    return jax.lax.fori_loop(0, 2, lambda k, a: a.at[k].add(1.0), y), z  # one in the body


def test_census_counts_each_scatter_once_with_its_line():
    counts = scatter_census.census(_f, jnp.ones(5), jnp.array([0, 1, 1, 2, 2]), depth=1)
    lines, start = inspect.getsourcelines(_f)
    here = Path(__file__).name
    by_line = {(p, w[0].rsplit(":", 1)[1]): n for (p, w), n in counts.items()
               if w and here in w[0]}
    assert by_line == {("scatter-add", str(start + 1)): 1, ("scatter", str(start + 2)): 1,
                       ("scatter-add", str(start + 3)): 1}
    assert sum(counts.values()) == 3
