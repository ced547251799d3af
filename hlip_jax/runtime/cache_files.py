"""Size-bounded caches on disk: which files to delete, least recently used first.  Shared by
the compilation cache (:mod:`hlip_jax.runtime.compile_cache`) and the traced-program cache
(:mod:`hlip_jax.runtime.trace_cache`)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Callable


def least_recently_used(files, budget: int, last_use: Callable[[os.stat_result], int],
                        keep: Path | None = None) -> list[tuple[Path, int]]:
    """(file, size) of the ``files`` to delete, least recently used first (``last_use`` of
    their stat), so that the rest total at most ``budget`` bytes; ``keep`` is never chosen.
    Files that vanish before their stat are left out (another process removed them)."""
    entries = []
    for f in files:
        try:
            st = f.stat()
        except OSError:
            continue
        entries.append((last_use(st), st.st_size, f))
    total = sum(size for _, size, _ in entries)
    chosen = []
    for _, size, f in sorted(entries):
        if total <= budget:
            break
        if f != keep:
            chosen.append((f, size))
            total -= size
    return chosen
