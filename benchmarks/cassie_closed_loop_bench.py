"""Closed-loop Cassie throughput against physics-only MJX in the same run (the body is
:mod:`hlip_jax.sweepio.bench`, also reachable as ``hlip-sweep bench``).

    python benchmarks/cassie_closed_loop_bench.py --batch 2 --duration 0.7      # CPU
    python benchmarks/cassie_closed_loop_bench.py --batch 8192 --duration 0.84   # one GPU
    python benchmarks/cassie_closed_loop_bench.py --batch 16384 --devices 1 2      # 2 GPUs
"""

from __future__ import annotations

import sys

from hlip_jax.presentation.cli import main

if __name__ == "__main__":
    sys.exit(main(["bench", *sys.argv[1:]]))
