"""Arrays kept as files between processes: one ``.npz`` per key under a directory.

A key (bytes) names the file by its SHA-256; the file holds the arrays and a SHA-256 of their
dtypes, shapes and bytes, written to a temporary file and renamed into place (a reader never
sees half a file).  :meth:`ArrayCache.load` returns None for anything else: no file, a
damaged or foreign one, a digest that does not match; :meth:`ArrayCache.save` gives up quietly
on a full or read-only disk.  A cache never fails the work that uses it; the work then
computes the arrays itself.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import zipfile
from pathlib import Path
from typing import NamedTuple

import numpy as np

from hlip_jax.runtime.cache_files import least_recently_used

_DIGEST = "_digest"
#: bytes an :class:`ArrayCache` keeps after :meth:`ArrayCache.prune` (default)
MAX_BYTES = 256 << 20


def _digest(arrays: dict) -> np.ndarray:
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}|{a.dtype.str}|{a.shape}|".encode())
        h.update(a.tobytes())
    return np.frombuffer(h.digest(), np.uint8)


class ArrayCache(NamedTuple):
    """The ``.npz`` files under ``path`` (module doc)."""
    path: Path

    def file(self, key: bytes) -> Path:
        """The file of ``key``."""
        return self.path / (hashlib.sha256(key).hexdigest() + ".npz")

    def load(self, key: bytes) -> dict | None:
        """The arrays stored under ``key``, or None (module doc)."""
        f = self.file(key)
        try:
            if not f.is_file() or f.stat().st_size > (1 << 30):
                return None
            with np.load(f, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError):
            return None
        stored = arrays.pop(_DIGEST, None)
        if stored is None or not np.array_equal(stored, _digest(arrays)):
            return None
        return arrays

    def prune(self, budget: int = MAX_BYTES) -> int:
        """Delete the least recently used files until the rest total at most ``budget`` bytes;
        returns the bytes freed (best effort)."""
        freed = 0
        for f, size in least_recently_used(self.path.glob("*.npz"), budget,
                                           lambda st: max(st.st_atime_ns, st.st_mtime_ns)):
            f.unlink(missing_ok=True)
            freed += size
        return freed

    def save(self, key: bytes, arrays: dict) -> None:
        """Store ``arrays`` (name → numeric array) under ``key``; best effort (module doc)."""
        tmp = None
        try:
            self.path.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=self.path, suffix=".tmp")
            with os.fdopen(fd, "wb") as fh:
                np.savez(fh, **arrays, **{_DIGEST: _digest(arrays)})
            os.replace(tmp, self.file(key))
            tmp = None
        except OSError:
            pass
        finally:
            if tmp is not None:
                Path(tmp).unlink(missing_ok=True)
