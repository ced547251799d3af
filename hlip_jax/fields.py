"""Validation metadata of configuration fields: every config class (the generic ones in
:mod:`hlip_jax.config`, each plant's own in its folder) declares its fields with :func:`spec`,
and the sweep validator reads them back with :func:`field_spec`."""

from __future__ import annotations

import dataclasses
from dataclasses import field
from typing import Any

INF = float("inf")


def spec(default, lo=-INF, hi=INF, doc="", unit="", choices=None):
    """A dataclass field with validation metadata (allowed closed range or choices)."""
    meta = {"lo": lo, "hi": hi, "doc": doc, "unit": unit, "choices": choices}
    if isinstance(default, (list, dict)):
        return field(default_factory=lambda: default, metadata=meta)
    return field(default=default, metadata=meta)


def field_spec(cls, name) -> dict[str, Any]:
    """Validation metadata of ``cls.name`` (empty for structural fields)."""
    for f in dataclasses.fields(cls):
        if f.name == name:
            return dict(f.metadata)
    raise KeyError(name)
