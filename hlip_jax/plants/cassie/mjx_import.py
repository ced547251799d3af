"""``mjx``, imported quietly: MuJoCo's MJX prints "Failed to import warp: …" to stdout at import
when the optional warp-lang package is absent (MJX-JAX then serves every call).  The import here
swallows exactly those lines and passes anything else MJX prints through unchanged."""

from __future__ import annotations

import contextlib
import io
import sys

_captured = io.StringIO()
with contextlib.redirect_stdout(_captured):
    from mujoco import mjx  # noqa: E402  (the one place the package imports MJX)

_QUIET = ("Failed to import warp:", "Failed to import mujoco_warp:")
for _line in _captured.getvalue().splitlines():
    if not _line.startswith(_QUIET):
        print(_line, file=sys.stdout)

__all__ = ["mjx"]
