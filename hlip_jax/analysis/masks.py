"""Which pre-impact samples of a run the statistics count: the masks, defined once.

Per run of K logged steps (k = 0 … K−1; :mod:`hlip_jax.core.steplog`):

* ``alive`` (K,): steps before the first invalid one (:func:`hlip_jax.core.steplog.alive`); a
  fallen run's steps end at its fall.
* ``settled`` (K,): k ≥ max(1, warm-up).  e_0 is never counted: x_R,0 is the robot standing
  on both feet (:attr:`hlip_jax.plants.Plant.measure`; on the point-mass H-LIP the H-LIP's own
  start, e_0 = 0), not a walking pre-impact state, so e_0 says nothing about E.  The next
  ``warmup`` − 1 steps are the start's transient (the robot leaves standing for its first
  steps), not the steady disturbance W is meant to bound.
* ``push_window`` (K,): from the first error after a push starts until the error is back
  inside the run's *pre-push set*, the box [min e, max e] per plane and coordinate of the
  run's settled errors before the push (both planes, every coordinate of the analysed state);
  a run with no settled error before its push, or that never returns, keeps the window to its
  end.  These are the recovery steps: reported on their own, never used for W.
* ``kept`` (K,) = alive ∧ settled ∧ ¬push_window: the errors coverage and the run scores use;
  ``dkept`` (K−1,) = kept_k ∧ kept_{k+1}: the disturbances d_k W is estimated from (both ends
  counted, so no d_k spans a push, the start or a fall).

All masks are numpy bool arrays; times are the plant's clock [s].
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from hlip_jax.core import steplog

#: default warm-up [steps]: errors k < WARMUP are the start's transient (e_0 never counts).
#: Measured on the 1024-run coverage study (docs/coverage_study.md, "Warm-up"): the median
#: |e_p| and |e_v| over runs at steps 2-3 are up to 4.3 times their level over steps >= 10;
#: from step 4 on they stay within 2 times it.
WARMUP = 4


class Masks(NamedTuple):
    """alive, settled, push_window, kept (K,) and dkept (K−1,) bool (module doc)."""
    alive: np.ndarray
    settled: np.ndarray
    push_window: np.ndarray
    kept: np.ndarray
    dkept: np.ndarray


def settled(K: int, warmup: int) -> np.ndarray:
    """k ≥ max(1, warmup) for k = 0 … K−1 (e_0 never counts)."""
    if int(warmup) < 0:
        raise ValueError(f"warmup: expected an integer >= 0, got {warmup!r}")
    return np.arange(K) >= max(1, int(warmup))


def push_window(e: np.ndarray, t: np.ndarray, base: np.ndarray, pushes) -> np.ndarray:
    """(K,) the recovery window of a run (module doc).

    e (K, 2, n) errors, t (K,) plant times [s], base (K,) the samples that may define the
    pre-push set (alive and settled); ``pushes``: (start [s], duration [s]) pairs."""
    K = t.size
    win = np.zeros(K, bool)
    for start, dur in sorted(pushes):
        first = np.flatnonzero(t > start)
        if first.size == 0:
            continue
        k0 = int(first[0])
        before = base & (np.arange(K) < k0) & ~win
        if not before.any():
            win[k0:] = True
            continue
        lo, hi = e[before].min(axis=0), e[before].max(axis=0)
        inside = np.all((e >= lo) & (e <= hi), axis=(1, 2))
        ended = t >= start + dur
        back = np.flatnonzero(inside & ended & (np.arange(K) >= k0))
        win[k0:(int(back[0]) if back.size else K)] = True
    return win


def masks(valid: np.ndarray, e: np.ndarray, t: np.ndarray, pushes, warmup: int) -> Masks:
    """The :class:`Masks` of one run: valid (K,) the log's ``valid``, e (K, 2, n) its errors in
    the analysis frame, t (K,) plant times [s], pushes (start, duration) pairs [s]."""
    alive = steplog.alive(valid)
    sett = settled(alive.size, warmup)
    win = push_window(np.where(alive[:, None, None], e, 0.0), np.where(alive, t, np.inf),
                      alive & sett, pushes)
    kept = alive & sett & ~win
    return Masks(alive, sett, win, kept, kept[:-1] & kept[1:])
