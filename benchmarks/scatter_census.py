"""Which scatter operations a Cassie tick stage traces, and from which source lines.

XLA's deterministic GPU operations (``--xla_gpu_deterministic_ops``, on in the CLI) replace
every scatter whose indices may repeat by an order-fixed implementation, which is slower.  This
lists, per stage of ``benchmarks/tick_profile.py``, the scatter primitives of its jaxpr
(``scatter``, ``scatter-add``, ``scatter-mul``, …; the bodies of loops and conditionals counted
once each) grouped by the innermost two source frames outside JAX:

    python benchmarks/scatter_census.py --stages terms condense qp_build
"""

from __future__ import annotations

import argparse
import collections
import os
import sys

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
    ``jnp``'s jitted helpers) has none."""
    counts = collections.Counter()
    _walk(jax.make_jaxpr(fn)(*args).jaxpr, counts, depth, prefix)
    return counts


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stages", nargs="+", default=["terms", "condense", "qp_build"])
    ap.add_argument("--top", type=int, default=12, help="source lines shown per stage")
    args = ap.parse_args(argv)
    sys.path.insert(0, __file__.rsplit("/", 1)[0])
    import tick_profile
    from hlip_jax.plants.cassie import control
    c = control.load()
    d, warm, des = tick_profile._state(c, 2)
    stages = tick_profile._stages(c, des, 2)
    for name in args.stages:
        counts = census(jax.vmap(stages[name]), d, warm)
        print(f"{name}: {sum(counts.values())} scatter equations")
        for (prim, where), n in counts.most_common(args.top):
            print(f"  {n:4d}  {prim:12s} {' <- '.join(where)}")


if __name__ == "__main__":
    main()
