"""``hlip-sweep``: run sweeps, write reports, list and inspect sweep files.

    hlip-sweep run SWEEP [--out DIR] [--batch N] [--resume] [--overwrite]
                         [--plant hlip|cassie] [--duration S] [--limit N]
                         [--no-report] [--no-coverage] [--quiet]
                         [--compile-cache DIR | --no-compile-cache]
    hlip-sweep report DIR
    hlip-sweep list
    hlip-sweep show SWEEP [--plant ...] [--duration S] [--limit N]
    hlip-sweep ticks DIR SCENARIO            (the controller's 1 kHz log of one Cassie run)
    hlip-sweep render DIR SCENARIO [-o FILE.mp4|.gif|.png] [--fps 30] [--camera track|fixed]
                      [--speed 1] [--width 640 --height 480] [--t0 S] [--t1 S]  (see the robot)
    hlip-sweep s2s DIR [--scenarios REGEX] [--skip K]   (the robot's S2S map, least squares)
    hlip-sweep whull DIR --out FILE [--scenarios REGEX]  (a hull W for the tube MPC)
    hlip-sweep coverage DIR [--q Q] [--train-on FIELD=V1,V2]
    hlip-sweep bench [--batch N ...] [--duration S] [--devices N ...] [--admm] [--qp-loop ...] [--qp-linsys ...] [--qp-kernel ...] [--condense ...] [--terms ...]
                     [--qp-rho-start ...]

SWEEP is a path to a TOML sweep file or the name of a shipped one (``paper`` for
``sweeps/paper.toml``).  Exit codes: 0 success; 1 the run stopped incomplete (``--max-chunks``,
or a file-system error such as a full disk while writing chunks; rerun with ``--resume``); 2
user error (bad sweep file, unusable or busy results directory, refused resume, corrupt chunk)
with a one-line message and no traceback; 130 interrupted (Ctrl-C) and 143 terminated
(SIGTERM), both leaving the manifest "incomplete" (rerun with ``--resume``).

``run`` and ``ticks`` keep compiled programs on disk (:mod:`hlip_jax.runtime.compile_cache`)
unless ``--no-compile-cache`` is given, so a rerun starts simulating without a compile.
On a GPU every command runs XLA's deterministic operations, so a rerun repeats bit for bit
(:mod:`hlip_jax.runtime.xla_flags`; ``XLA_FLAGS=--xla_gpu_deterministic_ops=false`` turns them off).

``HLIP_SWEEP_SIMULATE=module:function`` replaces the closed loop
(:func:`hlip_jax.simulation.execution.simulate`) by another function of the same contract — used by tests
and for trying alternative plants without editing the package.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import os
import re
import signal
import sys
import time
from pathlib import Path

from hlip_jax import plants
from hlip_jax.runtime import resources, xla_flags

EXIT_OK, EXIT_INCOMPLETE, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130
#: scenarios a run takes without --max-scenarios (a 1024-robot GPU chunk 64 times over)
MAX_RUN_SCENARIOS = 65_536
PROG = "hlip-sweep"


class UserError(Exception):
    """Reported as one line on stderr, exit code 2."""


class Terminated(BaseException):
    """SIGTERM or SIGHUP (the terminal closed) arrived: unwinds like Ctrl-C (a BaseException,
    so no ``except Exception`` stops it), leaving finished chunks and an "incomplete" manifest.
    ``signum``: the signal's number."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


#: the signals that end a run as :class:`Terminated` (exit 128 + the signal's number)
ENDING_SIGNALS = (signal.SIGTERM, signal.SIGHUP)


def _raise_terminated(signum, frame):
    raise Terminated(signum)


class NamedStdout:
    """Standard output whose write errors name it: ``hlip-sweep list > /dev/full`` says
    ``standard output: ...``, not a bare ``No space left on device`` that reads as the results
    directory's.  A broken pipe is passed on as it is (a reader that went away)."""

    def __init__(self, stream):
        self.stream = stream

    def _named(self, err: OSError) -> UserError:
        return UserError(f"standard output: cannot write it ({err.strerror or err}); allowed: a "
                         "terminal, a pipe or a file that can take the output")

    def write(self, text):
        """Write ``text``; an OSError (not a broken pipe) becomes a UserError naming stdout."""
        try:
            return self.stream.write(text)
        except BrokenPipeError:
            raise
        except OSError as err:
            raise self._named(err) from None

    def flush(self):
        """Flush; an OSError (not a broken pipe) becomes a UserError naming stdout."""
        try:
            self.stream.flush()
        except BrokenPipeError:
            raise
        except OSError as err:
            raise self._named(err) from None

    def __getattr__(self, name):
        return getattr(self.stream, name)


@contextlib.contextmanager
def _stdout_named():
    """Within: ``sys.stdout`` is a :class:`NamedStdout`, flushed on the way out (so a full
    disk under ``> FILE`` is found here, not at exit); the stream is restored after."""
    stream = sys.stdout
    sys.stdout = NamedStdout(stream)
    try:
        yield
        sys.stdout.flush()
    finally:
        sys.stdout = stream


@contextlib.contextmanager
def _sigterm_unwinds():
    """Within the block, each of :data:`ENDING_SIGNALS` raises :class:`Terminated` (in the main
    thread only; elsewhere the default actions stay)."""
    try:
        previous = {s: signal.signal(s, _raise_terminated) for s in ENDING_SIGNALS}
    except ValueError:          # not the main thread
        yield
        return
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


def shipped_dir() -> Path:
    """The shipped sweeps (inside an installed wheel, or ``sweeps/`` of a source checkout)."""
    return resources.data_dir("sweeps")


def resolve_sweep(arg: str) -> Path:
    """A sweep path, or a shipped sweep's name (``paper`` → ``sweeps/paper.toml``)."""
    p = Path(arg)
    if os.sep in arg or (p.exists() and not p.is_dir()):
        return p
    for cand in (shipped_dir() / arg, shipped_dir() / f"{arg}.toml"):
        if cand.is_file():
            return cand
    return p   # load_sweep reports "not found"


def _positive_int(s: str) -> int:
    try:
        v = int(s)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {s!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {v}")
    return v


def _finite_float(s: str) -> float:
    try:
        v = float(s)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {s!r}") from None
    if v != v or v in (float("inf"), float("-inf")):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {s!r}")
    return v


def _sweep_overrides(p: argparse.ArgumentParser) -> None:
    p.add_argument("--plant", choices=plants.NAMES,
                   help="override the plant of every scenario")
    p.add_argument("--duration", type=_finite_float, metavar="S",
                   help="override the simulated time of every scenario [s]; a path or grid axis "
                   "that sets its own duration keeps it (and a batch shares its longest run's "
                   "step count)")
    p.add_argument("--limit", type=_positive_int, metavar="N",
                   help="keep only the first N scenarios")
    p.add_argument("--physics", choices=_field_choices("physics"),
                   help="override impl.physics in the sweep's [impl] table: the implementation that "
                   "steps the simulated Cassie (warp needs warp-lang: pip install 'hlip_jax[warp]')")


def _cache_options(p: argparse.ArgumentParser) -> None:
    """``--compile-cache DIR`` / ``--no-compile-cache`` of the commands that compile."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--compile-cache", metavar="DIR",
                   help="directory of the persistent compilation cache (default "
                   "$HLIP_JAX_CACHE_DIR, else ~/.cache/hlip_jax/xla)")
    g.add_argument("--no-compile-cache", action="store_true",
                   help="compile without reading or writing the persistent cache")


def _use_cache(args) -> None:
    """Turn the persistent compilation cache on as the options ask.  A directory given with
    --compile-cache that cannot be used is a user error; an unusable default directory only
    turns the cache off (with a note)."""
    from hlip_jax.runtime import compile_cache, trace_cache
    if args.no_compile_cache:
        trace_cache.disable()
        return
    if args.compile_cache is not None:
        if not args.compile_cache.strip():
            raise UserError("--compile-cache: an empty path; allowed: a writable directory "
                            "(or --no-compile-cache)")
        link = _broken_link(Path(args.compile_cache))
        if link:
            from hlip_jax.sweepio.sweep import shown_path
            raise UserError(f"--compile-cache {shown_path(args.compile_cache)}: {link}; allowed: "
                            "a writable directory")
        try:
            _enable_caches(Path(args.compile_cache))
        except compile_cache.CacheDirError as err:
            raise UserError(f"--compile-cache {err}; allowed: a writable directory") from None
        return
    why = _default_cache_problem()
    if why is not None:         # never a cache in the working directory or at /.cache
        trace_cache.disable()
        print(f"{PROG}: note: compilation cache off: {why}", file=sys.stderr)
        return
    link = _broken_link(compile_cache.default_dir())
    if link:
        trace_cache.disable()
        from hlip_jax.sweepio.sweep import shown_path
        print(f"{PROG}: note: compilation cache off: {shown_path(compile_cache.default_dir())}: "
              f"{link}", file=sys.stderr)
        return
    try:
        _enable_caches(compile_cache.default_dir())
    except compile_cache.CacheDirError as err:
        print(f"{PROG}: note: compilation cache off: {err}", file=sys.stderr)


def _enable_caches(path: Path) -> None:
    """The compilation and trace caches in ``path`` (:func:`compile_cache.enable`) and the
    invariant sets' facet templates in ``path / "box_templates"``
    (:func:`hlip_jax.core.sets.keep_templates_in`)."""
    from hlip_jax.core import sets
    from hlip_jax.runtime import array_cache, compile_cache
    compile_cache.enable(path)
    templates = array_cache.ArrayCache(path / "box_templates")
    templates.prune()
    sets.keep_templates_in(templates)


def _broken_link(path: Path) -> str | None:
    """Why ``path`` is a symbolic link that leads to no directory (a loop, or dangling), or
    None (creating it would only say "File exists")."""
    try:
        if not path.is_symlink() or path.exists():
            return None
    except OSError as err:      # e.g. a name too long for the file system
        return f"an unusable path ({err.strerror})"
    try:
        os.stat(path)
    except OSError as err:
        return f"a symbolic link that leads nowhere ({err.strerror})"
    return None


def _default_cache_problem() -> str | None:
    """Why the default cache directory is not to be used, or None: an ``XDG_CACHE_HOME`` that
    is a relative path (the XDG rule: ignore it) or an empty ``HOME`` would put it in the
    working directory or at ``/.cache``."""
    if os.environ.get("HLIP_JAX_CACHE_DIR"):
        return None
    xdg = os.environ.get("XDG_CACHE_HOME")
    if xdg and not os.path.isabs(xdg):
        return (f"XDG_CACHE_HOME={xdg!r} is a relative path; allowed: an absolute path (or "
                "--compile-cache DIR)")
    if not xdg and os.environ.get("HOME", None) == "":
        return "HOME is empty; set HOME or XDG_CACHE_HOME (or --compile-cache DIR)"
    return None


def _add_run(sub) -> None:
    """The ``run`` subcommand's parser."""
    r = sub.add_parser("run", help="simulate every scenario of a sweep, then write the report",
                       description="Simulate every scenario of SWEEP chunk by chunk into DIR "
                       "(manifest.json, chunks/, summary.csv), then write the report.")
    r.add_argument("sweep", metavar="SWEEP", help="sweep file, or the name of a shipped sweep")
    r.add_argument("--out", metavar="DIR", help="results directory (default results/<sweep name>)")
    r.add_argument("--max-scenarios", type=_positive_int, metavar="N", default=MAX_RUN_SCENARIOS,
                   help=f"refuse a sweep of more than N scenarios before building any "
                   f"(default {MAX_RUN_SCENARIOS}; raise it for a larger run)")
    r.add_argument("--batch", type=_positive_int, metavar="N",
                   help="scenarios per chunk (one compiled call); default: at most 16 on CPU "
                   "(1024 on accelerators), balanced so the last chunk is nearly full; with "
                   "--resume, the stored value")
    r.add_argument("--resume", action="store_true",
                   help="continue an interrupted run in DIR (skips finished chunks)")
    r.add_argument("--overwrite", action="store_true",
                   help="discard a previous run in DIR")
    _sweep_overrides(r)
    r.add_argument("--no-report", action="store_true", help="skip the report")
    r.add_argument("--no-coverage", action="store_true",
                   help="skip the per-scenario invariant-set coverage columns of summary.csv "
                   "(≈ 30 ms per scenario; the report still analyses each path)")
    r.add_argument("--quiet", action="store_true", help="no progress output")
    r.add_argument("--ticks", metavar="REGEX",
                   help="after the sweep, replay the Cassie scenarios whose names match REGEX "
                   "within their chunks with the controller's 1 kHz log (as `ticks` does: "
                   "DIR/ticks/INDEX.npz, .png, .json) and show their figures in the report")
    r.add_argument("--render", metavar="REGEX",
                   help="after the sweep, replay the Cassie scenarios whose names match REGEX "
                   "within their chunks and draw them (as `render` does: DIR/videos/INDEX_NAME.mp4), "
                   "with a snapshot strip (one frame per simulated second, "
                   "DIR/videos/INDEX_NAME_strip.png) of each and of one representative scenario "
                   "per path, which the report shows; needs pip install 'hlip_jax[render]' and an "
                   "OpenGL backend (both checked before the sweep runs)")
    r.add_argument("--distributed", action="store_true",
                   help="several hosts: call jax.distributed.initialize() (coordinator, process "
                   "count and id from the environment, e.g. JAX_COORDINATOR_ADDRESS / SLURM); every "
                   "process runs this same command, chunks are sharded over all devices of all "
                   "hosts, and process 0 writes DIR and the report")
    r.add_argument("--max-chunks", type=_positive_int, help=argparse.SUPPRESS)
    _cache_options(r)


def _ticks_parser(sub) -> None:
    """The ``ticks`` subcommand's arguments."""
    tk = sub.add_parser("ticks", help="per-tick diagnostics of one Cassie scenario of a results "
                        "directory", description="Re-simulate one scenario of DIR within the "
                        "chunk it ran in (the sweep's own run: the replay's step log is checked "
                        "against the stored one) with the controller's 1 kHz log and write "
                        "DIR/ticks/INDEX.npz and INDEX.png (output errors, torques, contact "
                        "forces, CLF-QP status, phase, and the COM-height acceleration the "
                        "CLF-QP's model predicts beside the measured one).")
    _stored_scenario_arguments(tk, "(every robot of a chunk logs its ticks, so a large GPU "
                               "chunk needs memory; a float32 run at the margin may end "
                               "otherwise alone)")
    _cache_options(tk)


def _stored_scenario_arguments(parser, alone_note: str) -> None:
    """DIR SCENARIO [--alone]: one stored scenario, replayed within its chunk or alone
    (``ticks``, ``render``; :func:`_stored_scenario`)."""
    parser.add_argument("dir", metavar="DIR")
    parser.add_argument("scenario", metavar="SCENARIO", help="index or name of the scenario; "
                        "where an index is also another scenario's name (a scenario named "
                        "'0'), choose with index:N or name:NAME")
    parser.add_argument("--alone", action="store_true",
                        help="replay the scenario as a batch of one instead of within its "
                        "chunk " + alone_note)


#: the bench's variant flags: (CassieConfig field, metavar, what is timed, a note on the values)
_BENCH_VARIANTS = (
    ("qp_loop", "LOOP", "CLF-QP block loops", ""),
    ("qp_linsys", "SOLVE", "CLF-QP linear solves", ""),
    ("qp_kernel", "KERNEL", "CLF-QP iteration kernels",
     "; fused runs with the inverse linear solve only, so it needs --qp-linsys inverse"),
    ("qp_rho_start", "RHO", "CLF-QP starting step sizes", ""),
    ("condense", "SOLVE", "condensation solves", ""),
    ("terms", "TERMS", "whole-body terms", ""),
    ("physics", "IMPL", "physics implementations", "; warp needs warp-lang"),
)


def _field_table(field: str) -> tuple:
    """(table name, config class) that holds a bench variant's field: ``impl`` for the
    implementation switches, ``cassie`` for the controller's own."""
    from hlip_jax.simulation import config
    return (("impl", config.ImplConfig) if field in config.IMPL_FIELDS
            else ("cassie", config.CassieConfig))


def _field_choices(field: str) -> tuple:
    """The allowed values of the field (one list for the file and the CLI)."""
    from hlip_jax.simulation import config
    return tuple(config.field_spec(_field_table(field)[1], field)["choices"])


def _field_default(field: str) -> str:
    """The field's default: what the bench times without the flag."""
    import dataclasses
    cls = _field_table(field)[1]
    return next(f.default for f in dataclasses.fields(cls) if f.name == field)


def _bench_parser(sub) -> None:
    """The ``bench`` subcommand's arguments."""
    b = sub.add_parser("bench", help="closed-loop Cassie throughput against physics-only MJX",
                       description="Time the closed loop (MPC → stepping law → CLF-QP on MJX) on "
                       "straight-line scenarios against zero-torque MJX on the same batch, in one "
                       "process; print a markdown table (see hlip_jax/sweepio/bench.py).")
    b.add_argument("--batch", type=_positive_int, nargs="+", default=[2], metavar="N",
                   help="batch sizes (robots per compiled call)")
    b.add_argument("--duration", type=_finite_float, default=0.6, metavar="S",
                   help="simulated seconds per robot (> 0)")
    b.add_argument("--devices", type=_positive_int, nargs="+", default=[1], metavar="N",
                   help="device counts: the same batch sharded over the first N local devices")
    b.add_argument("--admm", action="store_true",
                   help="also time each batch with the CLF-QP's ADMM budget cut to one "
                   "convergence check and report the ADMM iterations' share of the tick")
    for field, metavar, what, note in _BENCH_VARIANTS:
        choices = _field_choices(field)
        b.add_argument("--" + field.replace("_", "-"), nargs="+", metavar=metavar,
                       default=[_field_default(field)], choices=choices,
                       help=f"{what} to time, each on the same batch in this process "
                       f"({_field_table(field)[0]}.{field}: {', '.join(choices)}{note})")
    b.add_argument("--json", metavar="FILE", help="also write the rows as JSON")


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog=PROG, description="Batch evaluator of H-LIP step planning: run a sweep of "
        "closed-loop scenarios, store the step-to-step logs, and write a report.")
    sub = ap.add_subparsers(dest="cmd", metavar="COMMAND")
    sub.required = True

    _add_run(sub)

    rp = sub.add_parser("report", help="(re)write the report of a results directory",
                        description="Write DIR/report.html, DIR/report.md and DIR/figures/.")
    rp.add_argument("dir", metavar="DIR")
    rp.add_argument("--heatmap", nargs=2, metavar=("AXIS", "AXIS"), default=None,
                    help="the two swept dimensions of the grid heat maps (a grid field such as "
                    "disturbance.pushes.0.time, or 'path'); default: the first two axes")

    cv = sub.add_parser("coverage", help="(re)compute the across-run coverage of a results "
                        "directory", description="Write DIR/coverage.csv: W and E from the "
                        "training runs, the test runs' coverage over runs (Clopper-Pearson) and "
                        "over steps (run-cluster bootstrap), per held-out split "
                        "(hlip_jax/analysis), and print the run-level rows; `report` shows it. "
                        "Unset options take the sweep's [analysis] table.")
    cv.add_argument("dir", metavar="DIR")
    cv.add_argument("--q", type=float, default=None, metavar="Q",
                    help="level of the conformal sets, in (0, 1) (default: the sweep's, 0.9)")
    cv.add_argument("--split", nargs="+", default=None, metavar="NAME",
                    help="held-out splits: seed, path, speed (default: the sweep's, all three)")
    cv.add_argument("--warmup", type=int, default=None, metavar="K",
                    help="errors k < K are the start's transient, not counted (default: the "
                    "sweep's, 4)")
    cv.add_argument("--train-on", default=None, metavar="FIELD=V1,V2",
                    help="instead of the splits: W from the runs whose swept FIELD (a grid "
                    "field or 'path') is one of the values, coverage on the others")

    _ticks_parser(sub)
    _render_parser(sub)

    _model_parsers(sub)

    sub.add_parser("list", help="list the shipped sweeps", description="List sweeps/*.toml.")

    s = sub.add_parser("show", help="expand a sweep and print its grid",
                       description="Validate SWEEP and print its paths, axes and scenario count.")
    s.add_argument("sweep", metavar="SWEEP")
    _sweep_overrides(s)
    s.add_argument("--scenarios", action="store_true", help="also list every scenario name")

    _bench_parser(sub)
    return ap


def _model_parsers(sub) -> None:
    """The commands that fit models and measured W from a results directory: s2s, identify,
    wbox, whull."""
    fs = sub.add_parser("s2s", help="fit the robot's step-to-step map from a results directory",
                        description="Least-squares S2S map [p, v]+ = A [p, v] + B u + c(stance) "
                        "per plane of the heading frame, from the step logs of DIR, beside the "
                        "planner's H-LIP (hlip_jax/core/s2s_fit.py).")
    fs.add_argument("dir", metavar="DIR")
    fs.add_argument("--scenarios", metavar="REGEX", default="",
                    help="only scenarios whose name matches REGEX (Python re.search)")
    fs.add_argument("--skip", type=int, default=4, metavar="K",
                    help="leave out the first K steps of every run (start from rest; >= 0)")

    ident = sub.add_parser("identify", help="fit an S2S model from a results directory and write "
                           "it for s2s.model = 'identified'",
                           description="Least-squares S2S map [p, v]+ = A [p, v] + B u + "
                           "c(plane, stance), one (A, B) for both planes, from the step logs of "
                           "the runs of DIR that walked (hlip_jax/core/s2s_model.py); writes it to "
                           "-o and compares its residual with the H-LIP's on --test runs.")
    ident.add_argument("dir", metavar="DIR")
    ident.add_argument("-o", "--out", required=True, metavar="FILE.npz",
                       help="the model file to write (a new file)")
    ident.add_argument("--scenarios", metavar="REGEX", default="",
                       help="fit on the scenarios whose name matches REGEX (default: all)")
    ident.add_argument("--test", metavar="REGEX", default=None,
                       help="held-out scenarios: the residual spread under the model and under "
                       "the H-LIP on them (not used in the fit)")
    ident.add_argument("--skip", type=int, default=4, metavar="K",
                       help="leave out the first K steps of every run (start from rest; >= 0)")

    wb = sub.add_parser("wbox", help="the W box of a results directory, as sweep-file lines "
                        "for the tube MPC", description="Read DIR/coverage.csv and print the "
                        "[base.mpc] lines (w_frame, w_c_1 ... w_v_2) of the symmetric box that "
                        "encloses the chosen groups' W, rounded up to 1e-4 (hlip_jax.core.robust).")
    wb.add_argument("dir", metavar="DIR")
    wb.add_argument("--method", default="box", metavar="METHOD",
                    help="which W of coverage.csv: box, hull, conformal_step, conformal_run or "
                    "conformal_box (default box)")
    wb.add_argument("--group", action="append", default=None, metavar="NAME",
                    help="a group of coverage.csv (repeat for several; default: all groups)")

    wh = sub.add_parser("whull", help="the hull W of a results directory, as a points file "
                        "and sweep-file lines for the tube MPC", description="Pool the "
                        "chosen runs' S2S disturbances (pushes' steps left out, as in "
                        "coverage.csv), write the vertices of their symmetric convex hull to "
                        "FILE (columns plane, c, p, v) and print the [base.mpc] lines that "
                        "make it the tube's W (hlip_jax.core.robust).")
    wh.add_argument("dir", metavar="DIR")
    wh.add_argument("--out", required=True, metavar="FILE", help="the CSV file to write")
    wh.add_argument("--scenarios", metavar="REGEX", default="",
                    help="only scenarios whose name matches REGEX (Python re.search)")


def _simulate_override():
    spec = os.environ.get("HLIP_SWEEP_SIMULATE")
    if not spec:
        return None
    mod, sep, fn = spec.partition(":")
    allowed = "allowed: module:function, a function configs -> step log (the tests' fake loop)"
    if not (sep and mod and fn):
        raise UserError(f"HLIP_SWEEP_SIMULATE={spec}: {allowed}")
    try:
        func = getattr(importlib.import_module(mod), fn)
    except (ImportError, AttributeError, ValueError) as err:
        raise UserError(f"HLIP_SWEEP_SIMULATE={spec}: cannot load it: {err}") from None
    if not callable(func):
        raise UserError(f"HLIP_SWEEP_SIMULATE={spec}: not a function; {allowed}")

    def simulate(configs, *rest, **kw):
        try:
            log = func(configs, *rest, **kw)
        except TypeError as err:
            raise UserError(f"HLIP_SWEEP_SIMULATE={spec}: the call failed: {err}; "
                            f"{allowed}") from None
        if not (isinstance(log, dict) or hasattr(log, "_asdict")):
            raise UserError(f"HLIP_SWEEP_SIMULATE={spec}: returned a value of type "
                            f"{type(log).__name__}, not a step log; {allowed}")
        return log

    return simulate


def _load(args):
    from hlip_jax.sweepio import sweep
    if not args.sweep:
        raise UserError("SWEEP: empty; give the path of a sweep file (e.g. sweeps/paper.toml)")
    return sweep.load_sweep(resolve_sweep(args.sweep), plant=args.plant,
                            duration=args.duration, limit=args.limit, physics=args.physics)


def _cache_inside(args, out: Path) -> None:
    """UserError when the compilation cache this command would use lies inside its results
    directory ``out`` (the run would refuse the folder it made itself, or later report it as
    foreign); checked before either is created."""
    from hlip_jax.runtime import compile_cache
    if args.no_compile_cache:
        return
    given = args.compile_cache is not None
    if not given and _default_cache_problem() is not None:
        return
    cache = Path(args.compile_cache) if given else compile_cache.default_dir()
    try:
        c, o = cache.resolve(), out.resolve()
    except (OSError, RuntimeError):      # a link loop: named where the cache is enabled
        return
    if c == o or o in c.parents:
        what = (f"--compile-cache {cache}" if given else
                f"HLIP_JAX_CACHE_DIR={cache}" if os.environ.get("HLIP_JAX_CACHE_DIR")
                else f"the compilation cache {cache}")
        raise UserError(f"{what} lies inside --out {out}; allowed: a compilation cache directory "
                        "outside the results directory (or --no-compile-cache)")


def _check_lock_file(out: Path) -> None:
    """UserError naming ``out/.lock`` when it is there but not a regular file (a stray
    ``mkdir``): the run could not take its lock.  A link is refused by the store itself."""
    import stat

    from hlip_jax.sweepio import store
    lock = out / store.LOCK
    try:
        mode = os.lstat(lock).st_mode
    except OSError:         # absent (or unreadable: the store names it)
        return
    if not stat.S_ISREG(mode) and not stat.S_ISLNK(mode):
        kind = "a directory" if stat.S_ISDIR(mode) else "not a regular file"
        raise UserError(f"--out {out}: {lock} is {kind}, not the run's lock file; remove it "
                        f"if no run is writing {out}")


def cmd_run(args) -> int:
    from hlip_jax.presentation import report
    from hlip_jax.sweepio import runner, store
    if args.out is not None and not args.out.strip():
        raise UserError("--out: an empty path; give a directory (default: results/<sweep name>)")
    if args.out is not None:
        _cache_inside(args, Path(args.out))     # before the cache or --out is created
    _use_cache(args)               # before anything compiles: JAX reads it at the first compile
    sw = _load(args)
    out = Path(args.out) if args.out is not None else Path("results") / sw.name
    if ".." in out.parts:       # lnk/../o: one real folder for every write (not cwd/o)
        out = Path(os.path.realpath(out))
    if args.out is None:        # the default results/<sweep name>, known once the sweep is read
        _cache_inside(args, out)
    try:
        not_dir = out.exists() and not out.is_dir()
    except OSError as err:      # e.g. a name too long for the file system
        from hlip_jax.sweepio.sweep import shown_path
        raise UserError(f"--out {shown_path(out)}: unusable as a results directory: "
                        f"{err.strerror or err}") from None
    if not_dir:
        raise UserError(f"--out {out}: exists and is not a directory")
    if out.is_symlink() and not out.exists():
        raise UserError(f"--out {out}: a symbolic link to a missing path; allowed: a directory "
                        "or a new path")
    if args.resume and args.overwrite:
        raise UserError("--resume and --overwrite exclude each other")
    _check_lock_file(out)
    if sw.n_scenarios > args.max_scenarios:
        raise UserError(f"{sw.name}: {sw.n_scenarios} scenarios; allowed: at most "
                        f"{args.max_scenarios} per run (--max-scenarios N raises the limit; "
                        "--limit N runs the first N)")
    sim = _simulate_override()
    if args.ticks is not None and args.distributed:
        raise UserError("--ticks and --distributed exclude each other: replay the scenarios "
                        f"afterwards with `{PROG} ticks DIR SCENARIO`")
    chosen = _tick_choice(sw, args.ticks) if args.ticks is not None else []
    if args.render is not None and args.distributed:
        raise UserError("--render and --distributed exclude each other: draw the scenarios "
                        f"afterwards with `{PROG} render DIR SCENARIO`")
    drawn = _render_choice(sw, args.render) if args.render is not None else []
    if args.distributed:
        import jax
        _init_distributed(jax)
        if jax.process_index() != 0:
            # the others compute their shards and keep a private copy of the store
            out = out / store.PROCESS_STORE.format(jax.process_index())
            args.no_report = True
            args.quiet = True
    if not args.quiet:
        print(f"{PROG}: {sw.name}: {sw.n_scenarios} scenarios -> {out}", file=sys.stderr)
    res = runner.run_sweep(sw, out, batch=args.batch, resume=args.resume,
                           overwrite=args.overwrite, simulate=sim, max_chunks=args.max_chunks,
                           progress=not args.quiet, with_coverage=not args.no_coverage)
    if not res.complete:
        print(f"{PROG}: stopped after {res.chunks_run} chunk(s); {out} is incomplete: "
              f"continue with `{PROG} run {args.sweep} --out {out} --resume`", file=sys.stderr)
        return EXIT_INCOMPLETE
    print(f"results: {out} ({res.n_scenarios} scenarios, {res.seconds:.1f} s)")
    if chosen:
        _tick_logs(out, chosen)
    if args.render is not None:
        _render_runs(out, drawn)
    stages = dict(res.stages)
    if not args.no_report:
        t_report = time.monotonic()
        with runner.on_host():
            html, md = report.write_report(out)
        stages["report"] = time.monotonic() - t_report
        print(f"report: {html}")
        print(f"        {md}")
    if not args.quiet:
        print(f"{PROG}: {sw.name}: " + ", ".join(f"{k} {v:.1f} s" for k, v in stages.items()),
              file=sys.stderr)
    return EXIT_OK


def _tick_choice(sw, pattern: str) -> list[int]:
    """Indices of the scenarios of ``sw`` whose names match ``pattern`` (``--ticks``); a user
    error, before anything runs, for a bad pattern, no match or a plant without a tick log."""
    from hlip_jax.simulation import execution
    cfgs = list(sw.scenarios)
    chosen = _matching([c.name for c in cfgs], pattern, "--ticks")
    for i in chosen:
        try:
            execution.check_keeps_ticks(cfgs[i], i)
        except ValueError as err:
            raise UserError(f"--ticks: {err}") from None
    return chosen


def _tick_logs(out: Path, chosen: list[int]) -> None:
    """Replay the ``--ticks`` scenarios of ``out`` within their chunks; one line each."""
    from hlip_jax.sweepio import store
    from hlip_jax.presentation import tick_report
    man = store.read_manifest(out)
    for rep in tick_report.replay_many(out, chosen):
        print(f"ticks: {rep.png}: {_agreement_text(rep, man)}")


def _init_distributed(jax) -> None:
    """``jax.distributed.initialize()``: coordinator, process count and id from a cluster's
    environment (SLURM, ...) or from ``JAX_COORDINATOR_ADDRESS``, ``JAX_NUM_PROCESSES`` and
    ``JAX_PROCESS_ID`` (e.g. several processes on one host, CPU devices included)."""
    kw = {}
    for env, key in (("JAX_NUM_PROCESSES", "num_processes"), ("JAX_PROCESS_ID", "process_id")):
        text = os.environ.get(env)
        if text is None:
            continue
        if not (text.isascii() and text.isdigit()):
            raise UserError(f"{env}={text!r}: expected an integer >= 0")
        kw[key] = int(text)
    try:
        jax.distributed.initialize(**kw)
    except (ValueError, RuntimeError) as err:
        raise UserError(f"--distributed: cannot start: {' '.join(str(err).split())[:300]}") from None


def cmd_report(args) -> int:
    from hlip_jax.presentation import report
    from hlip_jax.sweepio import store
    d = _results_dir(args.dir)
    store.check_chunks(d)           # a truncated or altered chunk is named before any figure
    _note_changed_files(d)
    from hlip_jax.sweepio import runner
    with runner.on_host():
        html, md = report.write_report(d, heatmap_axes=args.heatmap)
    print(f"report: {html}")
    print(f"        {md}")
    return EXIT_OK


def _note_changed_files(d: Path) -> None:
    """A note for each data file of the run (a hull W, a model) whose contents changed since
    the run: the report shows the stored results, made with the file as it was."""
    from hlip_jax.sweepio import store, sweep
    files = (store.read_manifest(d).get("run_identity") or {}).get("files") or {}
    for path, digest in (files.items() if isinstance(files, dict) else ()):
        try:
            now = sweep.file_digest(path)
        except OSError:
            continue                 # deleted or moved: nothing the report reads
        if now != digest:
            print(f"{PROG}: note: {path} changed since the run (sha256 {now[:12]} now, "
                  f"{str(digest)[:12]} in {store.MANIFEST}); the report shows the results "
                  "made with it as it was", file=sys.stderr)


def _train_on(text: str | None):
    """``FIELD=V1,V2`` → (FIELD, [values]) with numbers parsed as JSON, the rest as strings."""
    if text is None:
        return None
    field, sep, vals = text.partition("=")
    if not sep or not field.strip() or not vals.strip():
        raise UserError(f"--train-on: expected FIELD=V1[,V2...], e.g. path=circle or seed=1,2; "
                        f"got {text!r}")

    def value(v: str):
        try:
            return json.loads(v)
        except ValueError:
            return v

    return field.strip(), [value(v.strip()) for v in vals.split(",")]


def _same_value(a, b) -> bool:
    """A --train-on value equals a stored swept value (numbers by value: 0.010 is 0.01)."""
    num = (int, float)
    if isinstance(a, num) and isinstance(b, num) and not isinstance(a, bool) \
            and not isinstance(b, bool):
        return float(a) == float(b)
    return a == b


def _check_train_values(train_on, configs: list) -> None:
    """UserError naming a --train-on value that no scenario of the run takes (a typo would
    otherwise train on the other values without a word)."""
    if train_on is None:
        return
    field, values = train_on
    taken = list(dict.fromkeys(str(c["swept"][field]) for c in configs if field in c["swept"]))
    stored = [c["swept"][field] for c in configs if field in c["swept"]]
    if not stored:
        return                   # not a swept field: coverage_rows names it
    for v in values:
        if not any(_same_value(v, t) for t in stored):
            shown = ", ".join(taken[:8]) + (", ..." if len(taken) > 8 else "")
            raise UserError(f"--train-on: {field}={v!r} is none of the run's values of {field!r}; "
                            f"allowed: {shown}")


def _note_unfinished(d: Path, man: dict, what: str) -> None:
    """A note when some of the run's chunks are not stored (an unfinished run)."""
    from hlip_jax.sweepio import store
    ranges = store.chunk_ranges(man["n_scenarios"], man["batch"])
    stored = sum(b - a for i, (a, b) in enumerate(ranges) if store.chunk_path(d, i).is_file())
    if stored < man["n_scenarios"]:
        print(f"{PROG}: note: {stored} of the {man['n_scenarios']} scenarios are stored (an "
              f"unfinished run; finish it with `{PROG} run SWEEP --out {d} --resume`); {what}",
              file=sys.stderr)


def _coverage_settings(d: Path, args):
    """The directory's analysis settings with the command line's --q, --split, --warmup."""
    from hlip_jax.sweepio import store
    from hlip_jax.analysis import settings as an
    base = an.to_dict(store.analysis_settings(d))
    for opt, key, val in (("--q", "q", args.q), ("--split", "splits", args.split),
                          ("--warmup", "warmup", args.warmup)):
        if val is not None:
            try:
                an.from_dict({key: val}, opt)
            except ValueError as err:
                raise UserError(str(err).replace(f"{opt}.{key}", opt)) from None
            base[key] = val
    return an.from_dict(base)


def cmd_coverage(args) -> int:
    from hlip_jax.sweepio import store
    d = _results_dir(args.dir)
    settings = _coverage_settings(d, args)
    store.check_chunks(d)
    from hlip_jax.sweepio import runner
    train_on = _train_on(args.train_on)
    man = store.read_manifest(d)
    _check_train_values(train_on, man["configs"])
    _check_no_writer(d)
    _note_unfinished(d, man, "coverage.csv holds the stored ones")
    with runner.on_host():
        rows = store.coverage_rows(d, settings, train_on)
    _check_no_writer(d)             # a run started meanwhile writes its own table at its end
    if train_on is not None and all(r["note"] in ("no test run", "no training run") for r in rows):
        side = "test" if any(r["note"] == "no test run" for r in rows) else "training"
        raise UserError(f"--train-on: {args.train_on!r} leaves no {side} run in any group; "
                        f"{store.COVERAGE} is left as it was")
    path = store.write_coverage_rows(d, rows)
    for r in store.read_coverage(d):
        if r["level"] == "run":
            print(f"{r['group']:<32} {r['plane']:<9} {r['w_method']:<15} {r['split']:<6} "
                  f"runs covered {r['covered']}/{r['test_samples']} "
                  f"[{r['ci_low']}, {r['ci_high']}] {r['note']}")
    print(f"coverage: {path}")
    return EXIT_OK


def _check_no_writer(d: Path) -> None:
    """UserError while a run writes ``d``: the table of the chunks stored so far would stand,
    as the finished run's, over the one the run writes when it ends, if written after it."""
    from hlip_jax.sweepio import store
    holder = store.writer_of(d)
    if holder is not None:
        raise UserError(f"{d}: a run is writing this directory ({holder}); it writes "
                        f"{store.COVERAGE} itself when it finishes; run `{PROG} coverage {d}` "
                        "after it, if at all")


def _chosen_scenarios(d: Path, regex: str) -> list[int]:
    """Indices of the scenarios of results directory ``d`` whose name matches ``regex``
    (``--scenarios``), after checking its chunks; UserError when the expression is malformed
    or matches none."""
    from hlip_jax.sweepio import store
    _matching([], regex, "--scenarios")       # a malformed pattern is named before any chunk is read
    store.check_chunks(d)
    return _matching([c["name"] for c in store.read_manifest(d)["configs"]], regex,
                     "--scenarios")


def _stored_rows(d: Path, groups: list[list[int]]):
    """(the stored chunks' log of the scenarios of ``groups``, each group as rows of that log):
    a scenario's row is found by its index (an unfinished run stores some chunks only); a note
    names the scenarios not stored yet, a user error where a group has none."""
    from hlip_jax.sweepio import store
    wanted = [i for g in groups for i in g]
    log = store.load_log(d, wanted)
    row = {int(i): r for r, i in enumerate(log["index"])}
    missing = [i for i in dict.fromkeys(wanted) if i not in row]
    _note_unstored(d, len(missing), len(set(wanted)))
    rows = [[row[i] for i in g if i in row] for g in groups]
    if groups[0] and not rows[0]:
        raise UserError(f"{d}: none of the chosen scenarios is stored yet")
    return log, rows


def _note_unstored(d: Path, missing: int, wanted: int) -> None:
    """A note on stderr when ``missing`` of the ``wanted`` chosen scenarios of ``d`` have no
    chunk yet (an unfinished run, or one still running)."""
    if missing:
        print(f"{PROG}: note: {missing} of the {wanted} chosen scenarios are not "
              f"stored yet (an unfinished run; finish it with `{PROG} run SWEEP --out {d} "
              "--resume`); using the stored ones", file=sys.stderr)


def _matching(names: list[str], regex: str, option: str) -> list[int]:
    """Indices of ``names`` that ``regex`` matches (Python re.search); UserError naming
    ``option`` when the expression is malformed or, given names, matches none of them."""
    try:
        pattern = re.compile(regex)
    except (re.error, OverflowError, RecursionError) as err:    # a{4294967296}; 2,000 '('
        why = err if not isinstance(err, RecursionError) else "nested too deeply"
        shown = repr(regex) if len(regex) <= 60 else f"{regex[:60]!r}... ({len(regex)} characters)"
        raise UserError(f"{option}: {shown} is not a regular expression ({why})") from None
    chosen = [i for i, n in enumerate(names) if pattern.search(n)]
    if names and not chosen:
        shown = ", ".join(names[:5]) + (", …" if len(names) > 5 else "")
        raise UserError(f"{option}: {regex!r} matches none of the {len(names)} scenarios "
                        f"({shown})")
    return chosen


def cmd_s2s(args) -> int:
    import numpy as np

    from hlip_jax.core import s2s_fit
    from hlip_jax.sweepio import store
    d = _results_dir(args.dir)
    if args.skip < 0:
        raise UserError(f"--skip: expected an integer >= 0, got {args.skip}")
    log, (chosen,) = _stored_rows(d, [_chosen_scenarios(d, args.scenarios)])
    _check_skip(log, chosen, args.skip, 5)   # s2s_fit.fit's least
    try:
        f = s2s_fit.fit(log, chosen, args.skip)
    except ValueError as err:
        raise UserError(str(err)) from None
    A_h, B_h = s2s_fit.hlip_rows(log["A"][chosen[0]], log["B"][chosen[0]])
    print(f"{len(chosen)} scenarios, {f.n} step pairs (heading frame; regressor rank {[int(r) for r in f.rank]} of 5)")
    for j, plane in enumerate(("sagittal", "lateral")):
        for r, name in enumerate(("p+", "v+")):
            fit_row = np.r_[f.A[j, r], f.B[j, r]]
            print(f"{plane:<9} {name}: fit  {fit_row[0]:+8.3f} p {fit_row[1]:+8.3f} v {fit_row[2]:+8.3f} u"
                  f"  offsets L {f.offset[j, 0, r]:+.3f} R {f.offset[j, 1, r]:+.3f}  residual RMS {f.rms[j, r]:.4f}")
            print(f"{'':<9} {'':<3} H-LIP {A_h[r, 0]:+8.3f} p {A_h[r, 1]:+8.3f} v {B_h[r]:+8.3f} u")
    return EXIT_OK


def _check_skip(log, chosen: list[int], skip: int, need: int) -> None:
    """UserError naming --skip when it leaves fewer than ``need`` step pairs in all the chosen
    runs together (pairs k, k+1 of one run with k >= skip; the fit pools them): the cause is
    the option, not the scenarios.  Where even --skip 0 leaves fewer (the runs fell or are
    short) the scenarios are named instead, and the allowed values are those that leave
    ``need`` pairs."""
    from hlip_jax.core import steplog
    steps = [int(steplog.alive(log["valid"][s]).sum()) for s in chosen]

    def pairs(k: int) -> int:
        return sum(max(0, n - 1 - k) for n in steps)
    if pairs(skip) >= need:
        return
    longest = max(steps, default=0)
    if pairs(0) < need:
        raise UserError(f"scenarios: {len(chosen)} chosen runs with {pairs(0)} step pairs in "
                        f"all, even with --skip 0 (the longest kept {longest} steps before it "
                        f"ended or fell); the fit needs at least {need}: choose runs that walk "
                        "longer")
    limit = max(k for k in range(min(skip, longest)) if pairs(k) >= need)
    left = "no" if not pairs(skip) else f"only {pairs(skip)}"
    raise UserError(f"--skip: {skip} leaves {left} usable step pairs in the "
                    f"{len(chosen)} chosen runs (the longest has {longest} steps); the fit "
                    f"needs at least {need}; allowed: at most {limit}")


def cmd_identify(args) -> int:
    from hlip_jax.core import s2s_model
    from hlip_jax.sweepio import store
    d, out = _results_dir(args.dir), Path(args.out)
    if args.skip < 0:
        raise UserError(f"--skip: expected an integer >= 0, got {args.skip}")
    if out.suffix != ".npz" or out.exists():
        raise UserError(f"-o: {out}: allowed: a new file ending in .npz (nothing is overwritten)")
    _check_new_file(out, "-o")          # before the fit: its folder exists and takes files
    _check_not_a_run_file(out, "-o")
    chosen = _chosen_scenarios(d, args.scenarios)
    test = [] if args.test is None else _chosen_scenarios(d, args.test)
    if set(test) & set(chosen):
        test = [i for i in test if i not in set(chosen)]
        if not test:
            raise UserError("--test: every matching scenario is also fitted on; allowed: "
                            "scenarios outside --scenarios")
    log, (chosen, test) = _stored_rows(d, [chosen, test])
    _check_skip(log, chosen, args.skip, 7)   # s2s_model.fit's least
    h = store.read_manifest(d)["configs"][int(log["index"][chosen[0]])]["hlip"]
    try:
        model = s2s_model.fit(log, chosen, (h["z0"], h["t_ssp"], h["t_dsp"]), args.skip)
    except ValueError as err:
        raise UserError(str(err)) from None
    if model.rank < 7:      # least squares' minimum-norm answer, not one the steps determine
        raise UserError(f"scenarios: the {len(chosen)} chosen runs' {model.n} step pairs give "
                        f"a regressor of rank {model.rank} of 7, which does not determine the "
                        "model (the steps do not vary, or their logs are damaged); nothing "
                        "written; allowed: runs whose steps vary (several paths or speeds)")
    print(f"{len(chosen)} scenarios, {model.n} step pairs, regressor rank {model.rank} of 7")
    _print_model(model, log["A"][chosen[0]], log["B"][chosen[0]])
    if test:
        _print_heldout(log, test, model, args.skip)
    store.write_atomic(out, s2s_model.to_bytes(model))     # a link at -o is replaced
    print(f"model: {out}  (s2s.model = \"identified\", s2s.file = \"{out.resolve()}\")")
    return EXIT_OK


def _print_model(model, A3, B3) -> None:
    import numpy as np
    A_h, B_h = np.asarray(A3, float)[1:, 1:], np.asarray(B3, float)[1:]
    for r, name in enumerate(("p+", "v+")):
        print(f"{name}: fit   {model.A[r, 0]:+8.4f} p {model.A[r, 1]:+8.4f} v {model.B[r]:+8.4f} u"
              f"   residual RMS {model.rms[r]:.4f}")
        print(f"    H-LIP {A_h[r, 0]:+8.4f} p {A_h[r, 1]:+8.4f} v {B_h[r]:+8.4f} u")
    for j, plane in enumerate(("sagittal", "lateral")):
        print(f"constants {plane}: L p {model.offset[j, 0, 0]:+.4f} v {model.offset[j, 0, 1]:+.4f}"
              f"  R p {model.offset[j, 1, 0]:+.4f} v {model.offset[j, 1, 1]:+.4f}")


def _print_heldout(log, test, model, skip: int) -> None:
    """Spread (1st to 99th percentile) of the held-out residuals per plane, model and H-LIP."""
    import numpy as np

    from hlip_jax.core import s2s_fit, s2s_model
    r_id = s2s_model.residuals(log, test, model, skip)
    r_h = s2s_fit.residuals(log, test, None, skip,
                            hlip=s2s_fit.hlip_rows(log["A"][test[0]], log["B"][test[0]]))
    if not len(r_id):
        print("held out: no usable step pairs")
        return

    def spread(r):
        return np.percentile(r, 99, axis=0) - np.percentile(r, 1, axis=0)

    print(f"held out: {len(test)} scenarios, {len(r_id)} step pairs; residual spread "
          "(1st-99th percentile) p [m], v [m/s]")
    for j, plane in enumerate(("sagittal", "lateral")):
        s_id, s_h = spread(r_id[:, j]), spread(r_h[:, j])
        print(f"  {plane:<9} identified {s_id[0]:.4f}, {s_id[1]:.4f}   H-LIP {s_h[0]:.4f}, "
              f"{s_h[1]:.4f}   ratio {s_h[0] / s_id[0]:.2f}, {s_h[1] / s_id[1]:.2f}")


def cmd_whull(args) -> int:
    import csv
    import io

    import numpy as np

    from hlip_jax.core import robust
    from hlip_jax.sweepio import store
    d, out = _results_dir(args.dir), Path(args.out)
    if out.exists():
        raise UserError(f"--out: {out} exists; allowed: a new file (nothing is overwritten)")
    _check_not_a_run_file(out, "--out")
    chosen = _chosen_scenarios(d, args.scenarios)
    where = store.stored_chunk_of(d)
    _note_unstored(d, sum(i not in where for i in chosen), len(chosen))
    try:
        frame, samples, runs = store.disturbance_samples(d, chosen)
    except store.StoreError as err:
        raise UserError(str(err)) from None
    if not all(np.all(np.isfinite(S)) for S in samples):
        bad = next(i for i, *_, run in store.analysed_runs(d, store.analysis_settings(d).warmup,
                                                           chosen)
                   if not all(np.all(np.isfinite(run.kept_d(p))) for p in (0, 1)))
        raise UserError(f"{where[bad]}: scenario {bad}'s disturbances hold NaN or infinite "
                        "values (a damaged chunk); nothing written; remove the chunk and "
                        f"`hlip-sweep run SWEEP --out {d} --resume` simulates it again")
    if samples[0].shape[1] != 3:
        raise UserError("the runs' W is on [p, v]; the tube needs [c, p, v] "
                        "(gain.with_position = true)")
    verts = [robust.symmetric_hull_vertices(S) for S in samples]
    text = io.StringIO(newline="")
    w = csv.writer(text)
    w.writerow(robust.HULL_COLUMNS)
    for i, V in enumerate(verts):
        w.writerows([i + 1, *(f"{x:.9g}" for x in v)] for v in V)
    store.write_atomic(out, text.getvalue())       # a link at --out is replaced, not followed
    print(f"# W of {d}: the symmetric convex hull of {len(samples[0])} disturbance samples "
          f"per plane from {runs} runs (pushes' steps left out); "
          f"{len(verts[0])} and {len(verts[1])} vertex pairs in {out}")
    print("[base.mpc]")
    print(f'w_frame = "{frame}"')
    print('w_shape = "hull"')
    print(f'w_hull_file = "{out.resolve()}"')
    return EXIT_OK


def cmd_wbox(args) -> int:
    import numpy as np

    from hlip_jax.core import robust
    from hlip_jax.sweepio import store
    from hlip_jax.analysis import estimators
    d = _results_dir(args.dir)
    if args.method not in estimators.METHODS:
        raise UserError(f"--method: {args.method!r}; allowed: {', '.join(estimators.METHODS)}")
    # coverage.csv is checked against the manifest, the manifest against the chunks: a
    # manifest and table copied in together from another run are not this run's W (a table
    # alone, without a manifest, is read as before)
    if os.path.lexists(d / store.MANIFEST):
        store.check_chunks(d)
    try:
        rows = store.read_coverage(d)
        if not rows:        # not the options' doing: no group had a held-out split
            raise UserError(f"{d / store.COVERAGE}: holds no rows: no group of the run has "
                            "runs that differ in a field of its [analysis] splits "
                            f"({', '.join(store.analysis_settings(d).splits)}); allowed: a "
                            f"table of W, e.g. from `{PROG} coverage {d} --split path` or "
                            "--train-on FIELD=V1,V2")
        frame, w, groups = robust.w_from_coverage(rows, args.method, args.group)
    except store.OtherRunError as err:      # says how to rewrite it
        raise UserError(str(err)) from None
    except store.StoreError as err:     # advice added where the message gives none
        advice = ("" if "hlip-sweep coverage" in str(err)
                  else f" (write it with: hlip-sweep coverage {d})")
        raise UserError(f"{err}{advice}") from None
    except robust.NoWError as err:
        why = _no_samples_why(d)
        shown = str(err).split(" (")[0] + why if why else str(err)
        raise UserError(f"{d / store.COVERAGE}: {shown}") from None
    except ValueError as err:
        raise UserError(f"--group/--method: {err}") from None
    w = np.ceil(np.round(w * 1e4, 6)) / 1e4          # up to 1e-4, not past a value on the grid
    print(f"# W of {d} (coverage.csv, {args.method}; groups: {', '.join(groups)}):")
    print("# per plane the largest |w_lo|, |w_hi|, rounded up to 1e-4")
    print("[base.mpc]")
    print(f'w_frame = "{frame}"')
    for i in (0, 1):
        for j, name in enumerate("cpv"):
            print(f"w_{name}_{i + 1} = {w[i, j]:.4f}")
    return EXIT_OK


def _no_samples_why(d: Path) -> str:
    """Why a run has no disturbance samples, as far as the results tell: the runs' steps
    against the sweep's warm-up (", ..." text), or "" where the chunks cannot say."""
    from hlip_jax.core import steplog
    from hlip_jax.sweepio import store
    try:
        warmup = store.analysis_settings(d).warmup
        valid = store.load_log(d)["valid"]
    except (store.StoreError, KeyError, OSError):
        return ""
    longest = max((int(steplog.alive(v).sum()) for v in valid), default=0)
    if longest > warmup + 1:        # a sample needs steps k and k + 1 past the warm-up
        return ""
    return (f": no disturbance samples after the warm-up (the longest run has {longest} "
            f"steps, the warm-up is {warmup}; a sample needs two steps past it); run longer"
            + (f", or rewrite it with `{PROG} coverage {d} --warmup K` with K < {longest - 1}"
               if longest > 2 else ""))


def cmd_ticks(args) -> int:
    import numpy as np

    from hlip_jax.presentation import tick_report
    _use_cache(args)
    d, man, index = _stored_scenario(args)
    try:
        rep = tick_report.replay(d, index, alone=args.alone)
    except ValueError as err:
        raise UserError(str(err)) from None
    print(f"ticks: {rep.npz}")
    print(f"       {rep.png}")
    print(_agreement_text(rep, man))
    mm = tick_report.mismatch(dict(np.load(rep.npz)), man["configs"][index]["plant"])
    for phase, (meas, model) in mm.items():
        print(f"COM height acceleration, mean over {phase.upper()} ticks: measured {meas:+.3f}, "
              f"CLF-QP model {model:+.3f} m/s²")
    return EXIT_OK


def _results_dir(text: str) -> Path:
    """``text`` as a results directory; UserError when no such directory exists."""
    if not text:
        raise UserError("DIR: empty; give the results directory that `hlip-sweep run` wrote")
    d = Path(text)
    if os.path.lexists(d) and not d.is_dir():
        raise UserError(f"{d}: not a directory; give the results directory that holds it "
                        f"({d.parent})" if d.name == "manifest.json" else
                        f"{d}: not a directory; give a results directory")
    if not d.is_dir():
        raise UserError(f"{d}: results directory not found")
    return d


def _stored_scenario(args) -> tuple[Path, dict, int]:
    """(results directory, its manifest, the scenario's index) of ``ticks`` and ``render``'s
    DIR SCENARIO arguments."""
    from hlip_jax.sweepio import store
    d = _results_dir(args.dir)
    man = store.read_manifest(d)
    return d, man, _scenario_index(d, man, args.scenario)


def _scenario_index(d: Path, man: dict, text: str) -> int:
    """The index of scenario ``text`` of results directory ``d`` with manifest ``man``: a name,
    an index, ``name:NAME`` or ``index:N``; UserError listing what is allowed otherwise, and
    when ``text`` is both an index and another scenario's name (ambiguous)."""
    names = [c["name"] for c in man["configs"]]
    last = len(names) - 1

    def as_index(t: str):
        return int(t) if t.isascii() and t.isdigit() and int(t) <= last else None

    kind, sep, rest = text.partition(":")
    if sep and kind in ("name", "index") and text not in names:
        if kind == "name" and rest in names:
            return names.index(rest)
        if kind == "index" and as_index(rest) is not None:
            return as_index(rest)
        raise UserError(f"SCENARIO: {text!r}: no scenario of {d} has that {kind}; allowed: "
                        f"index:0..index:{last} or name: and a name from summary.csv")
    by_name = names.index(text) if text in names else None
    by_index = as_index(text)
    if by_name is not None and by_index is not None and by_name != by_index:
        raise UserError(f"SCENARIO: {text!r} is ambiguous: the name of scenario {by_name} and "
                        f"the index of scenario {names[by_index]!r}; choose with "
                        f"name:{text} or index:{text}")
    if by_name is not None or by_index is not None:
        return by_index if by_name is None else by_name
    raise UserError(f"SCENARIO: {text!r} is neither a scenario name of {d} nor an "
                    f"index; allowed: 0..{last} or a name from summary.csv (or index:N, "
                    "name:NAME)")


def _agreement_text(rep, man: dict) -> str:
    """One line: whether the replay (alone or within its chunk) is the sweep's run."""
    import jax

    from hlip_jax.presentation import tick_report
    where = ("alone" if rep.within == "alone"
             else f"within its chunk of {man['batch']} on {len(jax.devices())} device(s)")
    ran = man.get("jax", {}).get("devices", [])
    note = (f"; the sweep ran on {len(ran)} device(s)"
            if not rep.agreement.identical and ran and len(ran) != len(jax.devices()) else "")
    return f"replay ({where}): {tick_report.verdict(rep.agreement)}{note}"


# --- render: pictures of a stored Cassie scenario (hlip_jax.presentation.render) ---


def _render_parser(sub) -> None:
    """The ``render`` subcommand's arguments."""
    from hlip_jax.presentation.render import camera
    rd = sub.add_parser("render", help="draw one Cassie scenario of a results directory as a "
                        "video", description="Re-simulate one scenario of DIR as `ticks` does "
                        "(within its chunk: the sweep's own run) and draw the robot with "
                        "MuJoCo's renderer, headless (MUJOCO_GL=egl or osmesa, chosen where "
                        "unset), with the path, the H-LIP's planned and the robot's placed "
                        "footsteps, the obstacles' keep-out discs, the scenario's name and the "
                        "time; write FILE: an .mp4 video, a .gif animation or a .png snapshot "
                        "strip (one frame per simulated second).  Nothing else is written; "
                        "needs pip install 'hlip_jax[render]'.")
    _stored_scenario_arguments(rd, "(as `ticks --alone`)")
    rd.add_argument("-o", "--output", metavar="FILE",
                    help="the file to write: .mp4, .gif or .png (default "
                    "DIR/videos/INDEX_NAME.mp4)")
    rd.add_argument("--fps", type=_finite_float, default=30.0,
                    help="frames per second of video (default 30)")
    rd.add_argument("--speed", type=_finite_float, default=1.0,
                    help="simulated seconds per second of video (default 1)")
    rd.add_argument("--camera", choices=camera.CAMERAS, default="track",
                    help="track: follow the pelvis (default); fixed: the whole path from above")
    rd.add_argument("--width", type=int, metavar="PX",
                    help="frame width in pixels, even (default 640; 320 for a .png strip)")
    rd.add_argument("--height", type=int, metavar="PX",
                    help="frame height in pixels, even (default 480; 240 for a .png strip)")
    rd.add_argument("--t0", type=_finite_float, metavar="S",
                    help="start at this plant time [s] (default: the run's start)")
    rd.add_argument("--t1", type=_finite_float, metavar="S",
                    help="end at this plant time [s] (default: the run's end)")
    _cache_options(rd)


@contextlib.contextmanager
def _render_errors():
    """Within the block, :class:`hlip_jax.presentation.render.RenderError` is a user error (exit 2)."""
    from hlip_jax.presentation.render import RenderError
    try:
        yield
    except RenderError as err:
        raise UserError(str(err)) from None


def _render_ready(path: Path) -> str:
    """Check that a file like ``path`` can be written and an OpenGL backend drawn with (made
    ``mujoco.Renderer``'s); returns the backend's name (``MUJOCO_GL``)."""
    from hlip_jax.presentation.render import gl, output
    output.require(path)
    backend = gl.select()
    gl.activate(backend)
    return backend


def _render_output(d: Path, default: Path, given: str | None) -> Path:
    """``render``'s output file: ``given``, or ``default``; a user error for a path into the
    results directory other than its videos/ folder (the results are never written)."""
    from hlip_jax.presentation.render import files
    if given is not None and not given.strip():
        raise UserError("-o: an empty path; allowed: a file name ending in .mp4, .gif or .png")
    out = Path(given) if given else default
    where, results = out.resolve(), d.resolve()
    if where.is_relative_to(results) and not where.is_relative_to(results / files.VIDEOS):
        raise UserError(f"-o {out}: inside the results directory {d}; allowed: a path outside "
                        f"it or under {d / files.VIDEOS} (render changes no result)")
    if out.is_dir():
        raise UserError(f"-o {out}: a directory; allowed: a file name ending in .mp4, .gif or "
                        ".png")
    return out


def cmd_render(args) -> int:
    import time

    from hlip_jax.simulation import execution
    from hlip_jax.sweepio import store
    from hlip_jax.presentation.render import clip, files, motion
    _use_cache(args)
    d, man, index = _stored_scenario(args)
    cfg = store.stored_config(man["configs"], index, d)
    out = _render_output(d, files.video(d, index, cfg.name), args.output)
    strip = out.suffix.lower() == ".png"
    req = clip.Request(fps=args.fps, speed=args.speed, camera=args.camera, t0=args.t0,
                       t1=args.t1, width=args.width or (320 if strip else 640),
                       height=args.height or (240 if strip else 480))
    try:
        execution.check_keeps_ticks(cfg, index)
    except ValueError as err:
        raise UserError(f"SCENARIO: {err}") from None
    with _render_errors():
        clip.check(req)
        backend = _render_ready(out)
        start = time.perf_counter()
        try:
            mo = next(motion.replays(d, [index], alone=args.alone))
        except ValueError as err:
            raise UserError(str(err)) from None
        replayed = time.perf_counter() - start
        w = clip.write(mo, out, req)
    print(f"render: {w.path}")
    print(f"        {w.frames} frames of {w.simulated:.2f} s simulated, drawn and written in "
          f"{w.seconds:.1f} s (MUJOCO_GL={backend}); replay {mo.within} {replayed:.1f} s: "
          f"{mo.verdict}")
    return EXIT_OK


def _render_choice(sw, pattern: str) -> list[int]:
    """Indices of the scenarios of ``sw`` whose names match ``pattern`` (``--render``); a user
    error, before anything runs, for a bad pattern, no match, a plant without a tick log, the
    video library missing or no OpenGL backend."""
    from hlip_jax.simulation import execution
    cfgs = list(sw.scenarios)
    chosen = _matching([c.name for c in cfgs], pattern, "--render")
    for i in chosen:
        try:
            execution.check_keeps_ticks(cfgs[i], i)
        except ValueError as err:
            raise UserError(f"--render: {err}") from None
    with _render_errors():
        _render_ready(Path("check.mp4"))
    return chosen


def _render_runs(out: Path, chosen: list[int]) -> None:
    """The ``--render`` scenarios' videos and snapshot strips, and a strip of the report's
    representative scenario of every path (where its plant keeps a tick log), in
    ``out/videos``; one replay per chunk, one line per file."""
    from hlip_jax import plants
    from hlip_jax.presentation import report
    from hlip_jax.sweepio import store
    from hlip_jax.presentation.render import clip, files, motion
    man = store.read_manifest(out)
    reps = report.representatives(man, store.read_summary(out, man)).values()
    logs = {i for i in reps if plants.load(man["configs"][i]["plant"]).step_with_log}
    with _render_errors():
        for mo in motion.replays(out, sorted(set(chosen) | logs)):
            made = [clip.write(mo, files.strip(out, mo.index, mo.config.name),
                               clip.Request(width=320, height=240))]
            if mo.index in chosen:
                made.insert(0, clip.write(mo, files.video(out, mo.index, mo.config.name),
                                          clip.Request()))
            for w in made:
                print(f"render: {w.path} ({w.frames} frames; replay: {mo.verdict})")


def cmd_list(args) -> int:
    import tomllib
    files = sorted(shipped_dir().glob("*.toml"))
    if not files:
        raise UserError(f"no shipped sweeps found in {shipped_dir()}")
    from hlip_jax.sweepio import sweep
    for f in files:
        try:
            sw = sweep.load_sweep(f)
            n = f"{sw.total:5d} scenarios"
            desc = sw.description
        except sweep.SweepError as err:
            n, desc = "  invalid", str(err)
        except tomllib.TOMLDecodeError as err:  # pragma: no cover - load_sweep wraps it
            n, desc = "  invalid", str(err)
        print(sweep.printable(f"{f.stem:16s} {n}  {desc}"))
    return EXIT_OK


def cmd_show(args) -> int:
    sw = _load(args)
    print(sw.describe())
    if args.scenarios:
        for i, c in enumerate(sw.scenarios):
            print(f"  {i:5d}  {c.name}  (seed {c.seed})")
    return EXIT_OK


def _check_new_file(p: Path, option: str) -> None:
    """UserError, before any work, when the file ``p`` (``option``) cannot be written: its
    folder missing or not writable, or ``p`` a directory."""
    folder = p.parent
    if not str(p).strip():
        raise UserError(f"{option}: an empty path; allowed: a file in an existing, writable folder")
    if p.is_dir():
        raise UserError(f"{option} {p}: a directory; allowed: a file in an existing, writable folder")
    if not folder.is_dir():
        raise UserError(f"{option} {p}: the folder {folder} does not exist; allowed: a file in "
                        "an existing, writable folder")
    if not os.access(folder, os.W_OK | os.X_OK) or (p.exists() and not os.access(p, os.W_OK)):
        raise UserError(f"{option} {p}: not writable; allowed: a file in an existing, writable "
                        "folder")


def _check_not_a_run_file(p: Path, option: str) -> None:
    """UserError when the file ``p`` (``option``) would be written into the ``chunks`` folder
    of a results directory: a model named like a chunk is read as one of that run's chunks
    (and its every reader then refuses the run), so nothing is written there."""
    from hlip_jax.sweepio import store
    folder = p.parent.resolve()
    if folder.name == store.CHUNK_DIR and (folder.parent / store.MANIFEST).exists():
        raise UserError(f"{option} {p}: inside the {store.CHUNK_DIR} folder of the results "
                        f"directory {folder.parent}, which holds that run's chunks only; "
                        "allowed: a file in another folder")


def cmd_bench(args) -> int:
    if not args.duration > 0:
        raise UserError(f"--duration must be > 0 s, got {args.duration}")
    import json

    from hlip_jax.sweepio import bench
    if "warp" in args.physics:
        try:
            plants.tools(bench.PLANT).require_physics("warp")
        except ValueError as err:
            raise UserError(f"--physics: {err}") from None

    if "fused" in args.qp_kernel and "inverse" not in args.qp_linsys:
        raise UserError("--qp-kernel: 'fused' needs the inverse linear solve; allowed: xla, or "
                        "fused together with --qp-linsys inverse")

    if args.json:
        _check_new_file(Path(args.json), "--json")

    def write(rows):
        if args.json:
            Path(args.json).write_text(json.dumps(rows, indent=1))

    write(bench.closed_loop(args.batch, args.duration, args.devices, admm=args.admm,
                            qp_loops=args.qp_loop, physics=args.physics, on_row=write,
                            qp_linsys=args.qp_linsys, qp_rho_start=args.qp_rho_start,
                            qp_kernels=args.qp_kernel, condense=args.condense,
                            terms=args.terms))
    return EXIT_OK


def main(argv=None) -> int:
    """Entry point of the ``hlip-sweep`` console script; returns the exit code."""
    _never_unencodable()
    try:
        import jax  # noqa: F401  (reads its JAX_* switches from the environment when imported)
    except ValueError as err:           # e.g. JAX_ENABLE_X64=maybe
        print(f"{PROG}: error: {ascii(str(err))[1:-1]}; allowed: 1, true, yes, on, 0, false, "
              "no or off (or unset)", file=sys.stderr)     # not _fail: it imports JAX again
        return EXIT_USAGE
    from hlip_jax.presentation.report import ReportError
    from hlip_jax.sweepio.store import StoreError
    from hlip_jax.sweepio.sweep import SweepError

    args = build_parser().parse_args(argv)
    handler = {"run": cmd_run, "report": cmd_report, "list": cmd_list, "show": cmd_show,
               "bench": cmd_bench, "ticks": cmd_ticks, "coverage": cmd_coverage,
               "s2s": cmd_s2s, "identify": cmd_identify, "wbox": cmd_wbox,
               "whull": cmd_whull,
               "render": cmd_render}[args.cmd]
    try:
        xla_flags.apply()    # reproducible GPU runs (before JAX's backend starts)
        _check_environment(args)
        with _sigterm_unwinds(), _stdout_named():
            return handler(args)
    except (UserError, SweepError, StoreError, ReportError) as err:
        return _fail(str(err), EXIT_USAGE)
    except RecursionError:
        return _fail("input nested too deeply to process (recursion limit)", EXIT_USAGE)
    except (xla_flags.PoolTooSmall, xla_flags.FlagsError) as err:
        return _fail(str(err), EXIT_USAGE)
    except BrokenPipeError:     # the reader of stdout went away (`hlip-sweep list | head`)
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_OK
    except OSError as err:
        return _os_error(args, err)
    except KeyboardInterrupt:
        print(f"\n{PROG}: interrupted{_after_stop(args)}", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Terminated as stop:
        name = signal.Signals(stop.signum).name
        print(f"{PROG}: terminated ({name}){_after_stop(args)}", file=sys.stderr)
        return 128 + stop.signum


#: values of MUJOCO_GL that MuJoCo reads without raising when it is imported (on Linux)
MUJOCO_GL_READ = ("egl", "osmesa", "glfw", "glx", "enable", "enabled", "on", "true", "1",
                  "disable", "disabled", "off", "false", "0")


def _check_environment(args) -> None:
    """A user error, in one line, for environment settings that MuJoCo or JAX would refuse
    with a traceback: a ``MUJOCO_GL`` MuJoCo does not know, a ``JAX_PLATFORMS`` naming a
    backend this machine lacks (checked by starting the backend, only where it is set and the
    command computes; a distributed run starts it after ``jax.distributed.initialize``)."""
    gl = os.environ.get("MUJOCO_GL", "").strip().lower()
    if gl and gl not in MUJOCO_GL_READ:
        raise UserError(f"MUJOCO_GL={gl!r}: allowed: egl, osmesa, glfw, glx (or unset)")
    if args.cmd in SIMULATING:
        _check_jax_switches()
    platforms = os.environ.get("JAX_PLATFORMS", "").strip()
    if not platforms or args.cmd in ("list", "show") or getattr(args, "distributed", False):
        return
    import jax
    try:
        jax.devices()
    except RuntimeError as err:
        first = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise UserError(f"JAX_PLATFORMS={platforms!r}: {first}") from None


#: the commands that run the closed loop (``JAX_DISABLE_JIT``, ``JAX_NUMPY_RANK_PROMOTION``)
SIMULATING = ("run", "bench", "ticks", "render")


def _check_jax_switches() -> None:
    """A user error, before any work, for JAX switches the closed loop cannot run with:
    ``JAX_NUMPY_RANK_PROMOTION=raise`` (its arrays broadcast by rank: a traceback) and
    ``JAX_DISABLE_JIT`` on (every operation dispatched one at a time: hours for seconds)."""
    import jax
    rank = os.environ.get("JAX_NUMPY_RANK_PROMOTION")
    if rank is not None and jax.config.jax_numpy_rank_promotion not in ("allow", "warn"):
        raise UserError(f"JAX_NUMPY_RANK_PROMOTION={rank!r}: the closed loop promotes ranks; "
                        "allowed: allow or warn (or unset)")
    off = os.environ.get("JAX_DISABLE_JIT")
    if off is not None and jax.config.jax_disable_jit:
        raise UserError(f"JAX_DISABLE_JIT={off!r}: the closed loop needs compilation (without "
                        "it a run takes hours); allowed: 0, false, no or off (or unset)")


def _after_stop(args) -> str:
    """What an interrupted command leaves: `run` keeps its finished chunks and resumes; the
    other commands simulate nothing and are simply run again."""
    if args.cmd == "run":
        return "; finished chunks are kept: rerun with --resume"
    return f"; run `{PROG} {args.cmd}` again"


def _never_unencodable() -> None:
    """Printing never raises on a character the terminal's encoding lacks (``ü`` in a path
    under ``PYTHONIOENCODING=ascii``): it is written as an escape (``\\xfc``)."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.reconfigure(errors="backslashreplace")
        except (AttributeError, ValueError, OSError):   # not a text stream we may change
            pass


def _fail(msg: str, code: int) -> int:
    """Print ``msg`` as the one error line (newlines folded) and return ``code``."""
    from hlip_jax.sweepio.sweep import printable
    print(f"{PROG}: error: {printable(' '.join(msg.splitlines()))}", file=sys.stderr)
    return code


def _os_error(args, err: OSError) -> int:
    """A file-system error: during ``run`` the run is incomplete (exit 1: finished chunks are
    kept, resume once the cause is fixed); elsewhere exit 2."""
    folder = getattr(args, "dir", None) or getattr(args, "out", None)
    where = f"{err.filename}: " if err.filename else f"{folder}: " if folder else ""
    what = f"{where}{err.strerror or err}"
    if args.cmd == "run":
        return _fail(f"cannot write the results: {what}; finished chunks are kept: fix this and "
                     f"rerun with --resume", EXIT_INCOMPLETE)
    return _fail(what, EXIT_USAGE)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
