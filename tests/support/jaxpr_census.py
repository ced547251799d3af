"""A function's jaxpr equations counted by primitive and source line (:func:`census`), and
grouped by source file (:func:`by_file`).

Used by ``benchmarks/scatter_census.py`` (the scatters of a Cassie tick stage),
``benchmarks/eqn_census.py`` (the equations of the closed loop's programs by file) and the
tests that count a function's scatters.
"""

from __future__ import annotations

import collections
import os

import jax
from jax.extend import core


def _frames(eqn, depth: int) -> tuple[str, ...]:
    """``file:line`` of the innermost ``depth`` frames of an equation outside JAX itself."""
    from jax._src import source_info_util
    frames = source_info_util.user_frames(eqn.source_info.traceback)
    here = os.getcwd() + os.sep
    return tuple(f"{f.file_name.split('site-packages/')[-1].replace(here, '')}:{f.start_line}"
                 for f in list(frames)[:depth])


def _walk(jaxpr, counts: collections.Counter, depth: int, prefix: str) -> None:
    for eqn in jaxpr.eqns:
        if eqn.primitive.name.startswith(prefix):
            counts[(eqn.primitive.name, _frames(eqn, depth))] += 1
        for p in eqn.params.values():
            for sub in p if isinstance(p, (list, tuple)) else (p,):
                if isinstance(sub, core.ClosedJaxpr):
                    _walk(sub.jaxpr, counts, depth, prefix)
                elif isinstance(sub, core.Jaxpr):
                    _walk(sub, counts, depth, prefix)


def census(fn, *args, depth: int = 2, prefix: str = "scatter") -> collections.Counter:
    """(primitive name, source frames) → number of equations in ``fn``'s jaxpr whose
    primitive's name starts with ``prefix`` (the scatters by default; "" counts every
    equation).  Frames outside JAX only: an equation JAX's own functions issue (inside
    ``jnp``'s jitted helpers) has none.  The bodies of loops and conditionals count once each."""
    counts = collections.Counter()
    _walk(jax.make_jaxpr(fn)(*args).jaxpr, counts, depth, prefix)
    return counts


def by_file(counts: collections.Counter) -> collections.Counter:
    """Equations per source file from a :func:`census` of depth 1 ("(jax)": issued by JAX's
    own jitted helpers, no frame outside JAX)."""
    files = collections.Counter()
    for (_, where), n in counts.items():
        files[where[0].rsplit(":", 1)[0] if where else "(jax)"] += n
    return files
