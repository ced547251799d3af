"""Validation metadata of configuration fields: every config class (the generic ones in
:mod:`hlip_jax.simulation.config`, each plant's own in its folder) declares its fields with :func:`spec`,
and the sweep validator reads them back with :func:`field_spec`."""

from __future__ import annotations

import dataclasses
import json
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


#: the most characters of a user's value that a message shows (:func:`show_value`): a value
#: of megabytes (a string, an array) never makes a message of megabytes
FMT_MAX_CHARS = 200


def show_value(v) -> str:
    """A user's value for a one-line message: floats as %g, tables and arrays as JSON cut to 60
    characters, anything else its repr cut to :data:`FMT_MAX_CHARS`."""
    if isinstance(v, float):
        return f"{v:g}"
    if isinstance(v, (dict, list)):
        s = json.dumps(v, default=str)
        return s if len(s) <= 60 else s[:57] + "..."
    s = repr(v)
    return s if len(s) <= FMT_MAX_CHARS else s[:FMT_MAX_CHARS - 3] + "..."
