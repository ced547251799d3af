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
(:mod:`hlip_jax.sweepio.sweep`), and a chunk is always simulated with the same companions, so a resumed
run's arrays equal an uninterrupted run's byte for byte.

Resume: ``--resume`` requires the manifest's config hash (sha256 of the expanded configs and the
chunk size) to match; finished chunks are skipped after a full check (:func:`chunk_problem`:
every array read, so every CRC-32 checked, every field present, every shape and the ``index``
right); a bad chunk is named and simulated again.

Readers trust only what the run wrote: chunk files must be regular files named for one of the
run's chunks (a symbolic link, a FIFO, a ``chunks/`` folder that is a link or a stray
``chunk_*.npz`` is refused, :func:`check_chunks`), and ``summary.csv`` must agree with the
manifest (scenario cells) and with the chunks (status, fail step and metric cells,
:func:`read_summary`); a summary that does not is refused, naming its line and column, and is
rewritten from the chunks once deleted.

A run holds ``DIR/.lock`` (:func:`results_lock`, an ``flock`` naming the holder's pid) from
start to end, so a second run into the same directory fails at once; files are created with
the permissions the umask gives.  A run that finishes with a negative ``min_clearance`` has the
summary status ``collision`` (a failure), not ``ok``.

Per-scenario metrics: :mod:`hlip_jax.analysis.metrics`; the run loop that fills the directory:
:mod:`hlip_jax.sweepio.runner`.
"""

from __future__ import annotations

import contextlib
import csv
import datetime as _dt
import fcntl
import hashlib
import io
import json
import math
import os
import platform
import stat
import subprocess
import tempfile
import zipfile
import zlib
from importlib import metadata
from pathlib import Path
from typing import Sequence

import numpy as np

from hlip_jax.core import steplog
from hlip_jax.runtime import workers as workers_mod
from hlip_jax.analysis.metrics import SUMMARY_METRICS, push_windows
from hlip_jax.sweepio import sweep as sweep_mod

__all__ = [
    "StoreError", "OtherRunError", "LOG_FIELDS", "SUMMARY_METRICS", "chunk_ranges",
    "write_atomic", "save_npz_atomic", "save_figure_atomic", "read_manifest", "load_chunk", "load_log",
    "write_summary", "read_summary", "chunk_files", "write_coverage",
    "read_coverage", "coverage_rows", "write_coverage_rows", "coverage_sets", "analysis_settings",
    "disturbance_samples", "results_lock", "writer_of", "inside", "chunk_problem", "check_chunks",
    "stored_chunk_of",
]

MANIFEST = "manifest.json"
#: the private store of process N of a `--distributed` run, inside process 0's --out
PROCESS_STORE = ".process-{}"
LOCK = ".lock"              # held (flock) by the run writing the directory; names its pid
SUMMARY = "summary.csv"
CHUNK_DIR = "chunks"
TICK_DIR = "ticks"          # per-tick logs of the scenarios chosen with --ticks
STATUS_NAMES = steplog.STATUS_NAMES
LOG_FIELDS = steplog.FIELDS
STEP_FIELDS = steplog.STEP_FIELDS      # padded when chunks of different K are concatenated



class StoreError(RuntimeError):
    """A results directory cannot be used as asked (one clear line)."""


class OtherRunError(StoreError):
    """A derived file of a results directory (``coverage.csv``) written by another run, or
    naming none: the report rewrites it from the run's chunks; other readers refuse it."""


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
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as err:      # e.g. a read-only folder: named as the file, not the temporary
        raise type(err)(err.errno, f"{err.strerror}; cannot write this file: its folder must "
                        "be writable", str(path)) from None
    try:
        os.fchmod(fd, _file_mode())
        with os.fdopen(fd, "wb") as fh:
            fh.write(data.encode() if isinstance(data, str) else data)
            fh.flush()
            os.fsync(fh.fileno())
        try:
            os.replace(tmp, path)
        except IsADirectoryError as err:    # named as the file it stands for, not the temporary
            raise IsADirectoryError(err.errno, "a directory stands where this file is written; "
                                    "remove it", str(path)) from None
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def save_figure_atomic(fig, path, dpi: int) -> None:
    """``fig.savefig`` written atomically (:func:`write_atomic`): a figure file that is a
    symbolic link is replaced by the figure, its target never written."""
    buf = io.BytesIO()
    fig.savefig(buf, format=Path(path).suffix.lstrip(".") or "png", dpi=dpi)
    write_atomic(path, buf.getvalue())


def save_npz_atomic(path, arrays: dict) -> None:
    """``np.savez`` (uncompressed: deterministic bytes for equal arrays) written atomically."""
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    write_atomic(path, buf.getvalue())


# --------------------------------------------------------------------------------------------
# manifest


def package_versions() -> dict:
    """{package: version} of Python and the libraries whose versions a manifest records."""
    out = {"python": platform.python_version()}
    for pkg in ("hlip_jax", "jax", "jaxlib", "numpy", "scipy", "mujoco", "mujoco-mjx", "osqp",
                "matplotlib"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            pass
    return out


def jax_info() -> dict:
    """The JAX backend, devices and precision a manifest records (the error where JAX
    cannot start)."""
    try:
        import jax
        return {"backend": jax.default_backend(),
                "devices": [str(d) for d in jax.devices()],
                "x64": bool(jax.config.jax_enable_x64)}
    except Exception as err:  # pragma: no cover - diagnostics only
        return {"backend": "unavailable", "error": str(err)}


def git_commit() -> str | None:
    """The checkout's commit hash, or None outside a git checkout."""
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


def utc_now() -> str:
    """The time now in UTC, ISO 8601 to the second (the manifest's time stamps)."""
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def read_manifest(out_dir) -> dict:
    """The manifest of a results directory (StoreError if absent or unreadable)."""
    p = Path(out_dir) / MANIFEST
    if not Path(out_dir).is_dir():
        raise StoreError(f"{out_dir}: results directory not found")
    if not os.path.lexists(p):
        raise StoreError(f"{out_dir}: not a results directory (no {MANIFEST})")
    if not p.is_file() or p.stat().st_size > MANIFEST_MAX_BYTES:
        raise StoreError(f"{p}: not a manifest (a regular file of at most {MANIFEST_MAX_BYTES} "
                         "bytes)")
    try:
        man = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError) as err:     # JSONDecodeError and UnicodeDecodeError
        raise StoreError(f"{p}: unreadable manifest: {err}") from None
    except RecursionError:
        raise StoreError(f"{p}: unreadable manifest: arrays or objects nested too deeply "
                         "(a manifest nests about 4 deep); rerun the sweep with --overwrite") from None
    other = _other_version(man)
    if other is not None:
        raise StoreError(f"{p}: {other}")
    why = _manifest_problem(man)
    if why is not None:
        raise StoreError(f"{p}: damaged manifest: {why}; rerun the sweep with --overwrite")
    _check_identity(p, man)
    return man


#: manifests whose configs were found to match their config_hash: {(path, inode, size,
#: mtime): True}, so a command that reads the manifest many times hashes it once
_VERIFIED: dict = {}


def legacy_identity(batch: int, x64, with_coverage: bool) -> dict:
    """What a run's ``config_hash`` covers besides its configs, as every run records it: the
    chunk size, the precision and, when off, the per-scenario coverage; the whole of it for
    runs written before the manifest's ``run_identity`` (which adds the numerics, the layout
    and data files' SHA-256)."""
    return ({"batch": batch, "x64": x64} if with_coverage else
            {"batch": batch, "x64": x64, "coverage": False})


def layout_digest(layout: dict) -> str:
    """SHA-256 of a run's ``axes`` and ``paths`` (a manifest, or the sweep's layout): how the
    report groups and labels its results."""
    return sweep_mod.json_digest({"axes": layout.get("axes"), "paths": layout.get("paths")})


def _check_identity(p: Path, man: dict) -> None:
    """StoreError naming the manifest when its configs (with its ``run_identity``: the chunk
    size, precision, data files' SHA-256) do not give its ``config_hash``: a config edited by
    hand (a renamed scenario would relabel the stored results); and its ``axes`` and ``paths``
    against the layout digest the identity records.  A manifest without ``run_identity``
    (written before it, or with it removed) is checked against :func:`legacy_identity`."""
    extra, chash = man.get("run_identity"), man.get("config_hash")
    against = "its config_hash"
    if chash is None:           # deleted: the run id its chunks record stands in for it
        chash, against = chunks_run_id(p.parent, man), "the run id its chunks record"
        if chash is None:
            return
    if not isinstance(chash, str):
        raise StoreError(f"{p}: damaged manifest: 'config_hash' is {chash!r}; expected the "
                         "run's SHA-256 as a string; rerun the sweep with --overwrite")
    if not isinstance(extra, dict):         # written before run_identity (or it was removed)
        extra = legacy_identity(man["batch"], man.get("x64"), man.get("with_coverage", True))
    if extra.get("batch", man["batch"]) != man["batch"]:
        raise StoreError(f"{p}: damaged manifest: its batch {man['batch']} is not the run's "
                         f"chunk size ({extra.get('batch')}, in its run_identity; edited by "
                         "hand?), so its chunks would be read wrongly; nothing was removed")
    layout = extra.get("layout")
    if layout is not None and layout != layout_digest(man):
        raise StoreError(f"{p}: damaged manifest: its axes or paths do not match the run's "
                         "(edited by hand?), so the report would group and label the results "
                         "wrongly; rerun the sweep with --overwrite")
    st = p.stat()
    key = (str(p), st.st_ino, st.st_size, st.st_mtime_ns)
    if key in _VERIFIED:
        return
    if sweep_mod.dicts_hash(man["configs"], extra) != chash:
        for i in range(len(man["configs"])):        # a value not allowed: named as before
            stored_config(man["configs"], i, p.parent)
        raise StoreError(f"{p}: damaged manifest: its configs do not match {against} "
                         "(edited by hand, or of another run?), so the stored results cannot "
                         "be labelled; rerun the sweep with --overwrite")
    _VERIFIED[key] = True


def _other_version(man) -> str | None:
    """For a manifest of another version's format (an integer ``format`` other than
    :data:`MANIFEST_FORMAT`): a message that says so and leaves the results alone (read them
    with that version, or write this run elsewhere), or None."""
    fmt = man.get("format") if isinstance(man, dict) else None
    if isinstance(fmt, bool) or not isinstance(fmt, int) or fmt == MANIFEST_FORMAT:
        return None
    which = "a newer" if fmt > MANIFEST_FORMAT else "an older"
    return (f"results of {which} version of hlip_jax (manifest format {fmt}; this version reads "
            f"format {MANIFEST_FORMAT}): read them with that version, or give this run another "
            "--out (nothing here was changed)")


#: the largest manifest read [bytes] (1024 scenarios take about 2 MB)
MANIFEST_MAX_BYTES = 2_000_000_000


#: the keys of a manifest's scenario config that the summary and the report read, and their types
_CONFIG_KEYS = {"name": str, "plant": str, "seed": int, "swept": dict, "path": dict}


def _config_problem(c: dict) -> str | None:
    """What makes one scenario config of a manifest unreadable, or None."""
    for key, kind in _CONFIG_KEYS.items():
        if not isinstance(c.get(key), kind):
            what = {str: "a string", int: "an integer", dict: "a table"}[kind]
            return f"{key!r} is missing or not {what}"
    if "shape" not in c["path"]:
        return "'path' has no 'shape'"
    return None


#: the manifest format this version writes and reads (``format`` of manifest.json)
MANIFEST_FORMAT = 1


def _manifest_problem(man) -> str | None:
    """What makes a parsed manifest unusable, or None: not an object, of another format, or
    ``configs``, ``batch``, ``n_scenarios`` missing or inconsistent."""
    if not isinstance(man, dict):
        return f"expected a JSON object, got {type(man).__name__}"
    configs, batch, n = man.get("configs"), man.get("batch"), man.get("n_scenarios")
    if not isinstance(configs, list) or not all(isinstance(c, dict) for c in configs):
        return "'configs' is not a list of scenario objects"
    for key, v in (("batch", batch), ("n_scenarios", n)):
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            return f"{key!r} is {v!r}; expected an integer >= 1"
    if n != len(configs):
        return f"'n_scenarios' is {n} but {len(configs)} configs are listed"
    for i, c in enumerate(configs):
        bad = _config_problem(c)
        if bad:
            return f"configs[{i}]: {bad}"
    fmt = man.get("format")
    if isinstance(fmt, bool) or fmt != MANIFEST_FORMAT:
        return (f"'format' is {fmt!r}; this version reads format {MANIFEST_FORMAT} (results of "
                "another version of hlip_jax: read them with that version)")
    return None


def write_manifest(out_dir, man: dict) -> None:
    """Write ``man`` as DIR/manifest.json atomically (a reader never sees half a file)."""
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


#: the first bytes of a zip archive (an .npz file): a local file header, or an empty archive
ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")


def _read_npz(path) -> dict[str, np.ndarray]:
    """Every array of an .npz file, read in full (so every CRC-32 is checked); raises one of
    :data:`_CORRUPT` if it cannot."""
    with open(path, "rb") as fh:    # np.load reads any other file as a pickle
        if fh.read(4) not in ZIP_MAGIC:
            raise ValueError("not an .npz file: it does not begin as a zip archive does")
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def _corrupt_text(err: BaseException) -> str:
    return f"corrupt or unreadable chunk ({type(err).__name__}: {err})"


#: log fields added after results directories were first written → the value an older chunk
#: stands for (``anchor``: every run before it planned as the tube does), given the chunk
LATER_FIELDS = {"anchor": lambda z: np.zeros((z["index"].shape[0], 3))}


def _with_later_fields(z: dict) -> dict:
    for k, fill in LATER_FIELDS.items():
        if k not in z and "index" in z:
            z[k] = fill(z)
    return z


def _not_regular(path) -> str | None:
    """Why ``path`` cannot be a chunk file before it is opened, or None: missing, a symbolic
    link (a link to another run's chunk of the same identity would pass every other check;
    chunks are only ever written as regular files) or not a regular file (a FIFO would block
    the reader, a directory is no chunk)."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return "missing"
    except OSError as err:
        return f"unreadable ({err.strerror or err})"
    if stat.S_ISLNK(st.st_mode):
        return "a symbolic link, not a chunk file (chunks are regular files written by the run)"
    if not stat.S_ISREG(st.st_mode):
        return "not a regular file"
    return None


def load_chunk(path) -> dict[str, np.ndarray]:
    """Every array of a chunk file, read in full (a field of :data:`LATER_FIELDS` that an older
    chunk lacks is filled in); StoreError naming the file if it is not a regular file
    (:func:`_not_regular`), unreadable, truncated or fails a CRC check."""
    why = _not_regular(path)
    if why is not None:
        raise StoreError(f"{path}: {why}; `hlip-sweep run SWEEP --out DIR --resume` simulates "
                         "it again")
    try:
        return _with_later_fields(_read_npz(path))
    except _CORRUPT as err:
        raise StoreError(f"{path}: {_corrupt_text(err)}; "
                         f"`hlip-sweep run SWEEP --out DIR --resume` simulates it again") from None


#: a chunk's arrays of the closed loop's design (S2S model, stepping gain), finite in every run
DESIGNED_FIELDS = ("A", "B", "K_gain")

#: a chunk's array naming the run that wrote it (its manifest's ``config_hash``, per scenario)
RUN_ID = "run_id"


def chunk_problem(path, start: int, stop: int, run_id: str | None = None) -> str | None:
    """Why the chunk file ``path`` cannot stand for scenarios [start, stop) of the run
    ``run_id``, or None if it is sound: missing, unreadable or corrupt (every array is read,
    so every CRC is checked), a log field missing, an array whose leading size is not the
    chunk's scenario count, step arrays of unequal step counts, an ``index`` other than
    start..stop-1, a symbolic link or not a regular file (:func:`_not_regular`), or written
    by another run (its ``run_id``; chunks written before the
    field existed carry none and are not checked)."""
    path = Path(path)
    why = _not_regular(path)
    if why is not None:
        return why
    try:
        z = _read_npz(path)
    except _CORRUPT as err:
        return _corrupt_text(err)
    missing = [k for k in (*LOG_FIELDS, "index") if k not in z and k not in LATER_FIELDS]
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
    bad = next((k for k in DESIGNED_FIELDS if k in z and not np.all(np.isfinite(z[k]))), None)
    if bad is not None:
        return (f"array {bad!r} holds NaN or infinite values (a run's model and gain arrays "
                "are finite: checked before it is simulated)")
    if "stance" in z and not np.isin(z["stance"], (0, 1)).all():
        return "array 'stance' holds values other than 0 (left) and 1 (right)"
    if not np.array_equal(z["index"], np.arange(start, stop)):
        return f"holds other scenarios (index {z['index'][:3].tolist()}...; expected {start}..{stop - 1})"
    if run_id is not None and RUN_ID in z and set(map(str, z[RUN_ID])) != {run_id}:
        return (f"was written by another run (run id {str(z[RUN_ID][0])[:12]}, this "
                f"directory's {run_id[:12]})")
    return None


def check_chunks(out_dir) -> None:
    """Verify every stored chunk of a results directory fully (:func:`chunk_problem`) against
    the manifest's chunk size and run id; StoreError naming the first bad chunk, a ``chunks``
    folder that is a symbolic link (another run's chunks), or a file named like a chunk that
    is none of the run's (``chunk_00099.npz`` of a 4-chunk run, ``chunk_1.npz``: every reader
    of ``chunks/`` would take its scenarios).  A manifest without a run id (``config_hash``)
    is checked against the first chunk's, so that chunks of two runs are never mixed."""
    man = read_manifest(out_dir)
    ranges = _run_chunks_only(out_dir, man)
    run_id = man.get("config_hash")
    for i, (a, b) in enumerate(ranges):
        p = chunk_path(out_dir, i)
        if not os.path.lexists(p):
            continue
        if not isinstance(run_id, str):
            run_id = _run_id_of(p)
        why = chunk_problem(p, a, b, run_id)
        if why is not None:
            raise StoreError(f"{p}: {why}; `hlip-sweep run SWEEP --out {out_dir} --resume` "
                             f"simulates the chunk again")


def _run_chunks_only(out_dir, man: dict) -> list[tuple[int, int]]:
    """The chunk ranges of the run of manifest ``man``; StoreError if ``chunks`` is a symbolic
    link or holds a file named like a chunk that is none of the run's."""
    inside(out_dir, CHUNK_DIR)
    n, batch = int(man.get("n_scenarios", 0)), int(man.get("batch", 0))
    ranges = chunk_ranges(n, batch) if n and batch else []
    names = {chunk_path(out_dir, i).name for i in range(len(ranges))}
    stray = [f for f in chunk_files(out_dir) if f.name not in names]
    if stray:
        raise StoreError(f"{stray[0]}: not a chunk of this run ({len(ranges)} chunks, "
                         f"chunk_00000.npz to chunk_{max(len(ranges) - 1, 0):05d}.npz); "
                         "remove it")
    return ranges


def stored_chunk_of(out_dir) -> dict[int, Path]:
    """The chunk file that holds each stored scenario of a results directory, by scenario
    index (an unfinished run's scenarios not simulated yet are absent)."""
    ranges = _run_chunks_only(out_dir, read_manifest(out_dir))
    return {i: chunk_path(out_dir, k) for k, (a, b) in enumerate(ranges)
            if os.path.lexists(chunk_path(out_dir, k)) for i in range(a, b)}


def chunks_run_id(out_dir, man: dict) -> str | None:
    """The run id the first stored chunk of manifest ``man``'s run records that has one (None:
    no chunk stored, or none records it)."""
    n, batch = man.get("n_scenarios"), man.get("batch")
    for i in range(len(chunk_ranges(n, batch))):
        p = chunk_path(out_dir, i)
        if os.path.lexists(p):
            rid = _run_id_of(p)
            if isinstance(rid, str):
                return rid
    return None


def _run_id_of(path) -> str | None:
    """The run id a chunk file records (None: unreadable, or written before run ids)."""
    if _not_regular(path) is not None:
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            return str(z[RUN_ID][0]) if RUN_ID in z.files and z[RUN_ID].size else None
    except _CORRUPT:
        return None


def log_to_arrays(log, n: int) -> dict[str, np.ndarray]:
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
# summary.csv


def _cell(v) -> str:
    """A CSV cell: booleans lower-case, floats (numpy's too) as the shortest repr that reads
    back exactly, nan and ±inf by name."""
    if isinstance(v, (bool, np.bool_)):
        return str(bool(v)).lower()
    if isinstance(v, (float, np.floating)):
        v = float(v)
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


#: the summary columns that come from the chunks (the rest from the manifest's configs)
RESULT_COLUMNS = ("status", "fail_step", *SUMMARY_METRICS)


def _result_cells(z, j: int) -> dict:
    """The :data:`RESULT_COLUMNS` of row ``j`` of a chunk ``z`` (a dict or an open .npz)."""
    row = {"status": _status_name(int(z["status"][j]), z, j),
           "fail_step": int(z["fail_step"][j])}
    for k in SUMMARY_METRICS:
        if f"metric.{k}" not in z:      # a chunk written before the metric existed
            row[k] = math.nan
            continue
        v = z[f"metric.{k}"][j]
        row[k] = int(v) if k in ("steps", "qp_failures") else float(v)
    return row


def _stored_results(out_dir) -> dict[int, dict]:
    """scenario index → its :data:`RESULT_COLUMNS` as the stored chunks give them, reading
    only the chunks' ``index``, ``status``, ``fail_step`` and ``metric.*`` arrays."""
    out: dict[int, dict] = {}
    for f in chunk_files(out_dir):
        why = _not_regular(f)
        if why is not None:
            raise StoreError(f"{f}: {why}; `hlip-sweep run SWEEP --out DIR --resume` simulates "
                             "it again")
        try:
            with np.load(f, allow_pickle=False) as npz:
                z = {k: npz[k] for k in npz.files
                     if k in ("index", "status", "fail_step") or k.startswith("metric.")}
            for j, i in enumerate(z["index"]):
                out[int(i)] = _result_cells(z, j)
        except _CORRUPT as err:
            raise StoreError(f"{f}: {_corrupt_text(err)}; `hlip-sweep run SWEEP --out DIR "
                             "--resume` simulates it again") from None
    return out


def write_summary(out_dir) -> Path:
    """Write ``summary.csv`` from the manifest's configs and the stored chunk metrics
    (StoreError, nothing written, where ``chunks/`` holds a file that is none of the run's
    chunks: :func:`check_chunks`)."""
    man = read_manifest(out_dir)
    configs = man["configs"]
    cols = summary_columns(configs)
    rows: dict[int, dict] = {}
    _run_chunks_only(out_dir, man)
    for f in chunk_files(out_dir):
        z = load_chunk(f)
        for j, i in enumerate(z["index"]):
            i = int(i)
            cfg = configs[i]
            row = {"index": i, "name": cfg["name"], "path": cfg["swept"].get("path", ""),
                   "shape": cfg["path"]["shape"], "plant": cfg["plant"], "seed": cfg["seed"]}
            row.update({k: v for k, v in cfg["swept"].items() if k != "path"})
            row.update(_result_cells(z, j))
            rows[i] = row
    buf = io.StringIO()
    wr = csv.writer(buf, lineterminator="\n")
    wr.writerow(cols)
    for i in sorted(rows):
        wr.writerow([_cell(rows[i].get(c, "")) for c in cols])
    p = Path(out_dir) / SUMMARY
    write_atomic(p, buf.getvalue())
    return p


def read_summary(out_dir, man: dict | None = None) -> list[dict]:
    """Rows of ``summary.csv`` as dicts (numbers parsed where they parse), bound to the run
    that made them: StoreError where a row's scenario cells (name, path, shape, plant, seed,
    swept fields) differ from the manifest's config of its index (``man``, read if not given),
    or its result cells (:data:`RESULT_COLUMNS`: status, fail step, metrics) from what the
    stored chunks say, or one of those columns is missing: rows edited, swapped or of
    another run.  The message names the line and the column and says to delete the file
    (``report`` rewrites it from the chunks)."""
    p = Path(out_dir) / SUMMARY
    if not p.is_file():
        raise StoreError(f"{out_dir}: no {SUMMARY}")
    try:
        head, rows = _read_csv_table(p)
    except (csv.Error, UnicodeDecodeError, OSError) as err:
        raise StoreError(f"{p}: unreadable ({err}); delete it and run `hlip-sweep report` again "
                         "to rewrite it from the chunks") from None
    man = man if man is not None else read_manifest(out_dir)
    configs = man["configs"]
    _run_chunks_only(out_dir, man)
    stored = _stored_results(out_dir)
    extra = [c for c in head if c not in summary_columns(configs)]
    if extra:
        _refuse_summary(p, 1, f"column {_printable_cell(extra[0])} is not a summary column")
    for n, r in enumerate(rows, start=2):
        if None in r or None in r.values():     # DictReader: extra cells, missing cells
            cells = sum(v is not None for k, v in r.items() if k is not None) + len(r.get(None) or ())
            _refuse_summary(p, n, f"{cells} cells for the header's {len(head)} columns")
        bad = _summary_row_mismatch(r, configs) or _result_mismatch(r, stored)
        if bad:
            _refuse_summary(p, n, bad)
    return rows


def _refuse_summary(p: Path, line: int, what: str):
    raise StoreError(f"{p}: line {line}: {what} (edited, swapped or of another run); delete "
                     f"it and run "
                     f"`hlip-sweep report` again to rewrite it from the chunks")


def _result_mismatch(row: dict, stored: dict[int, dict]) -> str:
    """What in the result cells of summary row ``row`` (its index already checked) differs
    from the stored chunks ('' if nothing)."""
    i = row["index"]
    if i not in stored:
        return f"scenario {i} has no stored chunk"
    for k, v in stored[i].items():
        if k not in row:
            return f"column {k!r} is missing"
        if _cell(row[k]) != _cell(v) and not _same_number(row[k], v):
            return (f"column {k!r} of scenario {i} is {_printable_cell(row[k])}, the chunks "
                    f"say {_printable_cell(v)}")
    return ""


def _summary_row_mismatch(row: dict, configs: list) -> str:
    """What in summary row ``row`` differs from its scenario's config ('' if nothing)."""
    i = row.get("index")
    if not isinstance(i, int) or not 0 <= i < len(configs):
        return f"index {_printable_cell(i)} is not a scenario index (0..{len(configs) - 1})"
    cfg = configs[i]
    want = {"name": cfg["name"], "path": cfg["swept"].get("path", ""),
            "shape": cfg["path"]["shape"], "plant": cfg["plant"], "seed": cfg["seed"]}
    want.update({k: v for k, v in cfg["swept"].items() if k != "path"})
    for k, v in want.items():
        if k in row and _cell(row[k]) != _cell(v) and not _same_number(row[k], v):
            return (f"column {k!r} of scenario {i} is {_printable_cell(row[k])}, the manifest "
                    f"says {_printable_cell(v)}")
    return ""


def _same_number(a, b) -> bool:
    try:
        return float(a) == float(b)
    except (TypeError, ValueError):
        return False


def _printable_cell(v) -> str:
    """A summary cell for a message: printable, at most 60 characters."""
    t = sweep_mod.printable(_cell(v))
    return repr(t if len(t) <= 60 else t[:57] + "...")


def _read_csv(p: Path) -> list[dict]:
    return _read_csv_table(p)[1]


def _read_csv_table(p: Path) -> tuple[list[str], list[dict]]:
    """(the header, the rows as dicts with numbers parsed where they parse) of a CSV file."""
    rows = []
    # utf-8-sig: a byte-order mark (a spreadsheet's save) is not part of the first column name
    with open(p, newline="", encoding="utf-8-sig") as fh:
        reader = csv.DictReader(fh)
        for r in reader:
            out = {}
            for k, v in r.items():
                if not isinstance(v, str):      # a short row (None) or extra cells (a list)
                    out[k] = v
                    continue
                try:
                    out[k] = int(v)
                except ValueError:
                    try:
                        out[k] = float(v)
                    except ValueError:
                        out[k] = v
            rows.append(out)
        head = list(reader.fieldnames or [])
    return head, rows


# --------------------------------------------------------------------------------------------
# coverage.csv

COVERAGE = "coverage.csv"


def _group_key(z: dict, j: int, cfg, frame: str) -> tuple:
    """Runs analysed together share the path, plant, analysis frame and S2S model (A, B, K)."""
    mats = [np.asarray(z[k][j], np.float64).ravel() for k in ("A", "B", "K_gain", "anchor")]
    return (cfg.swept.get("path", ""), cfg.plant, frame, np.round(np.concatenate(mats), 12).tobytes())


def _group_label(cfgs: list, held: str) -> str:
    """The path (paths joined by '+'), then the swept fields (neither the seed nor the held-out
    field) that every run of the group shares."""
    first = cfgs[0].swept
    same = [f"{k}={v}" for k, v in first.items() if k not in ("path", "seed", held)
            and all(c.swept.get(k) == v for c in cfgs)]
    paths = "+".join(dict.fromkeys(str(c.swept.get("path", "")) for c in cfgs))
    return paths + ("/" + ",".join(same) if same else "")


def analysed_runs(out_dir, warmup: int, chosen=None):
    """(scenario index, config, group key, A + BK per plane, frame,
    :class:`hlip_jax.analysis.runs.RunErrors`) of every run with a valid step, in chunk
    order; ``chosen``: scenario indices to keep (None: all)."""
    from hlip_jax.analysis import runs
    chosen = None if chosen is None else set(int(i) for i in chosen)
    configs = read_manifest(out_dir)["configs"]
    for f in chunk_files(out_dir):
        z = load_chunk(f)
        for j, i in enumerate(z["index"]):
            if (chosen is not None and int(i) not in chosen) or not steplog.alive(z["valid"][j]).any():
                continue
            cfg = stored_config(configs, int(i), out_dir)
            Acl, frame, run = runs.run_errors(z, j, push_windows(cfg), warmup)
            yield int(i), cfg, _group_key(z, j, cfg, frame), Acl, frame, run


def stored_config(configs: list, i: int, out_dir):
    """Scenario ``i`` of a manifest's ``configs`` as a validated config; StoreError naming the
    manifest of ``out_dir`` where a stored value is not allowed (edited by hand)."""
    try:
        return sweep_mod.config_from_dict(configs[i])
    except sweep_mod.SweepError as err:
        raise StoreError(f"{Path(out_dir) / MANIFEST}: damaged manifest: configs[{i}]: {err}; "
                         "rerun the sweep with --overwrite") from None


def _groups(runs_list, field: str) -> list[dict]:
    """Runs grouped by :func:`_group_key` (without the path when ``field`` is "path": W from
    some paths, tested on the others); each group: Acl, frame, runs, keys (the runs' values of
    ``field``; None where it is not swept), cfgs."""
    groups: dict = {}
    for i, cfg, key, Acl, frame, run in runs_list:
        g = groups.setdefault(key[1:] if field == "path" else key,
                              {"Acl": Acl, "frame": frame, "runs": [], "keys": [], "cfgs": []})
        g["runs"].append(run)
        g["keys"].append(cfg.swept.get(field))
        g["cfgs"].append(cfg)
    return list(groups.values())


def disturbance_samples(out_dir, chosen=None, warmup: int | None = None):
    """The error-system disturbances d of a results directory's runs, pooled per plane, as
    coverage.csv's W sees them (the kept disturbances, :mod:`hlip_jax.analysis.masks`):
    (frame, [(N, n) plane 1, (N, n) plane 2], runs used).  ``chosen``: scenario indices (None:
    all); ``warmup``: the directory's analysis setting when None.  StoreError when the runs are
    in different analysis frames or none is left."""
    warmup = analysis_settings(out_dir).warmup if warmup is None else warmup
    frames, parts, n_runs = set(), ([], []), 0
    for *_, frame, run in analysed_runs(out_dir, warmup, chosen):
        frames.add(frame)
        for p in (0, 1):
            parts[p].append(run.kept_d(p))
        n_runs += 1
    if len(frames) > 1:
        raise StoreError(f"the runs are analysed in frames {sorted(frames)}; choose runs of one "
                         "frame (one gain in both planes gives the heading frame)")
    if not n_runs or not all(np.concatenate(p).size for p in parts):
        raise StoreError("no disturbance samples: no chosen run has two kept steps")
    return frames.pop(), [np.concatenate(p) for p in parts], n_runs


def analysis_settings(out_dir):
    """The results directory's :class:`hlip_jax.analysis.settings.AnalysisConfig` (from its
    manifest; the defaults for a directory written before the sweep's ``[analysis]`` table)."""
    from hlip_jax.analysis import settings
    raw = read_manifest(out_dir).get("analysis")
    try:
        return settings.from_dict(raw, "analysis")
    except ValueError as err:
        raise StoreError(f"{Path(out_dir) / MANIFEST}: damaged manifest: {err}; remove its "
                         "'analysis' entry to use the defaults, or rerun the sweep with "
                         "--overwrite") from None


#: runs per worker process of :func:`coverage_rows` (below two workers' worth: in-process)
COVERAGE_RUNS_PER_WORKER = 128


def coverage_rows(out_dir, settings=None, train_on: tuple | None = None,
                  workers: int | None = None) -> list[dict]:
    """coverage.csv rows of a results directory (:func:`hlip_jax.analysis.coverage.group_rows`)
    for every split of ``settings`` (the directory's own when None), per group.  ``train_on`` =
    (field, values), e.g. ("path", ["circle"]): one value split instead, W from the runs whose
    swept ``field`` takes one of ``values``, coverage on the others of the group.  The groups
    go to ``workers`` processes (default: one per :data:`COVERAGE_RUNS_PER_WORKER` runs, at
    most one per CPU; :func:`hlip_jax.runtime.workers.starmap`), with the same rows as in one."""
    from hlip_jax.analysis import coverage as cov, splits
    settings = analysis_settings(out_dir) if settings is None else settings
    runs_list = list(analysed_runs(out_dir, settings.warmup))
    if train_on is not None:
        field = train_on[0]
        missing = [cfg.name for _, cfg, *_ in runs_list if field not in cfg.swept]
        if missing:
            raise StoreError(f"coverage train_on: {field!r} is not a swept field of scenario "
                             f"{missing[0]!r}")
        todo = [(splits.Split(f"{field} in {list(train_on[1])}", field,
                              "test runs take other values of " + field), list(train_on[1]))]
    else:
        todo = [(splits.split(n), None) for n in settings.splits]
    calls = []
    for sp, values in todo:
        seen: dict = {}
        for g in _groups(runs_list, sp.field):
            label = _group_label(g["cfgs"], sp.field)
            seen[label] = seen.get(label, 0) + 1
            label += f" #{seen[label]}" if seen[label] > 1 else ""
            if values is None and len({k for k in g["keys"] if k is not None}) < 2:
                continue            # the field is not varied in this group: nothing held out
            calls.append((label, g["Acl"], g["runs"], g["keys"], cov.PLANES[g["frame"]], sp,
                          settings.q, settings.methods, values))
    if workers is None:
        workers = workers_mod.count(len(runs_list), COVERAGE_RUNS_PER_WORKER)
    return [r for part in workers_mod.starmap(cov.group_rows, calls, workers) for r in part]


def coverage_sets(out_dir, split: str = "seed", settings=None) -> list[tuple]:
    """(group label, frame, :func:`hlip_jax.analysis.coverage.fitted_sets`) of every group in
    which ``split``'s field takes two or more values: the sets the report draws."""
    from hlip_jax.analysis import coverage as cov, splits
    settings = analysis_settings(out_dir) if settings is None else settings
    sp = splits.split(split)
    out = []
    for g in _groups(list(analysed_runs(out_dir, settings.warmup)), sp.field):
        if len({k for k in g["keys"] if k is not None}) < 2:
            continue
        try:
            sets_ = cov.fitted_sets(g["Acl"], g["runs"], g["keys"], settings.q)
        except ValueError:          # no kept disturbance, an unstable gain: nothing to draw
            continue
        out.append((_group_label(g["cfgs"], sp.field), g["frame"], sets_))
    return out


def write_coverage(out_dir, settings=None, train_on: tuple | None = None) -> Path:
    """Write ``coverage.csv`` (columns :data:`hlip_jax.analysis.coverage.COLUMNS`) from the
    chunks (:func:`coverage_rows`)."""
    return write_coverage_rows(out_dir, coverage_rows(out_dir, settings, train_on))


#: the column of coverage.csv naming the run its rows come from (the manifest's config_hash)
COVERAGE_RUN = "run_id"


def _run_id(out_dir) -> str:
    """The run identity of a results directory as coverage.csv writes it: ``sha256:`` and its
    manifest's ``config_hash`` (never read as a number); "" where it has no manifest, or one
    without a run id."""
    if not os.path.lexists(Path(out_dir) / MANIFEST):
        return ""
    run_id = read_manifest(out_dir).get("config_hash")
    return f"sha256:{run_id}" if isinstance(run_id, str) else ""


def row_check(run_id: str, cells: list[str]) -> str:
    """The check of one coverage.csv row that its run cell records after ``#``: 16 hex digits
    of the SHA-256 of the run id and the row's other cells as written (a number edited by
    hand, the run id kept, no longer matches)."""
    text = "\x1f".join([run_id, *cells])
    return hashlib.sha256(text.encode("utf-8", "surrogatepass")).hexdigest()[:16]


def _edited_row(p: Path, run_id: str) -> int | None:
    """The line of ``coverage.csv`` ``p`` whose cells no longer match the check its run cell
    records (:func:`row_check`), or None; a row without a check is such a line too."""
    with open(p, newline="", encoding="utf-8-sig") as fh:
        table = list(csv.reader(fh))
    k = table[0].index(COVERAGE_RUN)
    for line, cells in enumerate(table[1:], start=2):
        if len(cells) != len(table[0]):
            return line
        rid, _, check = cells[k].partition("#")
        if check != row_check(rid, cells[:k] + cells[k + 1:]):
            return line
    return None


def write_coverage_rows(out_dir, rows: list[dict]) -> Path:
    """Write ``rows`` (of :func:`coverage_rows`) as the directory's ``coverage.csv``; each row
    names the run it comes from (:data:`COVERAGE_RUN`), which :func:`read_coverage` checks."""
    from hlip_jax.analysis import coverage as cov
    run_id = _run_id(out_dir)
    buf = io.StringIO()
    wr = csv.writer(buf, lineterminator="\n")
    wr.writerow(cov.COLUMNS + (COVERAGE_RUN,))
    for r in rows:
        cells = [_cell(r[c]) for c in cov.COLUMNS]
        wr.writerow(cells + [f"{run_id}#{row_check(run_id, cells)}" if run_id else ""])
    p = Path(out_dir) / COVERAGE
    write_atomic(p, buf.getvalue())
    return p


def read_coverage(out_dir) -> list[dict]:
    """Rows of ``coverage.csv`` as dicts (numbers parsed where they parse); StoreError if
    absent."""
    p = Path(out_dir) / COVERAGE
    if not p.is_file():
        if os.path.lexists(p):      # a directory, a device, a link to one: never opened
            raise StoreError(f"{p}: not a regular file (a coverage table is a CSV file); "
                             f"rewrite it with `hlip-sweep coverage {out_dir}`")
        raise StoreError(f"{out_dir}: no {COVERAGE}")
    try:
        head, rows = _read_csv_table(p)
    except (csv.Error, UnicodeDecodeError, OSError) as err:
        raise StoreError(f"{p}: unreadable ({err}); rewrite it with `hlip-sweep coverage "
                         f"{out_dir}`") from None
    missing = [c for c in COVERAGE_KEYS if c not in head]
    if missing:
        raise StoreError(f"{p}: not a coverage table of this version (no column "
                         f"{missing[0]!r}); rewrite it with `hlip-sweep coverage {out_dir}`")
    run_id = _run_id(out_dir)
    if run_id and COVERAGE_RUN not in head:
        raise OtherRunError(f"{p}: names no run (no column {COVERAGE_RUN!r}: written by an older "
                            f"version, or not by this run); rewrite it with `hlip-sweep coverage "
                            f"{out_dir}`")
    ids = [str(r.get(COVERAGE_RUN, "")).partition("#")[0] for r in rows]
    other = next((i for i in ids if i != run_id), None) if run_id else None
    if other is not None:
        raise OtherRunError(f"{p}: written by another run (run id {other[7:19] or 'none'}, this "
                            f"run's {run_id[7:19]}: copied from elsewhere?); rewrite it with "
                            f"`hlip-sweep coverage {out_dir}`")
    line = _edited_row(p, run_id) if run_id else None
    if line is not None:
        raise OtherRunError(f"{p}: line {line}: its cells do not match the check its "
                            f"{COVERAGE_RUN!r} cell records (edited by hand, or written by an "
                            f"older version); rewrite it with `hlip-sweep coverage {out_dir}`")
    for r, i in zip(rows, ids):     # the run id alone, as before the check was added
        if COVERAGE_RUN in r:
            r[COVERAGE_RUN] = i
    return rows


#: the columns every reader of coverage.csv needs
COVERAGE_KEYS = ("group", "plane", "w_method", "level")




# --------------------------------------------------------------------------------------------
# the lock of a run


def inside(out, name: str) -> Path:
    """``out / name``, refused (StoreError) when it is a symbolic link: a run never writes
    through a link out of its results directory (a link planted as ``.lock`` or
    ``figures/`` would otherwise have it write over the file or folder it points to)."""
    p = Path(out) / name
    if p.is_symlink():
        raise StoreError(f"{p}: a symbolic link inside the results directory; the run writes "
                         "only its own files there: remove the link")
    return p


@contextlib.contextmanager
def results_lock(out: Path):
    """Hold an exclusive lock on the results directory ``out`` (created) while a run writes it.

    The lock is an ``flock`` on ``out/.lock``, which records the holder's pid, host and start
    time; the kernel drops it when the holder exits, however it exits, so a lock left by a dead
    process is simply taken over.  Raises StoreError naming the holder if another process holds
    it, or naming ``--out`` if the directory cannot be created.  A run refused before it
    wrote a manifest (a directory that is not a results directory, ``--resume`` with nothing to
    resume) leaves no ``.lock``, nor the directory, where it created them."""
    made_dir = not out.exists()
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise StoreError(f"--out {out}: cannot create the results directory: "
                         f"{err.strerror or err}") from None
    for name in (LOCK, CHUNK_DIR, TICK_DIR):
        inside(out, name)           # never written through a link out of the directory
    made_lock = not (out / LOCK).exists()
    try:
        fd = os.open(out / LOCK, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o666)
    except OSError as err:          # a read-only directory (or lock file)
        raise StoreError(f"--out {out}: cannot open its lock file {LOCK}: "
                         f"{err.strerror or err}; the directory must be writable") from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 300, 0).decode(errors="replace").strip() or "another process"
            raise StoreError(f"--out {out}: another run is writing this directory ({holder}); "
                             f"wait for it to finish or choose another --out") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"pid {os.getpid()} on {platform.node()} since {utc_now()}\n".encode(), 0)
        try:
            yield out
        except BaseException:
            if made_lock and not (out / MANIFEST).exists():
                _remove_unused(out, made_dir)
            raise
    finally:
        os.close(fd)


def writer_of(out) -> str | None:
    """The holder of the results directory ``out``'s lock (:func:`results_lock`: a run
    writing it now), or None: nothing is created, and a lock left by a dead process (the
    kernel dropped it) is no holder."""
    try:
        fd = os.open(Path(out) / LOCK, os.O_RDONLY | os.O_NOFOLLOW)
    except OSError:                  # no lock file: no run has written here (or a link)
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return os.pread(fd, 300, 0).decode(errors="replace").strip() or "another process"
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


def _remove_unused(out: Path, made_dir: bool) -> None:
    """Remove the ``.lock`` (still held) of a refused run, and ``out`` if this run made it and
    it is empty."""
    with contextlib.suppress(OSError):
        (out / LOCK).unlink()
        if made_dir:
            out.rmdir()
