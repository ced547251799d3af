"""Arrays kept as files between processes: one ``.npz`` per key under a directory.

A key (bytes) names the file by its SHA-256; the file holds the arrays and a SHA-256 of the
key and of their dtypes, shapes and bytes, written to a temporary file and renamed into place
(a reader never sees half a file).  :meth:`ArrayCache.load` returns None for anything else: no
file, a damaged or foreign one (another key's arrays under this key's name included), a digest
that does not match; :meth:`ArrayCache.save` gives up quietly on a full or read-only disk, and
:meth:`ArrayCache.prune` deletes only the regular files it finds and skips those it cannot.  A
cache never fails the work that uses it; the work then computes the arrays itself.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path
from typing import NamedTuple

import numpy as np

from hlip_jax.runtime.cache_files import least_recently_used

_DIGEST = "_digest"
#: bytes an :class:`ArrayCache` keeps after :meth:`ArrayCache.prune` (default)
MAX_BYTES = 256 << 20


def _digest(key: bytes, arrays: dict) -> np.ndarray:
    """SHA-256 (32,) uint8 of ``key`` and of each array's name, dtype, shape and bytes: the
    key makes a file copied or renamed to another key's name a mismatch."""
    h = hashlib.sha256(hashlib.sha256(key).digest())
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
        except Exception:
            # a foreign file fails in many ways besides OSError, ValueError and BadZipFile:
            # zlib.error (a damaged compressed member), TypeError (a .npy, not an archive),
            # NotImplementedError (a compression method zipfile lacks), MemoryError (a header's
            # huge shape); none of them may end the run
            return None
        stored = arrays.pop(_DIGEST, None)
        if stored is None or not np.array_equal(stored, _digest(key, arrays)):
            return None
        return arrays

    def prune(self, budget: int = MAX_BYTES) -> int:
        """Delete the least recently used files until the rest total at most ``budget`` bytes;
        returns the bytes freed (best effort: only regular ``.npz`` files, never a directory or
        a symbolic link, whose target may lie outside the cache; a file that cannot be deleted
        is skipped)."""
        freed = 0
        try:
            files = [f for f in self.path.glob("*.npz") if f.is_file() and not f.is_symlink()]
        except OSError:
            return 0
        for f, size in least_recently_used(files, budget,
                                           lambda st: max(st.st_atime_ns, st.st_mtime_ns)):
            try:
                f.unlink(missing_ok=True)
            except OSError:
                continue
            freed += size
        return freed

    def save(self, key: bytes, arrays: dict) -> None:
        """Store ``arrays`` (name → numeric array) under ``key``; best effort (module doc)."""
        tmp = None
        try:
            self.path.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=self.path, suffix=".tmp")
            with os.fdopen(fd, "wb") as fh:
                np.savez(fh, **arrays, **{_DIGEST: _digest(key, arrays)})
            os.replace(tmp, self.file(key))
            tmp = None
        except OSError:
            pass
        finally:
            if tmp is not None:
                Path(tmp).unlink(missing_ok=True)
