"""support.jaxpr_census (used by benchmarks/scatter_census.py and benchmarks/eqn_census.py)
counts a function's equations (its scatters by default) by primitive and line, and groups
them by source file."""

import inspect
from pathlib import Path

import jax
import jax.numpy as jnp

from support import jaxpr_census


def _f(x, i):
    y = jax.ops.segment_sum(x, i, 3)                     # one scatter-add
    z = jnp.zeros(4).at[1].set(x[0])                      # one scatter
    return jax.lax.fori_loop(0, 2, lambda k, a: a.at[k].add(1.0), y), z  # one in the body


def test_census_counts_each_scatter_once_with_its_line():
    counts = jaxpr_census.census(_f, jnp.ones(5), jnp.array([0, 1, 1, 2, 2]), depth=1)
    lines, start = inspect.getsourcelines(_f)
    here = Path(__file__).name
    by_line = {(p, w[0].rsplit(":", 1)[1]): n for (p, w), n in counts.items()
               if w and here in w[0]}
    assert by_line == {("scatter-add", str(start + 1)): 1, ("scatter", str(start + 2)): 1,
                       ("scatter-add", str(start + 3)): 1}
    assert sum(counts.values()) == 3


def _g(x):
    y = jnp.sin(x) * 2.0                                  # sin, mul
    return jax.lax.fori_loop(0, 3, lambda k, a: a + 1.0, y)   # the loop; add in its body


def test_an_empty_prefix_counts_every_equation_and_eqn_census_groups_them_by_file():
    counts = jaxpr_census.census(_g, jnp.ones(3), depth=1, prefix="")
    # a fixed trip count makes the loop a scan; its counter's increment is JAX's own (no
    # frame outside JAX), sin, mul, the scan and the body's add are this file's
    assert sorted(p for p, _ in counts.elements()) == ["add", "add", "mul", "scan", "sin"]
    files = jaxpr_census.by_file(counts)
    mine = [n for f, n in files.items() if f.endswith(Path(__file__).name)]  # path from cwd
    assert files["(jax)"] == 1 and mine == [4] and len(files) == 2
