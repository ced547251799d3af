"""Progress news from inside a compiled closed loop.

A chunk of scenarios is one compiled call; without news from inside it a long chunk shows
nothing until it ends.  While someone listens (:func:`listening`, checked by :func:`active`
when the chunk starts) the rollout runs its walking steps in segments of one compiled program
and calls :func:`step_done` from Python after each segment (:func:`hlip_jax.simulation.execution.run`): no
host callback is compiled into the loop, so the loop's executable can be kept on disk."""

from __future__ import annotations

import contextlib
from typing import Callable, Iterator

_listeners: list[Callable[[int, int], None]] = []


@contextlib.contextmanager
def listening(fn: Callable[[int, int], None]) -> Iterator[None]:
    """Within the block, ``fn(steps_done, n_steps)`` hears every finished walking step."""
    _listeners.append(fn)
    try:
        yield
    finally:
        _listeners.remove(fn)


def active() -> bool:
    """Whether anyone listens (the rollout compiles the callback in only then)."""
    return bool(_listeners)


def step_done(k, n_steps: int) -> None:
    """Step ``k`` (0-based) of ``n_steps`` is finished: tell the innermost listener."""
    if _listeners:
        _listeners[-1](int(k) + 1, int(n_steps))
