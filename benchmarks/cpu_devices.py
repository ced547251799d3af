"""A while loop over a batch split across CPU devices: partitioned by XLA against one loop per
device (``shard_map``), against one device.

The closed loop's tick loop runs until no robot of the batch is still in its step.  Split
over devices by XLA's partitioner, that stopping test becomes a cross-device reduction on
every trip; :func:`hlip_jax.simulation.execution._per_device` gives each device its own loop instead.
This times a toy loop of the same shape (a batch of small matrix products, stopping when
every row's counter has reached ``--trips``)::

    python benchmarks/cpu_devices.py --devices 2 --batch 6 --trips 400000

prints the seconds of each variant (best of ``--repeats``, after a compile).
"""

from __future__ import annotations

import argparse
import os
import sys
import time


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--devices", type=int, default=2)
    ap.add_argument("--batch", type=int, default=6)
    ap.add_argument("--trips", type=int, default=400_000)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    if "jax" in sys.modules:
        sys.exit("run as a script: the device count must be set before JAX starts")
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "")
                               + f" --xla_force_host_platform_device_count={args.devices}")
    import jax
    import jax.numpy as jnp
    import numpy as np
    from jax.sharding import Mesh, NamedSharding, PartitionSpec as P

    def loop(x, n):
        def body(c):
            i, x = c
            return i + (i < n), jnp.tanh(x @ jnp.full((28, 28), 0.01, x.dtype) + 0.1)
        return jax.lax.while_loop(lambda c: jnp.any(c[0] < n), body,
                                  (jnp.zeros(x.shape[0], n.dtype), x))[1]

    mesh = Mesh(np.asarray(jax.devices("cpu")[:args.devices]), ("s",))
    split = NamedSharding(mesh, P("s"))
    x = jnp.ones((args.batch, 28), jnp.float32)
    n = jnp.full((args.batch,), args.trips, jnp.int32)
    variants = {
        "one device": (jax.jit(loop), (x, n)),
        "partitioned by XLA": (jax.jit(loop), jax.device_put((x, n), split)),
        "one loop per device (shard_map)": (
            jax.jit(jax.shard_map(loop, mesh=mesh, in_specs=P("s"), out_specs=P("s"),
                                  check_vma=False)),
            jax.device_put((x, n), split)),
    }
    print(f"{args.batch} rows, {args.trips} trips, {args.devices} CPU devices, "
          f"jax {jax.__version__}")
    for name, (fn, a) in variants.items():
        jax.block_until_ready(fn(*a))
        best = float("inf")
        for _ in range(args.repeats):
            t = time.perf_counter()
            jax.block_until_ready(fn(*a))
            best = min(best, time.perf_counter() - t)
        print(f"{name}: {best:.3f} s", flush=True)


if __name__ == "__main__":
    main()
