"""Results store: one directory per sweep run, written chunk by chunk so a run can resume.

Layout of ``DIR``::

    manifest.json           sweep file text, expanded configs, config hash, chunk size, package
                            versions, JAX backend/devices, git commit, start/end times, status
    chunks/chunk_00000.npz  the closed-loop Log of scenarios [0, batch), plus per-scenario
                            metrics (keys ``metric.<name>``) and ``index`` (global scenario ids)
    summary.csv             one row per scenario (see :data:`SUMMARY_METRICS`)

Every file is written atomically (temporary file in the same directory, then ``os.replace``), so
a killed run leaves only complete chunks.  Chunk ``i`` holds scenarios ``[i·batch, (i+1)·batch)``
of the expanded sweep; the last chunk is padded to ``batch`` with copies of its last scenario (so
every chunk has the same shape and one compile serves all) and the padding is dropped before
writing.  Chunks are deterministic: a scenario's seed comes from its config
(:mod:`hlip_jax.sweep`), and a chunk is always simulated with the same companions, so a resumed
run's arrays equal an uninterrupted run's byte for byte.

Resume: ``--resume`` requires the manifest's config hash (sha256 of the expanded configs and the
chunk size) to match; finished chunks (readable, with the expected ``index``) are skipped.

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

import csv
import dataclasses
import datetime as _dt
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
from importlib import metadata
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from hlip_jax import steplog
from hlip_jax import sweep as sweep_mod

__all__ = [
    "StoreError", "LOG_FIELDS", "SUMMARY_METRICS", "RunResult", "run_sweep", "chunk_ranges",
    "write_atomic", "save_npz_atomic", "read_manifest", "load_chunk", "load_log",
    "scenario_metrics", "write_summary", "read_summary", "chunk_files",
]

MANIFEST = "manifest.json"
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


def write_atomic(path, data: bytes | str) -> None:
    """Write ``data`` to ``path`` via a temporary file in the same directory and ``os.replace``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
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


def load_chunk(path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def _chunk_ok(path: Path, start: int, stop: int) -> bool:
    try:
        with np.load(path, allow_pickle=False) as z:
            idx = z["index"]
            return idx.shape == (stop - start,) and bool(np.all(idx == np.arange(start, stop)))
    except Exception:
        return False


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
        with np.load(f, allow_pickle=False) as z:
            idx = z["index"]
            sel = np.arange(idx.size) if want is None else np.flatnonzero(np.isin(idx, list(want)))
            if sel.size == 0:
                continue
            parts.append({k: z[k][sel] for k in z.files})
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


def _coverage_metrics(log: dict, s: int, mask: np.ndarray, du: np.ndarray) -> dict:
    """Per-plane coverage of [p, v] errors in the mRPI set (see module docstring); ``du``
    (K, 2): the scenario's foot-placement errors (:func:`_placement`)."""
    from hlip_jax import invariant as inv
    out = {}
    A, B, Kg, sl = error_model(log, s)
    x = np.asarray(log["x_robot"][s], np.float64)[:, :, sl]     # (K, 2, n)
    u = np.asarray(log["u_robot"][s], np.float64)
    e = np.asarray(log["e"][s], np.float64)[:, :, sl]
    # the error system's disturbance d = w + B δu: w from the robot's own S2S data (same
    # definition as the log's w), δu its foot-placement error
    w = steplog.s2s_residual(A, B, x, u)
    w = w + B[None, None, :] * du[:-1, :, None]
    frame = analysis_frame(log, s)
    if frame == "heading":
        Acl0 = A + np.outer(B, Kg[0])
        e, w = inv.heading_frame(np.where(mask[:, None, None], e, 0.0), w,
                                 np.asarray(log["ref_heading"][s], np.float64), Acl0)
    wmask = mask[1:] & mask[:-1]
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
            row["status"] = STATUS_NAMES.get(st, str(st))
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
      resume: skip chunks already stored (config hash must match).
      overwrite: discard an existing run in ``out_dir`` (its manifest, chunks, summary).
      simulate: ``configs -> Log`` (default :func:`hlip_jax.rollout.simulate`).
      max_chunks: stop after simulating this many chunks (interruptions, tests).
      with_coverage: compute the invariant-set coverage metrics per scenario (≈ 30 ms per
        scenario on a CPU core after a one-time JIT warm-up; False leaves those columns NaN,
        for very large sweeps).  Part of the config hash.
    Raises:
      StoreError: the directory holds another run (or a different config, on resume).
    """
    out = Path(out_dir)
    configs = list(sw.scenarios)
    n = len(configs)
    if n == 0:
        raise StoreError("the sweep expands to no scenarios")
    existing = (out / MANIFEST).is_file()
    old = read_manifest(out) if existing else None
    if batch is None:
        if resume and old is not None:
            batch = int(old["batch"])
        else:
            batch = default_batch(n)
    if isinstance(batch, bool) or not isinstance(batch, int) or batch < 1:
        raise StoreError(f"--batch: expected an integer >= 1, got {batch!r}")
    batch = min(batch, n)
    extra = {"batch": batch} if with_coverage else {"batch": batch, "coverage": False}
    chash = sweep_mod.config_hash(configs, extra)

    if existing and not (resume or overwrite):
        state = "complete" if old.get("status") == "complete" else "incomplete"
        raise StoreError(f"{out} already holds a run ({state}); pass --resume to continue it, "
                         f"--overwrite to discard it, or choose another --out")
    if existing and resume and old.get("config_hash") != chash:
        why = ("the chunk size differs (manifest batch "
               f"{old.get('batch')}, now {batch})" if old.get("batch") != batch
               else "the coverage setting differs (--no-coverage)"
               if old.get("with_coverage", True) != with_coverage
               else "the expanded sweep config differs")
        raise StoreError(f"refusing to resume {out}: {why}; config hash {chash[:12]} vs "
                         f"{str(old.get('config_hash'))[:12]} in {MANIFEST}")
    if existing and overwrite and not resume:
        for f in chunk_files(out):
            f.unlink()
        for name in (SUMMARY, MANIFEST):
            (out / name).unlink(missing_ok=True)
        old = None
    (out / CHUNK_DIR).mkdir(parents=True, exist_ok=True)

    ranges = chunk_ranges(n, batch)
    man = dict(old) if (resume and old) else {
        "format": 1,
        "sweep_name": sw.name,
        "sweep_file": sw.source,
        "sweep_text": sw.text,
        "description": sw.description,
        "axes": [{"fields": list(a.fields), "values": [list(v) for v in a.values],
                  "zipped": a.zipped} for a in sw.axes],
        "paths": list(sw.paths),
        "n_scenarios": n,
        "total_before_limit": sw.total,
        "batch": batch,
        "with_coverage": with_coverage,
        "n_chunks": len(ranges),
        "config_hash": chash,
        "configs": [sweep_mod.config_to_dict(c) for c in configs],
    }
    man.update({"versions": _versions(), "jax": _jax_info(), "git_commit": _git_commit(),
                "start_time": man.get("start_time") or _now(), "end_time": None,
                "status": "running"})
    man.setdefault("resumed_at", [])
    if resume and old:
        man["resumed_at"].append(_now())
    _write_manifest(out, man)

    sim = simulate if simulate is not None else _default_simulate(configs)
    t0 = time.monotonic()
    bar = Progress(n, sw.name, stream=stream, enabled=progress)
    done = sum(b - a for i, (a, b) in enumerate(ranges) if _chunk_ok(chunk_path(out, i), a, b))
    bar.update(done, "resuming" if done else "compiling")
    ran = skipped = 0
    try:
        ran, skipped, done = _run_chunks(out, configs, ranges, batch, sim, bar, done, max_chunks,
                                         with_coverage, man)
    except BaseException:
        # interrupted or failed: finished chunks stay; the manifest says the run is incomplete
        man["status"] = "incomplete"
        man["end_time"] = _now()
        man["seconds"] = man.get("seconds", 0.0) + (time.monotonic() - t0)
        _write_manifest(out, man)
        raise
    complete = all(_chunk_ok(chunk_path(out, i), a, b) for i, (a, b) in enumerate(ranges))
    man["status"] = "complete" if complete else "incomplete"
    man["end_time"] = _now()
    man["seconds"] = man.get("seconds", 0.0) + (time.monotonic() - t0)
    _write_manifest(out, man)
    if complete:
        write_summary(out)
    return RunResult(out, n, len(ranges), ran, skipped, complete, time.monotonic() - t0)


def _first_push(cfg) -> float | None:
    pushes = [p for p in cfg.disturbance.pushes if p.force > 0 and p.duration > 0]
    return min(p.time for p in pushes) if pushes else None


def _run_chunks(out, configs, ranges, batch, sim, bar, done, max_chunks, with_coverage, man):
    ran = skipped = 0
    for i, (a, b) in enumerate(ranges):
        p = chunk_path(out, i)
        if _chunk_ok(p, a, b):
            skipped += 1
            continue
        if max_chunks is not None and ran >= max_chunks:
            break
        chunk_cfgs = configs[a:b] + [configs[b - 1]] * (batch - (b - a))
        try:
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
        ran += 1
        done += b - a
        bar.update(done)
    return ran, skipped, done
