"""``mjx``, imported quietly: MuJoCo's MJX prints "Failed to import warp: …" to stdout at import
when the optional warp-lang package is absent (MJX-JAX then serves every call).  The import here
swallows exactly those lines and passes anything else MJX prints through unchanged; where
warp-lang is installed, its start-up banner is switched off before MJX initialises it."""

from __future__ import annotations

import contextlib
import io
import sys

try:  # the optional Warp implementation: no start-up banner or module-load lines in a
    import warp as _warp  # sweep's output (warnings and errors still print)
    _warp.config.log_level = _warp.LOG_WARNING
except ImportError:
    pass

_captured = io.StringIO()
with contextlib.redirect_stdout(_captured):
    from mujoco import mjx  # noqa: E402  (the one place the package imports MJX)

_QUIET = ("Failed to import warp:", "Failed to import mujoco_warp:")
for _line in _captured.getvalue().splitlines():
    if not _line.startswith(_QUIET):
        print(_line, file=sys.stdout)

__all__ = ["mjx"]
