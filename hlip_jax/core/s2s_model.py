"""An identified step-to-step (S2S) model: fitted from a robot's step log, written to a file,
read back and lifted to the [c, p, v] state the planner and the stepping law use.

The paper approximates the robot's S2S map by the H-LIP's and names fitting the robot's own
map as future work.  Here one linear map on [p, v] (p the COM relative to the stance foot [m],
v its velocity [m/s], at SSP⁻) is fitted for both planes, with a constant per plane and stance
foot,

    [p, v]_{k+1} = Â [p, v]_k + B̂ u_k + ĉ_{plane, stance_k},

by least squares over every usable step pair (:func:`hlip_jax.core.s2s_fit.pairs`, heading frame)
of the chosen runs.  One map for both planes keeps the planner's structure: the MPC, the
stepping law and the error sets act on the world's x and y planes with one (A, B), which
commutes with the heading's rotation only when both planes share it.  The constants ĉ are
written and reported (they are the systematic, side-alternating part of the residual) but not
planned with: the MPC's S2S map is linear.

Lifted to [c, p, v] with c⁺ = c + (p⁺ − p) + u (the COM moves by what it moved relative to the
stance foot plus the step):

    A3 = [[1, â11 − 1, â12], [0, Â]],   B3 = [1 + b̂1, B̂].

With the H-LIP's own Â = A2, B̂ = B2 this is :func:`hlip_jax.core.hlip.s2s_matrices` exactly.

The file (``.npz``) holds ``A`` (2, 2), ``B`` (2,), ``offset`` (2 planes, 2 stance, 2), ``rms``
(2,), ``n`` (pairs), ``rank``, and the H-LIP the runs walked with (``z0``, ``t_ssp``,
``t_dsp`` [m, s, s]): a model fitted at one cadence describes that cadence only.
"""

from __future__ import annotations

import io
import zipfile
from pathlib import Path
from typing import NamedTuple, Sequence

import numpy as np

from hlip_jax.core import s2s_fit

#: the largest model file read [bytes] (a model is a few hundred bytes)
MAX_BYTES = 1_000_000

#: the largest magnitude of a model file's numbers (its pair count ``n`` included)
MAX_VALUE = 1e9


class Model(NamedTuple):
    """An identified S2S model (module doc)."""
    A: np.ndarray         # (2, 2) Â on [p, v] [—, s; 1/s, —]
    B: np.ndarray         # (2,) B̂ on the step u [—; 1/s]
    offset: np.ndarray    # (2, 2, 2) ĉ per plane (sagittal, lateral), stance (L, R), [p, v]
    rms: np.ndarray       # (2,) RMS residual of the fit on [p, v] [m, m/s]
    n: int                # step pairs used
    rank: int             # rank of the regressor (7 = fully determined)
    cadence: tuple        # (z0 [m], t_ssp [s], t_dsp [s]) of the runs it was fitted on


def fit(log: dict, scenarios: Sequence[int], cadence: tuple, skip: int = 4) -> Model:
    """Least-squares model (module doc) from the step log ``log`` over ``scenarios``;
    ValueError with fewer than 7 usable pairs."""
    X, Y = s2s_fit.pairs(log, list(scenarios), skip)          # (n, 2, 5), (n, 2, 2)
    n = X.shape[0]
    if n < 7:
        raise ValueError(f"scenarios: {n} usable step pairs; the fit needs at least 7")
    rows = np.zeros((n, 2, 7))
    rows[:, :, :3] = X[:, :, :3]
    rows[:, 0, 3:5] = X[:, 0, 3:5]                            # sagittal stance constants
    rows[:, 1, 5:7] = X[:, 1, 3:5]                            # lateral stance constants
    R, T = rows.reshape(-1, 7), Y.reshape(-1, 2)
    coef, _, rank, _ = np.linalg.lstsq(R, T, rcond=None)       # (7, 2)
    rms = np.sqrt(np.mean((T - R @ coef) ** 2, axis=0))
    offset = np.stack([coef[3:5], coef[5:7]])                 # (plane, stance, [p, v])
    return Model(A=coef[:2].T, B=coef[2], offset=offset, rms=rms, n=n, rank=int(rank),
                 cadence=tuple(float(c) for c in cadence))


def residuals(log: dict, scenarios: Sequence[int], model: Model, skip: int = 4) -> np.ndarray:
    """Residuals (n, 2 planes, [p, v]) of the step pairs of ``scenarios`` under ``model``,
    its constants included [m; m/s]."""
    X, Y = s2s_fit.pairs(log, list(scenarios), skip)
    pred = X[:, :, :2] @ model.A.T + X[:, :, 2:3] * model.B
    pred = pred + np.einsum("nps,psk->npk", X[:, :, 3:5], model.offset)
    return Y - pred


def lifted(model: Model) -> tuple[np.ndarray, np.ndarray]:
    """(A3 (3, 3), B3 (3,)) on [c, p, v] (module doc)."""
    A, B = np.asarray(model.A, np.float64), np.asarray(model.B, np.float64)
    A3 = np.array([[1.0, A[0, 0] - 1.0, A[0, 1]], [0.0, *A[0]], [0.0, *A[1]]])
    return A3, np.array([1.0 + B[0], *B])


def to_bytes(model: Model) -> bytes:
    """The bytes of ``model``'s .npz file (for a caller that writes them atomically)."""
    buf = io.BytesIO()
    np.savez(buf, A=model.A, B=model.B, offset=model.offset, rms=model.rms,
             n=np.int64(model.n), rank=np.int64(model.rank),
             cadence=np.asarray(model.cadence, np.float64))
    return buf.getvalue()


def write(path, model: Model) -> Path:
    """Write ``model`` to ``path`` (.npz); returns the path."""
    path = Path(path)
    path.write_bytes(to_bytes(model))
    return path


_SHAPES = {"A": (2, 2), "B": (2,), "offset": (2, 2, 2), "rms": (2,), "n": (), "rank": (),
           "cadence": (3,)}


def read(path) -> Model:
    """The model in ``path``; ValueError (one line: what is wrong, what is allowed) for a file
    that is missing, not a regular file, too large, not a model, or holds non-finite values."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"{path!s}: not a readable file (write one with hlip-sweep identify)")
    if p.stat().st_size > MAX_BYTES:
        raise ValueError(f"{path!s}: {p.stat().st_size} bytes; a model file is at most "
                         f"{MAX_BYTES}")
    try:
        with np.load(p, allow_pickle=False) as z:
            arrays = {k: np.asarray(z[k]) for k in _SHAPES if k in z.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as err:
        raise ValueError(f"{path!s}: not a model file (.npz of hlip-sweep identify): "
                         f"{type(err).__name__}") from None
    for k, shape in _SHAPES.items():
        if k not in arrays or arrays[k].shape != shape:
            got = "missing" if k not in arrays else f"shape {arrays[k].shape}"
            raise ValueError(f"{path!s}: {k}: {got}; allowed: an array of shape {shape}")
        if arrays[k].dtype.kind not in "iuf":     # booleans, complex numbers, text: no model's
            raise ValueError(f"{path!s}: {k}: an array of {arrays[k].dtype}; allowed: real "
                             "numbers (integers or floats)")
        if not np.all(np.isfinite(arrays[k].astype(np.float64))):
            raise ValueError(f"{path!s}: {k}: non-finite values; allowed: finite numbers")
        if np.any(np.abs(arrays[k].astype(np.float64)) > MAX_VALUE):
            raise ValueError(f"{path!s}: {k}: values beyond ±{MAX_VALUE:g}; allowed: finite "
                             f"numbers within ±{MAX_VALUE:g} (a walking robot's S2S map is of "
                             "order 1; the closed loop computes in float32)")
    return Model(A=arrays["A"].astype(np.float64), B=arrays["B"].astype(np.float64),
                 offset=arrays["offset"].astype(np.float64), rms=arrays["rms"].astype(np.float64),
                 n=int(arrays["n"]), rank=int(arrays["rank"]),
                 cadence=tuple(float(c) for c in arrays["cadence"]))
