"""How large the closed loop's compiled programs are, and which source files make them so.

XLA's compile time grows with the program it is given.  This counts the equations of the
start or segment program (:func:`hlip_jax.simulation.rollout.start_batch`, ``segment_batch``; the
bodies of loops and conditionals counted once each) of a sweep file's first ``--batch``
scenarios, grouped by the source file of their innermost frame outside JAX ("(jax)": issued
by JAX's own jitted helpers, such as ``jnp`` indexing)::

    python benchmarks/eqn_census.py --sweep sweeps/paper.toml [--program segment]
        [--no-physics] [--top 25]

``--no-physics`` replaces the physics step by a function that only sets the motor torques,
leaving what the controller, the step's end and the MPC add: with Warp physics
(``impl.physics = "warp"``) the physics is one foreign call XLA does not compile, so this
is the part of the program XLA compiles (Warp itself needs a GPU).
"""

from __future__ import annotations

import argparse
import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))   # the repository root

from tests.support import jaxpr_census  # noqa: E402


def _no_physics() -> None:
    from hlip_jax.plants.cassie import control

    def physics(cassie, d, ctrl, force, mx=None, backend="jax", robots=1):
        return d.replace(ctrl=ctrl)
    control.physics = physics


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sweep", default="sweeps/paper.toml")
    ap.add_argument("--batch", type=int, default=6)
    ap.add_argument("--program", choices=["start", "segment"], default="segment")
    ap.add_argument("--no-physics", action="store_true")
    ap.add_argument("--top", type=int, default=25)
    args = ap.parse_args(argv)
    if args.no_physics:
        _no_physics()
    import jax

    from hlip_jax.simulation import arrays, rollout
    from hlip_jax.sweepio.sweep import load_sweep
    cfgs = list(load_sweep(args.sweep).scenarios)[:args.batch]
    batch, static = arrays.build(cfgs)
    static = static._replace(progress=True)
    with jax.default_matmul_precision("highest"):
        if args.program == "start":
            counts = jaxpr_census.census(lambda b: rollout.start_batch(b, static), batch,
                                         depth=1, prefix="")
        else:
            carry = jax.eval_shape(lambda b: rollout.start_batch(b, static), batch)[0]
            ks = jax.numpy.arange(rollout.segment_length(static.n_steps))
            counts = jaxpr_census.census(
                lambda b, c, k: rollout.segment_batch(b, c, k, static), batch, carry, ks,
                depth=1, prefix="")
    print(f"{args.sweep}: {len(cfgs)} scenarios, {args.program} program"
          f"{', physics left out' if args.no_physics else ''}: "
          f"{sum(counts.values())} equations", flush=True)
    for f, n in jaxpr_census.by_file(counts).most_common(args.top):
        print(f"  {n:6d}  {f}")


if __name__ == "__main__":
    main()
