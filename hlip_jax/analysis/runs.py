"""One run's analysis samples: the error system (:mod:`hlip_jax.analysis.errors`) with the
masks (:mod:`hlip_jax.analysis.masks`) applied, in the analysis frame and state.

:class:`RunErrors` fields, ``name: meaning (shape)``, K the run's logged steps, n = 3 on
[c, p, v] or 2 on [p, v]:

    e: errors e_k per plane [m, m, m/s] (K, 2, n)
    d: error-system disturbances d_k = e_{k+1} − A_cl e_k [m, m, m/s] (K−1, 2, n)
    ec: the COM position error c per plane [m] (K, 2) (kept on the [p, v] state too)
    masks: :class:`hlip_jax.analysis.masks.Masks` (kept errors, kept disturbances, the push
      window)
    fell: the run fell (bool)
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from hlip_jax.core import steplog
from hlip_jax.analysis import errors, masks as masks_mod


class RunErrors(NamedTuple):
    """One run's samples (module doc)."""
    e: np.ndarray
    d: np.ndarray
    ec: np.ndarray
    masks: masks_mod.Masks
    fell: bool

    def kept_e(self, p: int) -> np.ndarray:
        """The kept errors of plane p (k, n)."""
        return self.e[self.masks.kept, p]

    def kept_d(self, p: int) -> np.ndarray:
        """The kept disturbances of plane p (k, n)."""
        return self.d[self.masks.dkept, p]

    def window_e(self, p: int) -> np.ndarray:
        """The errors of plane p inside the push window, before any fall (k, n)."""
        return self.e[self.masks.push_window & self.masks.alive, p]

    def kept_ec(self, p: int) -> np.ndarray:
        """The kept COM position errors of plane p (k,) [m]."""
        return self.ec[self.masks.kept, p]


def run_errors(log: dict, s: int, pushes, warmup: int):
    """(A_cl (2, n, n), frame, :class:`RunErrors`) of scenario ``s`` of a step-log dict;
    ``pushes``: the scenario's (start [s], duration [s]) pairs; ``warmup``: steps dropped at
    the start (:func:`hlip_jax.analysis.masks.settled`)."""
    alive = steplog.alive(log["valid"][s])
    _, _, _, Acl, e, d, _ = errors.error_samples(log, s, alive, errors.placement(log, s))
    frame = errors.analysis_frame(log, s)
    ec = np.asarray(log["e"][s], np.float64)[:, :, 0]
    if frame == "heading":
        ec = steplog.to_heading_frame(ec, np.asarray(log["ref_heading"][s], np.float64))
    t = np.asarray(log["t_plant"][s], np.float64)
    m = masks_mod.masks(log["valid"][s], e, t, pushes, warmup)
    fell = bool(np.asarray(log["fail_step"][s]) >= 0)
    return Acl, frame, RunErrors(e, d, ec, m, fell)
