"""Which scatter operations a Cassie tick stage traces, and from which source lines.

XLA's deterministic GPU operations (``--xla_gpu_deterministic_ops``, on in the CLI) replace
every scatter whose indices may repeat by an order-fixed implementation, which is slower.  This
lists, per stage of ``benchmarks/tick_profile.py``, the scatter primitives of its jaxpr
(``scatter``, ``scatter-add``, ``scatter-mul``, …; the bodies of loops and conditionals counted
once each) grouped by the innermost two source frames outside JAX:

    python benchmarks/scatter_census.py --stages terms condense qp_build

The counting itself is :func:`tests.support.jaxpr_census.census` (the tests use it too).
"""

from __future__ import annotations

import argparse
import pathlib
import sys

import jax

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))   # the repository root

from tests.support.jaxpr_census import census  # noqa: E402


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
