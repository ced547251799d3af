"""Run-to-run reproducible sweeps on a GPU: XLA's deterministic GPU operations, on by default.

On a GPU, XLA implements scatters and some reductions with atomic additions whose order
varies from run to run.  The closed loop is chaotic, so those
last-bit differences grow: runs of the same five paper scenarios on one H200 differed by
up to 10 cm in the COM after ten steps (BENCHMARKS.md, "GPU runs repeat bit for bit").
``--xla_gpu_deterministic_ops=true`` makes XLA use order-fixed implementations; with it the two
runs were equal bit for bit, at the same speed for that batch.  The CLI adds the flag to
``XLA_FLAGS`` before JAX starts its backend; a user who sets the flag in ``XLA_FLAGS``
(``=true`` or ``=false``) keeps that value.  The CPU backend ignores it (its operations are
deterministic).
"""

from __future__ import annotations

import os
from typing import MutableMapping

FLAG = "--xla_gpu_deterministic_ops"


def with_deterministic_ops(flags: str) -> str:
    """``flags`` (an XLA_FLAGS value) with ``FLAG=true`` appended, unless it already sets FLAG."""
    if any(f.split("=", 1)[0] == FLAG for f in flags.split()):
        return flags
    return f"{flags} {FLAG}=true".strip()


def apply(environ: MutableMapping[str, str] = os.environ) -> None:
    """Set ``environ["XLA_FLAGS"]`` as :func:`with_deterministic_ops` says (call before the
    first JAX computation: XLA reads the variable when the backend starts)."""
    environ["XLA_FLAGS"] = with_deterministic_ops(environ.get("XLA_FLAGS", ""))
