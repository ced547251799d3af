"""Results store: one directory per sweep run, written chunk by chunk so a run can resume.

Layout of ``DIR``::

    manifest.json           sweep file text, expanded configs, config hash, chunk size, package
                            versions, JAX backend/devices, git commit, start/end times, status
    chunks/chunk_00000.npz  the closed-loop Log of scenarios [0, batch), plus per-scenario
                            metrics (keys ``metric.<name>``) and ``index`` (global scenario ids)
    summary.csv             one row per scenario (see :data:`SUMMARY_METRICS`)
    coverage.csv            across-run coverage per (group, plane, W method): W and E from
                            training runs, coverage of the test runs' errors with a 95 %
                            Clopper–Pearson interval (:func:`write_coverage`,
                            :mod:`hlip_jax.coverage`)

Every file is written atomically (temporary file in the same directory, then ``os.replace``), so
a killed run leaves only complete chunks.  Chunk ``i`` holds scenarios ``[i·batch, (i+1)·batch)``
of the expanded sweep; the last chunk is padded to ``batch`` with copies of its last scenario (so
every chunk has the same shape and one compile serves all) and the padding is dropped before
writing.  Chunks are deterministic: a scenario's seed comes from its config
(:mod:`hlip_jax.sweep`), and a chunk is always simulated with the same companions, so a resumed
run's arrays equal an uninterrupted run's byte for byte.

Resume: ``--resume`` requires the manifest's config hash (sha256 of the expanded configs and the
chunk size) to match; finished chunks are skipped after a full check (:func:`chunk_problem`:
every array read, so every CRC-32 checked, every field present, every shape and the ``index``
right); a bad chunk is named and simulated again.

A run holds ``DIR/.lock`` (:func:`results_lock`, an ``flock`` naming the holder's pid) from
start to end, so a second run into the same directory fails at once; files are created with
the permissions the umask gives.  A run that finishes with a negative ``min_clearance`` has the
summary status ``collision`` (a failure), not ``ok``.

Metrics (per scenario, over valid pre-impact samples k, i.e. steps before any failure):

* ``rms_track_err``, ``max_track_err`` [m]: distance of the robot COM c_k (x–y) to the path,
  taken as the polyline through the reference positions r(t_j) of that scenario (the
  step-sampled path; chord error ≈ L²/(8R), ~3 mm for 0.2 m steps on a 2 m circle).
* ``rms_pos_err`` [m]: RMS of |c_k − r(t_k)| (time-indexed tracking error, includes lag).
* ``final_pos_err`` [m]: |c_k − r(t_k)| at the last valid step.
* ``emax_{x,y}_{c,p,v}``: max |e| per plane and component [m, m, m/s].
* ``place_err_rms`` [m]: RMS over valid steps of |δu_k|, the foot-placement error (executed
  step minus the stepping law's step u_HLIP + K e at the same pre-impact error;
  :func:`hlip_jax.invariant.placement_errors`); ``place_err_along`` [m]: its mean along the path
  heading (a systematic over- (> 0) or under-step).  0 on the H-LIP plant without step noise.
* ``cov_{x,y}_inner`` / ``cov_{x,y}_outer``: in-sample coverage bracket of the errors in the
  mRPI set E of ``e⁺ = (A + BK) e + d`` with W the box of that scenario's own samples of the
  error system's disturbance d = w + B δu (the S2S disturbance plus the foot-placement error;
  the errors obey this recursion exactly, so a run started at e = 0 is covered in-sample
  whenever its W contains the origin, and the held-out figure is the test); the state is
  [c, p, v] when the gain acts on c, else [p, v] (see :func:`error_model`).
* ``cov_{x,y}_heldout``: W and E from the first half of the steps, coverage (outer set) of the
  errors in the second half.
* The coverage and E-size metrics are per plane of the scenario's :func:`analysis_frame`:
  x = sagittal (along the path heading θ_d(t_k)) and y = lateral when the gain is the same in
  both planes (errors and disturbances rotated step by step,
  :func:`hlip_jax.invariant.heading_frame`), world x and y otherwise.  ``emax_*`` stay in the
  world frame.
* ``e_size_{x,y}``: volume of that in-sample E (outer set; [m²·m/s] on [c, p, v], [m·m/s] on
  [p, v]): the size of the error tube a gain earns on this run.
* ``push_peak_err`` [m]: largest COM-to-path distance from the first push's start on
  (NaN without a push).
* ``push_recovery_steps``: steps from the first pre-impact sample at or after the first push's
  start until the COM-to-path distance is within ``RECOVERY_TOL`` (0.15 m) and stays within it
  to the end of the run (0 if it never left; NaN without a push, after a failure, or when it is
  not back by the end).
* ``qp_failures``: valid steps whose MPC QP status is not 1 (solved).
* ``min_clearance`` [m]: min obstacle clearance over valid steps (inf without obstacles).
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import datetime as _dt
import fcntl
import functools
import io
import json
import math
import os
import platform
import subprocess
import sys
import tempfile
import time
import zipfile
import zlib
from importlib import metadata
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from hlip_jax import progress, steplog
from hlip_jax import sweep as sweep_mod

__all__ = [
    "StoreError", "LOG_FIELDS", "SUMMARY_METRICS", "RunResult", "run_sweep", "chunk_ranges",
    "write_atomic", "save_npz_atomic", "read_manifest", "load_chunk", "load_log",
    "scenario_metrics", "write_summary", "read_summary", "chunk_files", "write_coverage",
    "read_coverage", "coverage_rows", "results_lock", "chunk_problem", "check_chunks",
]

MANIFEST = "manifest.json"
LOCK = ".lock"              # held (flock) by the run writing the directory; names its pid
SUMMARY = "summary.csv"
CHUNK_DIR = "chunks"
STATUS_NAMES = steplog.STATUS_NAMES
LOG_FIELDS = steplog.FIELDS
STEP_FIELDS = steplog.STEP_FIELDS      # padded when chunks of different K are concatenated

SUMMARY_METRICS = (
    "steps", "rms_track_err", "max_track_err", "rms_pos_err", "final_pos_err",
    "emax_x_c", "emax_x_p", "emax_x_v", "emax_y_c", "emax_y_p", "emax_y_v",
    "cov_x_inner", "cov_x_outer", "cov_x_heldout", "cov_y_inner", "cov_y_outer", "cov_y_heldout",
    "qp_failures", "min_clearance", "e_size_x", "e_size_y", "push_peak_err",
    "push_recovery_steps", "place_err_rms", "place_err_along",
)

#: COM-to-path distance a pushed robot must return to and stay within [m] (the paper's push
#: acceptance: back within 0.15 m of the path)
RECOVERY_TOL = 0.15


class StoreError(RuntimeError):
    """A results directory cannot be used as asked (one clear line)."""


# --------------------------------------------------------------------------------------------
# atomic files


def _file_mode() -> int:
    """Permissions of a new file under the process umask (what ``open`` would give)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return 0o666 & ~mask


def write_atomic(path, data: bytes | str) -> None:
    """Write ``data`` to ``path`` via a temporary file in the same directory and ``os.replace``
    (permissions as the umask gives any new file, not ``mkstemp``'s 0600)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, _file_mode())
        with os.fdopen(fd, "wb") as fh:
            fh.write(data.encode() if isinstance(data, str) else data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def save_npz_atomic(path, arrays: dict) -> None:
    """``np.savez`` (uncompressed: deterministic bytes for equal arrays) written atomically."""
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    write_atomic(path, buf.getvalue())


# --------------------------------------------------------------------------------------------
# manifest


def _versions() -> dict:
    out = {"python": platform.python_version()}
    for pkg in ("hlip_jax", "jax", "jaxlib", "numpy", "scipy", "mujoco", "mujoco-mjx", "osqp",
                "matplotlib"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            pass
    return out


def _jax_info() -> dict:
    try:
        import jax
        return {"backend": jax.default_backend(),
                "devices": [str(d) for d in jax.devices()],
                "x64": bool(jax.config.jax_enable_x64)}
    except Exception as err:  # pragma: no cover - diagnostics only
        return {"backend": "unavailable", "error": str(err)}


def _git_commit() -> str | None:
    here = Path(__file__).resolve().parent
    try:
        r = subprocess.run(["git", "rev-parse", "HEAD"], cwd=here, capture_output=True,
                           text=True, timeout=5)
        if r.returncode != 0:
            return None
        commit = r.stdout.strip()
        d = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=here,
                           capture_output=True, text=True, timeout=5)
        return commit + ("-dirty" if d.returncode == 0 and d.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return None


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def read_manifest(out_dir) -> dict:
    """The manifest of a results directory (StoreError if absent or unreadable)."""
    p = Path(out_dir) / MANIFEST
    if not Path(out_dir).is_dir():
        raise StoreError(f"{out_dir}: results directory not found")
    if not p.is_file():
        raise StoreError(f"{out_dir}: not a results directory (no {MANIFEST})")
    try:
        return json.loads(p.read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise StoreError(f"{p}: unreadable manifest: {err}") from None


def _write_manifest(out_dir, man: dict) -> None:
    # indented for reading; compact for large sweeps (the configs dominate its size)
    indent = 1 if len(man.get("configs", ())) <= 1000 else None
    write_atomic(Path(out_dir) / MANIFEST, json.dumps(man, indent=indent) + "\n")


# --------------------------------------------------------------------------------------------
# chunks


def chunk_ranges(n: int, batch: int) -> list[tuple[int, int]]:
    """``[(start, stop), ...]`` covering ``range(n)`` in blocks of ``batch``."""
    return [(s, min(s + batch, n)) for s in range(0, n, batch)]


def chunk_path(out_dir, i: int) -> Path:
    return Path(out_dir) / CHUNK_DIR / f"chunk_{i:05d}.npz"


def chunk_files(out_dir) -> list[Path]:
    return sorted((Path(out_dir) / CHUNK_DIR).glob("chunk_*.npz"))


#: what reading a truncated or altered .npz raises (zipfile checks each member's CRC-32)
_CORRUPT = (OSError, EOFError, ValueError, KeyError, zipfile.BadZipFile, zlib.error)


def _read_npz(path) -> dict[str, np.ndarray]:
    """Every array of an .npz file, read in full (so every CRC-32 is checked); raises one of
    :data:`_CORRUPT` if it cannot."""
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def _corrupt_text(err: BaseException) -> str:
    return f"corrupt or unreadable chunk ({type(err).__name__}: {err})"


def load_chunk(path) -> dict[str, np.ndarray]:
    """Every array of a chunk file, read in full; StoreError naming the file if it is
    unreadable, truncated or fails a CRC check."""
    try:
        return _read_npz(path)
    except _CORRUPT as err:
        raise StoreError(f"{path}: {_corrupt_text(err)}; "
                         f"`hlip-sweep run SWEEP --out DIR --resume` simulates it again") from None


def chunk_problem(path, start: int, stop: int) -> str | None:
    """Why the chunk file ``path`` cannot stand for scenarios [start, stop), or None if it is
    sound: missing, unreadable or corrupt (every array is read, so every CRC is checked), a
    log field missing, an array whose leading size is not the chunk's scenario count, step
    arrays of unequal step counts, or an ``index`` other than start..stop-1."""
    path = Path(path)
    if not path.is_file():
        return "missing"
    try:
        z = _read_npz(path)
    except _CORRUPT as err:
        return _corrupt_text(err)
    missing = [k for k in (*LOG_FIELDS, "index") if k not in z]
    if missing:
        return f"lacks the array(s) {', '.join(missing)}"
    n = stop - start
    for k, v in z.items():
        if v.ndim == 0 or v.shape[0] != n:
            return f"array {k!r} has shape {v.shape}; expected {n} scenarios first"
    K = z["t"].shape[1] if z["t"].ndim > 1 else None
    for k in STEP_FIELDS:
        if k in z and (z[k].ndim < 2 or z[k].shape[1] != K):
            return f"array {k!r} has shape {z[k].shape}; expected {K} steps second"
    if not np.array_equal(z["index"], np.arange(start, stop)):
        return f"holds other scenarios (index {z['index'][:3].tolist()}...; expected {start}..{stop - 1})"
    return None


def check_chunks(out_dir) -> None:
    """Verify every stored chunk of a results directory fully (:func:`chunk_problem`) against
    the manifest's chunk size; StoreError naming the first bad chunk."""
    man = read_manifest(out_dir)
    n, batch = int(man.get("n_scenarios", 0)), int(man.get("batch", 0))
    for i, (a, b) in enumerate(chunk_ranges(n, batch) if n and batch else ()):
        p = chunk_path(out_dir, i)
        why = chunk_problem(p, a, b) if p.is_file() else None
        if why is not None:
            raise StoreError(f"{p}: {why}; `hlip-sweep run SWEEP --out {out_dir} --resume` "
                             f"simulates the chunk again")


def _log_to_arrays(log, n: int) -> dict[str, np.ndarray]:
    """Log NamedTuple (or dict) → dict of numpy arrays, first ``n`` scenarios."""
    d = log._asdict() if hasattr(log, "_asdict") else dict(log)
    out = {}
    for k in LOG_FIELDS:
        if k not in d:
            raise StoreError(f"closed-loop log lacks the field {k!r}")
        out[k] = np.ascontiguousarray(np.asarray(d[k])[:n])
    return out


def _pad_steps(a: np.ndarray, K: int, name: str) -> np.ndarray:
    if a.shape[1] == K:
        return a
    pad = [(0, 0)] * a.ndim
    pad[1] = (0, K - a.shape[1])
    if a.dtype == bool:
        fill = False
    elif np.issubdtype(a.dtype, np.floating):
        fill = np.inf if name == "clearance" else np.nan
    else:
        fill = 0
    return np.pad(a, pad, constant_values=fill)


def load_log(out_dir, indices: Sequence[int] | None = None) -> dict[str, np.ndarray]:
    """Concatenate the stored chunks (optionally only scenarios ``indices``, in that order).

    Chunks of different step counts K are padded (valid=False, NaN, clearance inf)."""
    files = chunk_files(out_dir)
    if not files:
        raise StoreError(f"{out_dir}: no chunks stored")
    want = None if indices is None else {int(i) for i in indices}
    parts = []
    for f in files:
        z = load_chunk(f)
        idx = z["index"]
        sel = np.arange(idx.size) if want is None else np.flatnonzero(np.isin(idx, list(want)))
        if sel.size == 0:
            continue
        parts.append({k: z[k][sel] for k in z})
    if not parts:
        raise StoreError(f"{out_dir}: none of the scenarios {sorted(want)} is stored")
    K = max(p["t"].shape[1] for p in parts)
    out = {k: np.concatenate([_pad_steps(p[k], K, k) if k in STEP_FIELDS else p[k]
                              for p in parts]) for k in parts[0]}
    if indices is not None:
        order = {int(i): j for j, i in enumerate(out["index"])}
        take = [order[int(i)] for i in indices if int(i) in order]
        out = {k: v[take] for k, v in out.items()}
    return out


# --------------------------------------------------------------------------------------------
# metrics


def _seg_dist(P: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Distance of each point P (n, 2) to the polyline through R (m, 2) [same units]."""
    if R.shape[0] == 1:
        return np.linalg.norm(P - R[0], axis=1)
    a, b = R[:-1], R[1:]                       # (m-1, 2)
    ab = b - a
    L2 = np.maximum(np.sum(ab * ab, axis=1), 1e-300)
    ap = P[:, None, :] - a[None]               # (n, m-1, 2)
    s = np.clip(np.sum(ap * ab[None], axis=2) / L2[None], 0.0, 1.0)
    d = ap - s[..., None] * ab[None]
    return np.sqrt(np.min(np.sum(d * d, axis=2), axis=1))


def error_model(log: dict, s: int):
    """(A, B, K, state slice) of the error dynamics e⁺ = (A + BK) e + w of scenario ``s``.

    A gain that acts on the global position c (non-zero c entry) closes the loop on the full
    [c, p, v] state; a gain on [p, v] only leaves c integrating (eigenvalue 1: no bounded
    invariant set in c), so the analysis then uses the 2-state [p, v] system."""
    A = np.asarray(log["A"][s], np.float64)
    B = np.asarray(log["B"][s], np.float64)
    K = np.asarray(log["K_gain"][s], np.float64)
    if K.shape[-1] == 3 and np.any(K[:, 0] != 0.0):
        return A, B, K, slice(0, 3)
    return A[1:, 1:], B[1:], K[:, -2:], slice(1, 3)


#: W boxes narrower than this half-width in an axis are widened to it [m or m/s]: a state the
#: disturbance never reaches (e.g. every axis of a noise-free float64 H-LIP run) would
#: otherwise give a flat W, for which no mRPI set with an interior exists.
W_MIN_HALFWIDTH = 1e-6


def _placement(log: dict, s: int) -> np.ndarray:
    """(K, 2) foot-placement errors δu_k of scenario ``s`` [m] (NaN where e is)."""
    from hlip_jax import invariant as inv
    return inv.placement_errors(log["u_robot"][s], log["u_hlip"][s], log["e"][s],
                                log["K_gain"][s])


def analysis_frame(log: dict, s: int) -> str:
    """The frame of scenario ``s``'s per-plane error analysis: "heading" (sagittal along the
    path heading θ_d(t_k), lateral to its left; :func:`hlip_jax.invariant.heading_frame`) when
    the stepping gain is the same in both planes, else "world" (x, y): a different gain per
    plane does not commute with the rotation."""
    K = np.asarray(log["K_gain"][s], np.float64)
    return "heading" if K.ndim == 1 or np.array_equal(K[0], K[1]) else "world"


def error_samples(log: dict, s: int, mask: np.ndarray, du: np.ndarray):
    """(A, B, K, e, w, wmask) of scenario ``s`` in its analysis frame and state
    (:func:`analysis_frame`, :func:`error_model`): errors e (K, 2, n), error-system
    disturbances w (K−1, 2, n) with e_{k+1} = (A + BK) e_k + w_k, and the mask of counted w
    (both ends in ``mask``); ``du`` (K, 2): the foot-placement errors (:func:`_placement`)."""
    from hlip_jax import invariant as inv
    A, B, Kg, sl = error_model(log, s)
    x = np.asarray(log["x_robot"][s], np.float64)[:, :, sl]     # (K, 2, n)
    u = np.asarray(log["u_robot"][s], np.float64)
    e = np.asarray(log["e"][s], np.float64)[:, :, sl]
    # the error system's disturbance d = w + B δu: w from the robot's own S2S data (same
    # definition as the log's w), δu its foot-placement error
    w = steplog.s2s_residual(A, B, x, u)
    w = w + B[None, None, :] * du[:-1, :, None]
    if analysis_frame(log, s) == "heading":
        Acl0 = A + np.outer(B, Kg[0])
        e, w = inv.heading_frame(np.where(mask[:, None, None], e, 0.0), w,
                                 np.asarray(log["ref_heading"][s], np.float64), Acl0)
    return A, B, Kg, e, w, mask[1:] & mask[:-1]


def _coverage_metrics(log: dict, s: int, mask: np.ndarray, du: np.ndarray) -> dict:
    """Per-plane coverage of [p, v] errors in the mRPI set (see module docstring); ``du``
    (K, 2): the scenario's foot-placement errors (:func:`_placement`)."""
    from hlip_jax import invariant as inv
    out = {}
    A, B, Kg, e, w, wmask = error_samples(log, s, mask, du)
    nK = int(mask.sum())
    half = nK // 2
    for p, plane in enumerate("xy"):
        keys = [f"cov_{plane}_inner", f"cov_{plane}_outer", f"cov_{plane}_heldout",
                f"e_size_{plane}"]
        for k in keys:
            out[k] = math.nan
        Acl = A + np.outer(B, Kg[p])
        if wmask.sum() < 1 or not np.all(np.abs(np.linalg.eigvals(Acl)) < 1 - 1e-9):
            continue
        try:
            W = inv.estimate_w(w[:, p], wmask, "box")
            E = inv.mrpi(Acl, W, min_halfwidth=W_MIN_HALFWIDTH)
            c = inv.coverage(E, e[:, p], mask)
            out[keys[0]], out[keys[1]] = c.inner, c.outer
            out[keys[3]] = float(E.volume())
            tr = wmask & (np.arange(wmask.size) + 1 < half)
            te = mask & (np.arange(mask.size) >= half)
            if tr.sum() >= 1 and te.sum() >= 1:
                Wt = inv.estimate_w(w[:, p], tr, "box")
                Et = inv.mrpi(Acl, Wt, min_halfwidth=W_MIN_HALFWIDTH)
                out[keys[2]] = inv.coverage(Et, e[:, p], te).outer
        except Exception:   # degenerate W (e.g. a single sample): leave NaN
            continue
    return out


def push_recovery(d_path: np.ndarray, t: np.ndarray, t_push: float, failed: bool,
                  tol: float = RECOVERY_TOL) -> tuple[float, float]:
    """(peak distance, steps to recover) after a push starting at ``t_push`` [s], from the
    COM-to-path distances ``d_path`` [m] at the valid pre-impact times ``t`` [s] (module
    docstring); ``failed``: the run ended in a failure (no recovery counted)."""
    after = np.flatnonzero(t >= t_push - 1e-9)
    if after.size == 0:
        return math.nan, math.nan
    d = d_path[after]
    peak = float(np.max(d))
    if failed:
        return peak, math.nan
    out = np.flatnonzero(d > tol)
    if out.size == 0:
        return peak, 0.0
    if out[-1] == d.size - 1:             # still outside at the end of the run
        return peak, math.nan
    return peak, float(out[-1] + 1)


def scenario_metrics(log: dict, s: int, with_coverage: bool = True,
                     push_time: float | None = None) -> dict:
    """Summary metrics of scenario ``s`` of a log dict (see the module docstring);
    ``push_time`` [s]: start of the scenario's first push (None: no push)."""
    mask = steplog.alive(log["valid"][s])       # steps before any failure
    n = int(mask.sum())
    m = {k: math.nan for k in SUMMARY_METRICS}
    m["steps"] = n
    m["qp_failures"] = int(np.sum(mask & (np.asarray(log["qp_status"][s]) != 1)))
    clr = np.asarray(log["clearance"][s], np.float64)[mask]
    m["min_clearance"] = float(np.min(clr)) if clr.size else math.inf
    if n == 0:
        return m
    c = np.asarray(log["x_robot"][s], np.float64)[mask][:, :, 0]   # (n, 2) COM x, y
    r = np.asarray(log["ref_pos"][s], np.float64)[mask]
    d_time = np.linalg.norm(c - r, axis=1)
    d_path = _seg_dist(c, r)
    m["rms_track_err"] = float(np.sqrt(np.mean(d_path ** 2)))
    m["max_track_err"] = float(np.max(d_path))
    m["rms_pos_err"] = float(np.sqrt(np.mean(d_time ** 2)))
    m["final_pos_err"] = float(d_time[-1])
    if push_time is not None:
        t = np.asarray(log["t_plant"][s], np.float64)[mask]        # pushes act on the plant clock
        m["push_peak_err"], m["push_recovery_steps"] = push_recovery(
            d_path, t, push_time, failed=int(np.asarray(log["status"][s])) != 0)
    du_all = _placement(log, s)                                       # (K, 2)
    du = du_all[mask]
    h = np.asarray(log["ref_heading"][s], np.float64)[mask]
    m["place_err_rms"] = float(np.sqrt(np.mean(np.sum(du ** 2, axis=1))))
    m["place_err_along"] = float(np.mean(np.cos(h) * du[:, 0] + np.sin(h) * du[:, 1]))
    e = np.abs(np.asarray(log["e"][s], np.float64)[mask])            # (n, 2, 3)
    for p, plane in enumerate("xy"):
        for j, comp in enumerate("cpv"):
            m[f"emax_{plane}_{comp}"] = float(np.max(e[:, p, j]))
    if with_coverage:
        m.update(_coverage_metrics(log, s, mask, du_all))
    return m


# --------------------------------------------------------------------------------------------
# summary.csv


def _cell(v) -> str:
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    return str(v)


def summary_columns(configs: list[dict]) -> list[str]:
    swept = []
    for c in configs:
        for k in c.get("swept", {}):
            if k != "path" and k not in swept:
                swept.append(k)
    return (["index", "name", "path", "shape", "plant", "seed"] + swept
            + ["status", "fail_step"] + list(SUMMARY_METRICS))


#: summary status of a run that finished but whose COM entered an obstacle's disc
STATUS_COLLISION = "collision"


def _status_name(st: int, z: dict, j: int) -> str:
    """The summary status of row ``j`` of a chunk: the closed loop's status, except that a run
    that finished with a negative ``min_clearance`` counts as a failure, "collision"."""
    name = STATUS_NAMES.get(st, str(st))
    clear = z.get("metric.min_clearance")
    if name == "ok" and clear is not None and float(clear[j]) < 0.0:
        return STATUS_COLLISION
    return name


def write_summary(out_dir) -> Path:
    """Write ``summary.csv`` from the manifest's configs and the stored chunk metrics."""
    man = read_manifest(out_dir)
    configs = man["configs"]
    cols = summary_columns(configs)
    rows: dict[int, dict] = {}
    for f in chunk_files(out_dir):
        z = load_chunk(f)
        for j, i in enumerate(z["index"]):
            i = int(i)
            cfg = configs[i]
            row = {"index": i, "name": cfg["name"], "path": cfg["swept"].get("path", ""),
                   "shape": cfg["path"]["shape"], "plant": cfg["plant"], "seed": cfg["seed"]}
            row.update({k: v for k, v in cfg["swept"].items() if k != "path"})
            st = int(z["status"][j])
            row["status"] = _status_name(st, z, j)
            row["fail_step"] = int(z["fail_step"][j])
            for k in SUMMARY_METRICS:
                if f"metric.{k}" not in z:      # a chunk written before the metric existed
                    row[k] = math.nan
                    continue
                v = z[f"metric.{k}"][j]
                row[k] = int(v) if k in ("steps", "qp_failures") else float(v)
            rows[i] = row
    buf = io.StringIO()
    wr = csv.writer(buf, lineterminator="\n")
    wr.writerow(cols)
    for i in sorted(rows):
        wr.writerow([_cell(rows[i].get(c, "")) for c in cols])
    p = Path(out_dir) / SUMMARY
    write_atomic(p, buf.getvalue())
    return p


def read_summary(out_dir) -> list[dict]:
    """Rows of ``summary.csv`` as dicts (numbers parsed where they parse)."""
    p = Path(out_dir) / SUMMARY
    if not p.is_file():
        raise StoreError(f"{out_dir}: no {SUMMARY}")
    return _read_csv(p)


def _read_csv(p: Path) -> list[dict]:
    rows = []
    with open(p, newline="") as fh:
        for r in csv.DictReader(fh):
            out = {}
            for k, v in r.items():
                try:
                    out[k] = int(v)
                except ValueError:
                    try:
                        out[k] = float(v)
                    except ValueError:
                        out[k] = v
            rows.append(out)
    return rows


# --------------------------------------------------------------------------------------------
# coverage.csv

COVERAGE = "coverage.csv"
#: level q of the split-conformal W box in coverage.csv (:mod:`hlip_jax.coverage`)
COVERAGE_Q = 0.9


def _push_masks(t: np.ndarray, cfg) -> tuple[np.ndarray, np.ndarray]:
    """(dpush (K−1,), epush (K,)) of a run with pre-impact plant times ``t`` (K,) [s]: steps
    whose interval [t_k, t_{k+1}] overlaps a push, and errors at or after the first push."""
    pushes = _active_pushes(cfg)
    dpush = np.zeros(t.size - 1, bool)
    for p in pushes:
        dpush |= (t[:-1] <= p.time + p.duration) & (t[1:] >= p.time)
    first = _first_push(cfg)
    epush = t >= first - 1e-9 if first is not None else np.zeros(t.size, bool)
    return dpush, epush


def _run_samples(z: dict, j: int, cfg):
    """(group key, A + BK per plane, frame, :class:`hlip_jax.coverage.RunSamples`) of row ``j``
    of a chunk, with the same errors and disturbances as the summary metrics."""
    from hlip_jax import coverage as cov
    mask = steplog.alive(z["valid"][j])
    A, B, Kg, e, w, wmask = error_samples(z, j, mask, _placement(z, j))
    frame = analysis_frame(z, j)
    ec = np.asarray(z["e"][j], np.float64)[:, :, 0]
    if frame == "heading":
        ec = steplog.to_heading_frame(ec, np.asarray(z["ref_heading"][j], np.float64))
    t = np.asarray(z["t_plant"][j], np.float64)
    dpush, epush = _push_masks(np.where(mask, t, np.inf), cfg)
    Acl = np.stack([A + np.outer(B, Kg[p]) for p in range(2)])
    key = (cfg.swept.get("path", ""), cfg.plant, frame,
           np.round(np.concatenate([A.ravel(), B.ravel(), Kg.ravel()]), 12).tobytes())
    return key, Acl, frame, cov.RunSamples(e, mask, epush & mask, w, wmask, dpush & wmask, ec)


def _group_label(cfgs: list) -> str:
    """The path (paths joined by '+'), then the swept fields (not the seed) that every run of
    the group shares."""
    first = cfgs[0].swept
    same = [f"{k}={v}" for k, v in first.items() if k not in ("path", "seed")
            and all(c.swept.get(k) == v for c in cfgs)]
    paths = "+".join(dict.fromkeys(str(c.swept.get("path", "")) for c in cfgs))
    return paths + ("/" + ",".join(same) if same else "")


def _coverage_groups(out_dir, field: str | None) -> list[dict]:
    """Runs with a valid step, grouped by path, plant, analysis frame and S2S model (A, B, K);
    the path is left out of the key when ``field`` is "path" (W from some paths, tested on
    the others).  Each group: A_cl, frame, runs, keys (replicate keys, or the values of
    ``field``), configs."""
    configs = read_manifest(out_dir)["configs"]
    groups: dict = {}
    for f in chunk_files(out_dir):
        z = load_chunk(f)
        for j, i in enumerate(z["index"]):
            cfg = sweep_mod.config_from_dict(configs[int(i)])
            if not steplog.alive(z["valid"][j]).any():
                continue
            key, Acl, frame, run = _run_samples(z, j, cfg)
            if field is not None and field not in cfg.swept:
                raise StoreError(f"coverage train_on: {field!r} is not a swept field of "
                                 f"scenario {cfg.name!r} (swept: {', '.join(cfg.swept)})")
            g = groups.setdefault(key[1:] if field == "path" else key,
                                  {"Acl": Acl, "frame": frame, "runs": [], "keys": [],
                                   "cfgs": []})
            g["runs"].append(run)
            g["keys"].append(cfg.swept[field] if field is not None
                             else cfg.swept.get("seed", int(i)))
            g["cfgs"].append(cfg)
    return list(groups.values())


def coverage_rows(out_dir, q: float = COVERAGE_Q, train_on: tuple | None = None) -> list[dict]:
    """coverage.csv rows of a results directory (:func:`hlip_jax.coverage.group_rows`) per
    group of :func:`_coverage_groups`.  Default split: replicates are the values of the swept
    ``seed`` (each run its own replicate when the seed is not swept).  ``train_on`` =
    (field, values), e.g. ("path", ["circle"]): W from the runs whose swept ``field`` (a grid
    field, or "path") takes one of ``values``, coverage on the others of the group."""
    from hlip_jax import coverage as cov
    if not 0.0 < q < 1.0:
        raise StoreError(f"coverage q: expected a level in (0, 1), got {q!r}")
    field, values = (None, None) if train_on is None else (train_on[0], list(train_on[1]))
    rows, seen = [], {}
    for g in _coverage_groups(out_dir, field):
        label = _group_label(g["cfgs"])
        seen[label] = seen.get(label, 0) + 1
        label += f" #{seen[label]}" if seen[label] > 1 else ""
        planes = ("sagittal", "lateral") if g["frame"] == "heading" else ("world x", "world y")
        split = (f"{field} in {values}" if field is not None else
                 "seed" if all("seed" in c.swept for c in g["cfgs"]) else "run")
        rows += cov.group_rows(label, g["Acl"], g["runs"], g["keys"], planes, q,
                               min_halfwidth=W_MIN_HALFWIDTH, split_name=split,
                               train_values=values)
    return rows


def write_coverage(out_dir, q: float = COVERAGE_Q, train_on: tuple | None = None) -> Path:
    """Write ``coverage.csv`` (columns :data:`hlip_jax.coverage.COLUMNS`) from the chunks
    (:func:`coverage_rows`: split level ``q`` and ``train_on``)."""
    from hlip_jax import coverage as cov
    buf = io.StringIO()
    wr = csv.writer(buf, lineterminator="\n")
    wr.writerow(cov.COLUMNS)
    for r in coverage_rows(out_dir, q, train_on):
        wr.writerow([_cell(r[c]) for c in cov.COLUMNS])
    p = Path(out_dir) / COVERAGE
    write_atomic(p, buf.getvalue())
    return p


def read_coverage(out_dir) -> list[dict]:
    """Rows of ``coverage.csv`` as dicts (numbers parsed where they parse); StoreError if
    absent."""
    p = Path(out_dir) / COVERAGE
    if not p.is_file():
        raise StoreError(f"{out_dir}: no {COVERAGE}")
    return _read_csv(p)


# --------------------------------------------------------------------------------------------
# running


@dataclasses.dataclass
class RunResult:
    out_dir: Path
    n_scenarios: int
    n_chunks: int
    chunks_run: int          # simulated in this call
    chunks_skipped: int      # already present (resume)
    complete: bool
    seconds: float


class Progress:
    """Plain-text progress on a stream: scenarios done/total, rate, ETA."""

    def __init__(self, total: int, label: str, stream=None, enabled: bool = True):
        self.total, self.label, self.enabled = total, label, enabled
        self.stream = stream if stream is not None else sys.stderr
        self.t0 = time.monotonic()
        self.done0 = None
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()

    def note(self, text: str) -> None:
        """One line of news (a bad chunk found on resume) on the stream, even when the
        progress itself is off: a repair is worth saying."""
        self.stream.write(f"[{self.label}] {text}\n")
        self.stream.flush()

    def update(self, done: int, note: str = "") -> None:
        if not self.enabled:
            return
        if self.done0 is None:
            self.done0, self.t0 = done, time.monotonic()
            rate_s, eta_s = "-", "-"
        else:
            dt = time.monotonic() - self.t0
            rate = (done - self.done0) / dt if dt > 0 else 0.0
            rate_s = f"{rate:.2f}/s" if rate else "-"
            eta_s = f"{(self.total - done) / rate:.0f}s" if rate > 0 else "-"
        pct = 100.0 * done / max(self.total, 1)
        msg = (f"[{self.label}] {done}/{self.total} scenarios ({pct:3.0f}%)  rate {rate_s}  "
               f"ETA {eta_s}{'  ' + note if note else ''}")
        if self.tty:
            self.stream.write("\r" + msg.ljust(79))
            if done >= self.total:
                self.stream.write("\n")
        else:
            self.stream.write(msg + "\n")
        self.stream.flush()


def default_batch(n: int, cap: int | None = None) -> int:
    """Chunk size for ``n`` scenarios: at most ``cap`` (16 on CPU, 1024 on accelerators) and
    balanced, ceil(n / ceil(n / cap)), so the padded last chunk wastes little (20 → 10 + 10)."""
    if cap is None:
        try:
            import jax
            cap = 16 if jax.default_backend() == "cpu" else 1024
        except Exception:   # pragma: no cover
            cap = 16
    n_chunks = max(1, math.ceil(n / cap))
    return max(1, math.ceil(n / n_chunks))


def _default_simulate(configs):
    """The closed loop with sweep-wide array shapes, so every chunk reuses one compile."""
    from hlip_jax import rollout
    shapes = rollout.shapes_of(configs)
    return functools.partial(rollout.simulate, shapes=shapes)


def run_sweep(sw: "sweep_mod.Sweep", out_dir, *, batch: int | None = None, resume: bool = False,
              overwrite: bool = False, simulate: Callable | None = None,
              max_chunks: int | None = None, progress: bool = True, stream=None,
              with_coverage: bool = True) -> RunResult:
    """Simulate every scenario of ``sw`` chunk by chunk into ``out_dir``.

    Args:
      sw: the validated sweep (:func:`hlip_jax.sweep.load_sweep`).
      out_dir: results directory (created).
      batch: scenarios per chunk (one ``simulate`` call); default :func:`default_batch`,
        capped at the number of scenarios.  On resume, the manifest's value unless given.
      resume: skip chunks already stored (config hash must match); every stored chunk is
        verified in full (:func:`chunk_problem`) and a bad one is simulated again, named on
        the progress stream.
      overwrite: discard an existing run in ``out_dir`` (its manifest, chunks, summary).
      simulate: ``configs -> Log`` (default :func:`hlip_jax.rollout.simulate`).
      max_chunks: stop after simulating this many chunks (interruptions, tests).
      with_coverage: compute the invariant-set coverage metrics per scenario (≈ 30 ms per
        scenario on a CPU core after a one-time JIT warm-up; False leaves those columns NaN,
        for very large sweeps).  Part of the config hash.
    Raises:
      StoreError: the directory holds another run (or a different config, on resume), another
        process is running into it (:func:`results_lock`), or it cannot be created or written.
    """
    out = Path(out_dir)
    configs = list(sw.scenarios)
    if not configs:
        raise StoreError("the sweep expands to no scenarios")
    with results_lock(out):
        return _run_locked(sw, out, configs, batch, resume, overwrite, simulate, max_chunks,
                           Progress(len(configs), sw.name, stream=stream, enabled=progress),
                           with_coverage)


@contextlib.contextmanager
def results_lock(out: Path):
    """Hold an exclusive lock on the results directory ``out`` (created) while a run writes it.

    The lock is an ``flock`` on ``out/.lock``, which records the holder's pid, host and start
    time; the kernel drops it when the holder exits, however it exits, so a lock left by a dead
    process is simply taken over.  Raises StoreError naming the holder if another process holds
    it, or naming ``--out`` if the directory cannot be created."""
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd = os.open(out / LOCK, os.O_RDWR | os.O_CREAT, 0o666)
    except OSError as err:
        raise StoreError(f"--out {out}: cannot create the results directory: "
                         f"{err.strerror or err}") from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 300, 0).decode(errors="replace").strip() or "another process"
            raise StoreError(f"--out {out}: another run is writing this directory ({holder}); "
                             f"wait for it to finish or choose another --out") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"pid {os.getpid()} on {platform.node()} since {_now()}\n".encode(), 0)
        yield out
    finally:
        os.close(fd)


def _check_existing(out: Path, old: dict | None, resume: bool, overwrite: bool, chash: str,
                    batch: int, with_coverage: bool) -> dict | None:
    """Refuse a run into a directory holding another one (or resuming a different config);
    with ``overwrite``, delete the old run.  Returns the manifest to continue, or None."""
    if old is not None and not (resume or overwrite):
        state = "complete" if old.get("status") == "complete" else "incomplete"
        raise StoreError(f"{out} already holds a run ({state}); pass --resume to continue it, "
                         f"--overwrite to discard it, or choose another --out")
    if old is not None and resume and old.get("config_hash") != chash:
        why = ("the chunk size differs (manifest batch "
               f"{old.get('batch')}, now {batch})" if old.get("batch") != batch
               else "the coverage setting differs (--no-coverage)"
               if old.get("with_coverage", True) != with_coverage
               else "the expanded sweep config differs")
        raise StoreError(f"refusing to resume {out}: {why}; config hash {chash[:12]} vs "
                         f"{str(old.get('config_hash'))[:12]} in {MANIFEST}")
    if old is not None and overwrite and not resume:
        for f in chunk_files(out):
            f.unlink()
        for name in (SUMMARY, COVERAGE, MANIFEST):
            (out / name).unlink(missing_ok=True)
        return None
    return old if resume else None


def _new_manifest(sw, configs, batch: int, n_chunks: int, chash: str, with_coverage: bool) -> dict:
    """The manifest of a fresh run (before the environment and status fields)."""
    return {
        "format": 1,
        "sweep_name": sw.name,
        "sweep_file": sw.source,
        "sweep_text": sw.text,
        "description": sw.description,
        "axes": [{"fields": list(a.fields), "values": [list(v) for v in a.values],
                  "zipped": a.zipped} for a in sw.axes],
        "paths": list(sw.paths),
        "n_scenarios": len(configs),
        "total_before_limit": sw.total,
        "batch": batch,
        "with_coverage": with_coverage,
        "n_chunks": n_chunks,
        "config_hash": chash,
        "configs": [sweep_mod.config_to_dict(c) for c in configs],
    }


def _run_locked(sw, out: Path, configs, batch, resume, overwrite, simulate, max_chunks, bar,
                with_coverage) -> RunResult:
    """:func:`run_sweep` with the directory lock held."""
    n = len(configs)
    old = read_manifest(out) if (out / MANIFEST).is_file() else None
    if batch is None:
        batch = int(old["batch"]) if (resume and old is not None) else default_batch(n)
    if isinstance(batch, bool) or not isinstance(batch, int) or batch < 1:
        raise StoreError(f"--batch: expected an integer >= 1, got {batch!r}")
    batch = min(batch, n)
    extra = {"batch": batch} if with_coverage else {"batch": batch, "coverage": False}
    chash = sweep_mod.config_hash(configs, extra)
    old = _check_existing(out, old, resume, overwrite, chash, batch, with_coverage)
    ranges = chunk_ranges(n, batch)
    man = dict(old) if old else _new_manifest(sw, configs, batch, len(ranges), chash,
                                              with_coverage)
    man.update({"versions": _versions(), "jax": _jax_info(), "git_commit": _git_commit(),
                "start_time": man.get("start_time") or _now(), "end_time": None,
                "status": "running"})
    man.setdefault("resumed_at", [])
    if old:
        man["resumed_at"].append(_now())
    try:
        (out / CHUNK_DIR).mkdir(parents=True, exist_ok=True)
        _write_manifest(out, man)
    except OSError as err:
        raise StoreError(f"--out {out}: cannot write the results directory: "
                         f"{err.strerror or err}") from None

    sim = simulate if simulate is not None else _default_simulate(configs)
    t0 = time.monotonic()
    good = _verify_stored(out, ranges, bar)
    done = sum(b - a for i, (a, b) in enumerate(ranges) if i in good)
    bar.update(done, "resuming" if done else "compiling")
    ran = skipped = 0
    try:
        ran, skipped, done = _run_chunks(out, configs, ranges, batch, sim, bar, done, max_chunks,
                                         with_coverage, good)
    except BaseException:
        # interrupted or failed: finished chunks stay; the manifest says the run is incomplete
        man.update(status="incomplete", end_time=_now(),
                   seconds=man.get("seconds", 0.0) + (time.monotonic() - t0))
        with contextlib.suppress(OSError):    # e.g. the disk is full: the first error counts
            _write_manifest(out, man)
        raise
    complete = len(good) == len(ranges)
    man.update(status="complete" if complete else "incomplete", end_time=_now(),
               seconds=man.get("seconds", 0.0) + (time.monotonic() - t0))
    _write_manifest(out, man)
    if complete:
        write_summary(out)
        write_coverage(out)
    return RunResult(out, n, len(ranges), ran, skipped, complete, time.monotonic() - t0)


def _verify_stored(out: Path, ranges, bar) -> set[int]:
    """Indices of the stored chunks that are sound (:func:`chunk_problem`); each stored but
    bad chunk is named on the progress stream and will be simulated again."""
    good = set()
    for i, (a, b) in enumerate(ranges):
        p = chunk_path(out, i)
        if not p.is_file():
            continue
        why = chunk_problem(p, a, b)
        if why is None:
            good.add(i)
        else:
            bar.note(f"{p.name}: {why}; simulating it again")
    return good


def _active_pushes(cfg) -> list:
    """The scenario's pushes that act (positive force and duration)."""
    return [p for p in cfg.disturbance.pushes if p.force > 0 and p.duration > 0]


def _first_push(cfg) -> float | None:
    pushes = _active_pushes(cfg)
    return min(p.time for p in pushes) if pushes else None


def _step_news(bar, done: int, chunk: int, n_chunks: int, every: float = 5.0):
    """A :mod:`hlip_jax.progress` listener: the walking step reached inside the running chunk,
    on the progress line at most every ``every`` seconds."""
    last = [-math.inf]

    def hear(k: int, n_steps: int) -> None:
        now = time.monotonic()
        if now - last[0] >= every or k == n_steps:
            last[0] = now
            bar.update(done, f"chunk {chunk + 1}/{n_chunks}: step {k}/{n_steps}")
    return hear


def _run_chunks(out, configs, ranges, batch, sim, bar, done, max_chunks, with_coverage, good):
    """Simulate and store every chunk not in ``good`` (verified stored chunk indices, which
    grows as chunks are written); returns (chunks run, chunks skipped, scenarios done)."""
    ran = skipped = 0
    for i, (a, b) in enumerate(ranges):
        p = chunk_path(out, i)
        if i in good:
            skipped += 1
            continue
        if max_chunks is not None and ran >= max_chunks:
            break
        chunk_cfgs = configs[a:b] + [configs[b - 1]] * (batch - (b - a))
        try:
            with progress.listening(_step_news(bar, done, i, len(ranges))):
                log = sim(chunk_cfgs)
        except (ImportError, NotImplementedError) as err:
            plants = sorted({c.plant for c in chunk_cfgs})
            raise StoreError(f"the closed loop for plant {', '.join(plants)} is not available: "
                             f"{type(err).__name__}: {err}") from None
        arrays = _log_to_arrays(log, b - a)
        arrays["index"] = np.arange(a, b, dtype=np.int64)
        mets = [scenario_metrics(arrays, s, with_coverage, _first_push(chunk_cfgs[s]))
                for s in range(b - a)]
        for k in SUMMARY_METRICS:
            arrays[f"metric.{k}"] = np.asarray([m[k] for m in mets], np.float64)
        save_npz_atomic(p, arrays)
        good.add(i)
        ran += 1
        done += b - a
        bar.update(done)
    return ran, skipped, done
