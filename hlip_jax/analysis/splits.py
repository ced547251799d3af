"""Train/test splits of a group's runs, defined once; the run is the unit that is split.

A split names the swept field whose values are held out and what that makes the guarantee
mean:

``seed``  (field ``seed``): test runs are other noise draws of the same paths and speeds.
    Runs are exchangeable, so the run-level conformal level holds as stated.
``path``  (field ``path``): test runs walk paths no training run walked.  The level holds
    only if the sweep's paths were drawn from one family; a few hand-picked shapes are not
    such a draw, so the figure is an out-of-distribution check, not a guarantee.
``speed`` (field ``path.peak_speed``): test runs walk at speeds no training run walked;
    the same caveat as ``path``.

The distinct values of the field are sorted and assigned alternately, the 1st, 3rd, 5th … to
training and the others to test (:func:`interleave`): deterministic and about half on each
side; with an even number of values the largest is held out, so a held-out speed lies between
trained ones or, for the largest, beyond them.  A value
split (:func:`by_values`, the CLI's ``--train-on FIELD=V1,V2``) trains on the listed values.

Within one run (the summary's per-scenario figure, :mod:`hlip_jax.analysis.metrics`) the steps are
split in time instead (:func:`time_halves`): the first half of the kept steps trains, the
second tests.  Steps of one run are correlated, so this is a consistency check of that run,
not a held-out statistic.
"""

from __future__ import annotations

from typing import NamedTuple, Sequence

import numpy as np


class Split(NamedTuple):
    """A registered split: its name, the swept field it holds out, the assumption its
    guarantee rests on (the report prints it next to the number)."""
    name: str
    field: str
    assumption: str


SPLITS = {s.name: s for s in (
    Split("seed", "seed", "test runs are other noise seeds of the same paths and speeds: "
          "exchangeable runs, the conformal level holds"),
    Split("path", "path", "test runs walk other paths: exchangeable only if the paths were "
          "drawn from one family (here: an out-of-distribution check)"),
    Split("speed", "path.peak_speed", "test runs walk other speeds: exchangeable only if the "
          "speeds were drawn from one distribution (here: between and beyond the trained "
          "speeds)"),
)}


def split(name: str) -> Split:
    """The registered split ``name``; ValueError listing the names otherwise."""
    if name not in SPLITS:
        raise ValueError(f"split {name!r}; allowed: {', '.join(SPLITS)}")
    return SPLITS[name]


def _sorted_values(keys: Sequence) -> list:
    return sorted(set(keys), key=lambda k: (str(type(k)), k))


def interleave(keys: Sequence) -> tuple[np.ndarray, np.ndarray]:
    """(train, test) run indices: the sorted distinct keys alternate train, test, train, …;
    every run of a key goes to its key's side.  ValueError with fewer than 2 distinct keys."""
    uniq = _sorted_values(keys)
    if len(uniq) < 2:
        raise ValueError(f"needs >= 2 distinct values to hold out, got {len(uniq)}")
    train_keys = set(uniq[0::2])
    return by_values(keys, train_keys)


def by_values(keys: Sequence, train_values) -> tuple[np.ndarray, np.ndarray]:
    """(train, test) run indices: runs whose key is in ``train_values`` train, the rest test."""
    want = set(train_values)
    ks = list(keys)
    return (np.array([i for i, k in enumerate(ks) if k in want], int),
            np.array([i for i, k in enumerate(ks) if k not in want], int))


def time_halves(kept: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(early, late) step masks (K,) of one run: the first ⌊n/2⌋ of its n kept steps, and the
    others."""
    kept = np.asarray(kept, bool)
    early = kept & (np.cumsum(kept) <= int(kept.sum()) // 2)
    return early, kept & ~early
