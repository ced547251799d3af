"""Sweep files: TOML text → validated list of :class:`hlip_jax.simulation.config.ScenarioConfig`.

A sweep file (read with :mod:`tomllib`) has seven top-level keys::

    name = "paper"                       # optional; default: the file's stem
    description = "..."                  # optional free text

    [base]                               # settings shared by every scenario
    plant = "hlip"                       # ScenarioConfig fields: plant, seed, duration
    duration = 30.0
    [base.hlip]    z0 = 0.8 ...          # HLIPConfig
    [base.mpc]     alpha = 0.01 ...      # MPCConfig
    [base.gain]    type = "lqr" ...      # GainConfig
    [base.disturbance] noise_p = 0.0 ... # DisturbanceConfig
    [[base.disturbance.pushes]]          # PushConfig, a list
    [[base.obstacles]]                   # ObstacleConfig, a list
    [base.path]                          # default path parameters for every [[paths]] entry

    [[paths]]                            # one entry per reference path (at least one)
    shape = "circle"                     # a key of hlip_jax.core.paths.SHAPES
    name = "circle-trap"                 # optional; default: the shape (made unique)
    radius = 2.0                         # every other key is a parameter of that shape
    [paths.overrides]                    # optional: base settings for this path only
    obstacles = [{x = 3.0, y = 0.5, radius = 0.3}]

    [grid.product]                       # Cartesian product over these axes
    "mpc.alpha" = [0.01, 0.1]
    "gain.type" = ["lqr", "deadbeat"]
    [[grid.zip]]                         # one more axis: these lists are walked together
    "disturbance.pushes.0.force" = [100.0, 200.0]
    "disturbance.pushes.0.time"  = [5.0, 10.0]

    [impl]                               # optional: hlip_jax.runtime.impl, config.ImplConfig
    profile = "auto"                     # GPU settings on a GPU, the sweep's own on a CPU
    physics = "jax"                      # any implementation field set here wins

    [analysis]                           # optional: hlip_jax.analysis.settings
    splits = ["seed", "path", "speed"]   # held-out splits of coverage.csv
    q = 0.9                              # level of the calibrated sets
    warmup = 4                           # start-up steps not counted

Grid field names are dotted paths into the scenario: ``seed``, ``duration``, ``plant``,
``hlip.*``, ``mpc.*``, ``gain.*``, ``disturbance.*``, ``disturbance.pushes.<i>.*``,
``obstacles.<i>.*`` (the list entry must exist in the base or the path's overrides) and
``path.<param>`` (a parameter of the path's shape).  The scenarios are, path-major, every path
× every point of the product of all axes (a zip group is one axis).

Validation happens here, before anything is compiled: an unknown key (with the closest known
key, via :mod:`difflib`), a wrong type, NaN/inf, a value outside the range declared in
:mod:`hlip_jax.simulation.config` (or in the path's parameter spec), an empty grid axis, zip lists of
unequal length — each raises :class:`SweepError` whose message names the field, the value and
what is allowed.  Validation is complete here, so ``hlip-sweep show`` rejects whatever ``run``
would, before any compile:

* Names: the sweep name (a directory name) and path names (figure file names) are 1–100 and
  1–64 characters of ASCII letters, digits, spaces and ``. _ - + = , @ ( )``, never starting with
  ``.`` (so never ``.`` or ``..``); two path names may not give the same file slug
  (:func:`file_slug`).
* Static settings (:data:`STATIC_FIELDS`: the plant, the MPC horizon and the QP settings) take
  one value across the sweep: not swept over several values, not overridden for one path.
* Cross-field checks per scenario: step limits, durations of at least two steps, Cassie's
  disturbances, a push starting before the run ends, no obstacle covering the path's start, a
  path's x0, y0 and waypoints within :data:`MAX_PATH_OFFSET` (1,000 m) of the origin.
* Sizes: fewer than :data:`MAX_SCENARIOS` scenarios, counted from the axes without building
  them; tables and arrays at most :data:`MAX_DEPTH` deep; no byte-order mark.  A grid larger
  than :data:`EAGER_SCENARIOS` is validated on a covering subset (:func:`_validation_points`:
  every value of every axis, every combination of the axes that take part in cross-field
  checks) and its scenarios are built on first use of :attr:`Sweep.scenarios`.

Decisions:

* Seeds.  A scenario's seed is derived from the configured seed and the scenario's name,
  ``crc32(f"{seed}:{name}") mod 2³¹``, so it depends on nothing but the scenario itself (not on
  its index, the chunk size or which other scenarios are in the sweep): resuming, ``--limit`` or
  reordering cannot change a scenario's noise.  Sweeping ``seed`` gives replicates.
* Integers are accepted for float fields; booleans are never numbers.
* ``swept`` of each scenario holds ``{"path": <path name>, <grid field>: <value>, ...}``.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import hashlib
import itertools
import json
import math
import os
import re
import tomllib
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from hlip_jax.simulation import config as C
from hlip_jax.runtime import impl as impl_mod
from hlip_jax import plants
from hlip_jax.analysis import settings as analysis_settings
from hlip_jax.analysis.settings import AnalysisConfig
from hlip_jax.core.fields import FMT_MAX_CHARS  # noqa: F401  (the messages' cap)
from hlip_jax.core.fields import show_value as _fmt

__all__ = [
    "SweepError", "Axis", "Sweep", "load_sweep", "parse_sweep", "config_to_dict",
    "config_hash", "dicts_hash", "json_digest", "as_written", "data_files", "file_digest", "file_digests",
    "path_param_spec", "known_shapes", "MAX_SCENARIOS", "file_slug",
    "STATIC_FIELDS",
]

#: a grid of this many scenarios or more is a mistake, not a sweep (allowed: fewer)
MAX_SCENARIOS = 10_000_000
#: grids up to this size are expanded and validated scenario by scenario at parse time; larger
#: ones are validated on a covering subset (:func:`_validation_points`) and expanded on demand
EAGER_SCENARIOS = 5_000
#: values one grid axis may hold: each is validated on its own (about 50 µs each), so an axis of
#: millions would keep `show` busy for minutes
MAX_AXIS_VALUES = 100_000
#: entries a list field (``obstacles``, ``disturbance.pushes``) may hold: each one is compiled
#: into the closed loop (256 obstacles compile in about 40 s on a CPU, 10,000 would take hours)
MAX_LIST_ITEMS = 256
#: deepest nesting of tables and arrays a sweep file may have (a real one needs about 6)
MAX_DEPTH = 32
#: longest sweep name (it names the results directory) and path name (it names figure files)
MAX_NAME_LEN, MAX_PATH_NAME_LEN = 100, 64
#: characters a sweep or path name may hold (it becomes a file or directory name)
_NAME_RE = re.compile(r"[A-Za-z0-9 _.+=,@()-]+")
_NAME_ALLOWED = "ASCII letters, digits, spaces and . _ - + = , @ ( ) (no slashes)"
#: settings that are array shapes or compiled solver settings (:func:`hlip_jax.simulation.arrays.build`
#: requires them equal across a batch): one value per sweep
STATIC_FIELDS = C.STATIC_FIELDS

TOP_KEYS = ("name", "description", "base", "paths", "grid", "analysis", "impl")
GRID_KEYS = ("product", "zip")
PATH_RESERVED = ("shape", "name", "overrides")
# ScenarioConfig fields a sweep file may set in [base] / [paths.overrides]; name and swept are
# generated, path comes from [[paths]] (+ [base.path] defaults).
BASE_EXCLUDE = ("name", "swept", "path")
# list-valued config fields and the dataclass of their entries
LIST_ITEMS = {"pushes": C.PushConfig, "obstacles": C.ObstacleConfig}


class SweepError(ValueError):
    """A sweep file (or a command-line override) is invalid.  ``str(err)`` is one clear line."""


# --------------------------------------------------------------------------------------------
# path parameter specs (from hlip_jax.core.paths)


def known_shapes() -> tuple[str, ...]:
    """Names of the path shapes :mod:`hlip_jax.core.paths` provides."""
    from hlip_jax.core import paths
    return tuple(paths.SHAPES)


def path_param_spec(shape: str) -> dict[str, dict]:
    """Parameter spec of ``shape``: ``{param: {"default", "lo", "hi", "doc", "unit", "choices"}}``.

    Read from :mod:`hlip_jax.core.paths` (``PARAM_SPECS[shape]``); missing keys get neutral values.
    """
    from hlip_jax.core import paths
    raw = paths.PARAM_SPECS[shape]
    out = {}
    for k, v in raw.items():
        d = dict(v) if isinstance(v, dict) else dict(dataclasses.asdict(v)) if dataclasses.is_dataclass(v) else {"default": v}
        d.setdefault("lo", -math.inf)
        d.setdefault("hi", math.inf)
        d.setdefault("doc", "")
        d.setdefault("unit", "")
        d.setdefault("choices", None)
        out[k] = d
    return out


# --------------------------------------------------------------------------------------------
# scalar checks


def printable(text: str) -> str:
    """``text`` with every control character but newline and tab written as an escape
    (``\\x1b``): a sweep's name, description or keys never reach a terminal as raw control
    sequences."""
    return "".join(c if c in "\n\t" or c.isprintable() else repr(c)[1:-1] for c in str(text))


def _tname(v) -> str:
    return {bool: "boolean", int: "integer", float: "float", str: "string", list: "array",
            dict: "table"}.get(type(v), type(v).__name__)


def _allowed(meta: dict, kind: str) -> str:
    if meta.get("choices"):
        return "one of " + ", ".join(repr(c) for c in meta["choices"])
    lo, hi = meta.get("lo", -math.inf), meta.get("hi", math.inf)
    unit = f" [{meta['unit']}]" if meta.get("unit") else ""
    what = "an integer" if kind == "int" else "a finite number"
    def num(x):
        return f"{int(x)}" if kind == "int" or float(x).is_integer() and abs(x) < 1e15 else f"{x:g}"
    if math.isinf(lo) and math.isinf(hi):
        return what + unit
    if math.isinf(hi):
        return f"{what} >= {num(lo)}{unit}"
    if math.isinf(lo):
        return f"{what} <= {num(hi)}{unit}"
    return f"{what} in [{num(lo)}, {num(hi)}]{unit}"


def check_scalar(value, kind: str, meta: dict, where: str):
    """Validate one scalar against its type (``"float" | "int" | "str" | "bool"``) and metadata.

    Returns the value coerced to the field type (int → float for float fields).
    """
    doc = f" ({meta['doc']})" if meta.get("doc") else ""
    if kind == "str":
        if not isinstance(value, str):
            raise SweepError(f"{where}: expected a string, got {_tname(value)} {_fmt(value)}; "
                             f"allowed: {_allowed(meta, kind)}")
        if meta.get("choices") and value not in meta["choices"]:
            near = difflib.get_close_matches(value, list(meta["choices"]), n=1)
            hint = f"; did you mean {near[0]!r}?" if near else ""
            raise SweepError(f"{where}: {_fmt(value)} is not allowed; allowed: "
                             f"{_allowed(meta, kind)}{hint}")
        return value
    if kind == "bool":
        if not isinstance(value, bool):
            raise SweepError(f"{where}: expected true or false, got {_tname(value)} {_fmt(value)}")
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SweepError(f"{where}: expected {'an integer' if kind == 'int' else 'a number'}, "
                         f"got {_tname(value)} {_fmt(value)}; allowed: {_allowed(meta, kind)}{doc}")
    if isinstance(value, float) and not math.isfinite(value):
        raise SweepError(f"{where}: {value} is not a finite number; allowed: "
                         f"{_allowed(meta, kind)}{doc}")
    if kind == "int":
        if isinstance(value, float):
            if not value.is_integer():
                raise SweepError(f"{where}: expected an integer, got {value:g}; allowed: "
                                 f"{_allowed(meta, kind)}{doc}")
            value = int(value)
    else:
        try:
            value = float(value)
        except OverflowError:       # an integer beyond float's range
            raise SweepError(f"{where}: an integer of {len(str(abs(value)))} digits is out of "
                             f"range; allowed: {_allowed(meta, kind)}{doc}") from None
    lo, hi = meta.get("lo", -math.inf), meta.get("hi", math.inf)
    if not (lo <= value <= hi):
        raise SweepError(f"{where}: {_fmt(value)} is out of range; allowed: "
                         f"{_allowed(meta, kind)}{doc}")
    if meta.get("choices") and value not in meta["choices"]:
        raise SweepError(f"{where}: {_fmt(value)} is not allowed; allowed: {_allowed(meta, kind)}")
    return value


def _unknown_key(key: str, known, where: str) -> SweepError:
    known = list(known)
    near = difflib.get_close_matches(str(key), known, n=1, cutoff=0.6)
    hint = f"; did you mean {near[0]!r}?" if near else ""
    loc = f"{where}.{key}" if where else str(key)
    return SweepError(f"{loc}: unknown key{hint} (known keys: {', '.join(known)})")


# --------------------------------------------------------------------------------------------
# dataclass schema walking


def _fields(cls, exclude=()) -> dict[str, dataclasses.Field]:
    return {f.name: f for f in dataclasses.fields(cls) if f.name not in exclude}


def _nested_cls(f: dataclasses.Field):
    """The dataclass of a nested config field, or None for scalars."""
    if f.default_factory is not dataclasses.MISSING:
        v = f.default_factory()
        if dataclasses.is_dataclass(v):
            return type(v)
    return None


def _kind(f: dataclasses.Field) -> str:
    t = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", str(f.type))
    return {"float": "float", "int": "int", "str": "str", "bool": "bool"}.get(t, t)


def _build(cls, raw, where: str, exclude=()):
    """Validate the table ``raw`` into ``cls`` (missing keys take the dataclass defaults)."""
    if not isinstance(raw, dict):
        raise SweepError(f"{where}: expected a table, got {_tname(raw)} {_fmt(raw)}")
    fields = _fields(cls, exclude)
    for key in raw:
        if key not in fields:
            raise _unknown_key(key, fields, where)
    kwargs = {}
    for name, f in fields.items():
        if name not in raw:
            continue
        v, loc = raw[name], f"{where}.{name}"
        if name in LIST_ITEMS:
            if not isinstance(v, list):
                raise SweepError(f"{loc}: expected an array of tables, got {_tname(v)} {_fmt(v)}")
            if len(v) > MAX_LIST_ITEMS:
                raise SweepError(f"{loc}: {len(v)} entries; allowed: at most {MAX_LIST_ITEMS} "
                                 "(each is compiled into the closed loop)")
            kwargs[name] = tuple(_build(LIST_ITEMS[name], item, f"{loc}.{i}")
                                 for i, item in enumerate(v))
        elif (sub := _nested_cls(f)) is not None:
            kwargs[name] = _build(sub, v, loc)
        else:
            kwargs[name] = check_scalar(v, _kind(f), dict(f.metadata), loc)
    return cls(**kwargs)


def _check_path_params(shape: str, params: dict, where: str, loc_of=None) -> dict:
    """Validate path parameters against the shape's spec; ``loc_of(k)`` names key k in
    messages (default ``where.k``)."""
    loc_of = loc_of or (lambda k: f"{where}.{k}")
    spec = path_param_spec(shape)
    out = {}
    for k, v in params.items():
        if k not in spec:
            raise _unknown_key(k, list(spec) + list(PATH_RESERVED), where)
        meta = spec[k]
        kind = meta.get("kind") or "float"
        if kind == "points":
            from hlip_jax.core import paths
            try:
                paths.validate_params(shape, {k: v})
            except (ValueError, TypeError) as err:
                raise SweepError(f"{loc_of(k)}: {err}") from None
            out[k] = [[float(a) for a in pt] for pt in v]
            continue
        out[k] = check_scalar(v, kind, meta, loc_of(k))
    return out


def _cross_checks(cfg: C.ScenarioConfig, where: str) -> None:
    """Checks that involve several fields (single-field ranges live in config.py)."""
    m = cfg.mpc
    if m.step_width_min > m.step_width_max:
        raise SweepError(f"{where}: mpc.step_width_min: {m.step_width_min:g} exceeds "
                         f"mpc.step_width_max = {m.step_width_max:g}; allowed: min <= max")
    if m.step_length_min > m.step_length_max:
        raise SweepError(f"{where}: mpc.step_length_min: {m.step_length_min:g} exceeds "
                         f"mpc.step_length_max = {m.step_length_max:g}; allowed: min <= max")
    problem = plants.check(cfg)
    if problem:
        raise SweepError(f"{where}: {problem}")
    T = cfg.hlip.t_ssp + cfg.hlip.t_dsp
    if cfg.duration < 2 * T:
        raise SweepError(f"{where}: duration: {cfg.duration:g} s is shorter than two walking steps "
                         f"(2 × (hlip.t_ssp + hlip.t_dsp) = {2 * T:g} s); allowed: >= {2 * T:g}")
    for i, p in enumerate(cfg.disturbance.pushes):
        if p.time >= cfg.duration:
            raise SweepError(f"{where}: disturbance.pushes.{i}.time: {p.time:g} s is at or after "
                             f"the end of the run (duration = {cfg.duration:g} s), so the push "
                             f"never acts; allowed: 0 <= time < {cfg.duration:g}")
    if cfg.obstacles:
        _check_start_clear(cfg, where)
    _check_path_origin(cfg, where)
    _check_s2s(cfg, where)
    if m.robust:
        _check_tube(cfg, where)


#: how far from the world origin a path may start or place a waypoint [m]: the closed loop
#: computes in absolute coordinates, and the same path moved farther out tracks measurably
#: differently (at 2,000 m a cardioid's max_track_err is 0.196 m instead of 0.129 m)
MAX_PATH_OFFSET = 1000.0


def _check_path_origin(cfg: C.ScenarioConfig, where: str) -> None:
    """The path's x0, y0 and waypoints within :data:`MAX_PATH_OFFSET` of the origin."""
    params = cfg.path.params
    coords = [(k, params[k]) for k in ("x0", "y0") if k in params]
    coords += [(f"waypoints.{i}", max(abs(a) for a in pt))
               for i, pt in enumerate(params.get("waypoints") or ())]
    for key, v in coords:
        if abs(v) > MAX_PATH_OFFSET:
            raise SweepError(f"{where}: path.{key}: {v:g} m from the origin; allowed: within "
                             f"±{MAX_PATH_OFFSET:g} m (results computed farther out differ from "
                             "the same path's nearer the origin: rounding)")


def _check_s2s(cfg: C.ScenarioConfig, where: str) -> None:
    """An identified S2S model is read from s2s.file, fitted at this scenario's H-LIP cadence
    (z0, t_ssp, t_dsp); the H-LIP model reads no file."""
    s, h = cfg.s2s, cfg.hlip
    if s.model == "hlip":
        if s.file:
            raise SweepError(f"{where}: s2s.file: {_fmt(s.file)} is read with s2s.model = "
                             "'identified' only; allowed with s2s.model = 'hlip': ''")
        return
    from hlip_jax.core import s2s_model
    try:
        model = s2s_model.read(s.file)
    except ValueError as err:
        raise SweepError(f"{where}: s2s.file: {err}") from None
    want = (h.z0, h.t_ssp, h.t_dsp)
    if any(abs(a - b) > 1e-9 for a, b in zip(model.cadence, want)):
        raise SweepError(f"{where}: s2s.file: fitted at (z0, t_ssp, t_dsp) = "
                         f"{tuple(round(c, 6) for c in model.cadence)}; allowed: the scenario's "
                         f"hlip values {tuple(round(c, 6) for c in want)}")


def _check_tube(cfg: C.ScenarioConfig, where: str) -> None:
    """A robust MPC needs a bounded E (a Schur-stable A + B K on [c, p, v]), one gain in both
    planes for a heading-frame W, and non-empty tightened step limits (hlip_jax.core.robust)."""
    from hlip_jax.simulation import arrays
    from hlip_jax.core import robust
    m = cfg.mpc
    if m.mode != "tube":
        raise SweepError(f"{where}: mpc.mode: {m.mode!r} with mpc.robust = true; allowed: 'tube' "
                         "(the tube guarantee needs the plan to start from the H-LIP's own state)")
    if not cfg.gain.with_position:
        raise SweepError(f"{where}: gain.with_position: false with mpc.robust = true; allowed: "
                         "true (without the c term the COM position error has no bounded E)")
    _check_w_shape(m, where)
    try:
        A, B = arrays.s2s_of(cfg)
        t = arrays.tube_of(cfg, A, B)
        robust.check_limits(t, m.step_length_min, m.step_length_max, m.step_width_min,
                            m.step_width_max)
    except ValueError as err:
        raise SweepError(f"{where}: {err}") from None


def _check_w_shape(m: C.MPCConfig, where: str) -> None:
    """A hull W takes its points from mpc.w_hull_file (readable, well formed) and no box
    half-widths; a box W reads no file."""
    box = [f"w_{q}_{i}" for i in (1, 2) for q in "cpv"]
    if m.w_shape == "box":
        if m.w_hull_file:
            raise SweepError(f"{where}: mpc.w_hull_file: {_fmt(m.w_hull_file)} is read with "
                             "mpc.w_shape = 'hull' only; allowed with w_shape = 'box': ''")
        return
    for f in box:
        if getattr(m, f) != 0.0:
            raise SweepError(f"{where}: mpc.{f}: {getattr(m, f):g} with mpc.w_shape = 'hull' "
                             "(the hull's points are W); allowed: 0")
    from hlip_jax.core import robust
    try:
        robust.read_hull(m.w_hull_file)
    except ValueError as err:
        raise SweepError(f"{where}: mpc.w_hull_file: {err}") from None


@functools.lru_cache(maxsize=256)
def _path_start(shape: str, params_json: str) -> tuple[float, float]:
    """(x, y) of a path at t = 0 [m], where the robot stands at the start."""
    from hlip_jax.core import paths
    p = paths.make_path(shape, **json.loads(params_json))
    return float(p.x[0]), float(p.y[0])


def _check_start_clear(cfg: C.ScenarioConfig, where: str) -> None:
    """No obstacle's keep-out disc (radius + margin, what the MPC keeps the COM out of) may
    cover the path's start: the robot would begin inside it (negative clearance from the first
    step, or a plan with no feasible step)."""
    sx, sy = _path_start(cfg.path.shape, json.dumps(cfg.path.params, sort_keys=True))
    for i, o in enumerate(cfg.obstacles):
        d = math.hypot(o.x - sx, o.y - sy)
        if d < o.radius + o.margin:
            raise SweepError(f"{where}: obstacles.{i}: the disc at ({o.x:g}, {o.y:g}) with radius "
                             f"{o.radius:g} m + margin {o.margin:g} m covers the path's start "
                             f"({sx:g}, {sy:g}), where the robot stands at t = 0 (distance "
                             f"{d:.3g} m); allowed: radius + margin < {d:.3g} m or the centre "
                             "further from the start")


# --------------------------------------------------------------------------------------------
# sweep structure


@dataclass(frozen=True)
class Axis:
    """One grid axis: one field (product) or several fields walked together (zip)."""
    fields: tuple[str, ...]
    values: tuple[tuple, ...]   # values[j] = the j-th point: one value per field
    zipped: bool = False

    def __len__(self) -> int:
        return len(self.values)


@dataclass(frozen=True)
class Sweep:
    """A validated, expanded sweep."""
    name: str
    description: str
    source: str                       # file the text came from ("<string>" otherwise)
    text: str                         # the sweep file text, verbatim
    paths: tuple[str, ...]            # path names in order
    axes: tuple[Axis, ...]
    total: int                        # scenarios before --limit
    n_scenarios: int                  # scenarios after --limit
    #: the ``[analysis]`` table (:mod:`hlip_jax.analysis.settings`): splits, methods, q, warm-up
    analysis: AnalysisConfig
    #: the ``[impl]`` table's profile (:mod:`hlip_jax.runtime.impl`) and the implementation fields the
    #: file (or ``--physics``) sets itself, which a profile never changes
    impl_profile: str
    impl_explicit: frozenset
    #: builds the scenarios (a large grid is counted at parse time and built on demand)
    expand: Callable[[], tuple] = dataclasses.field(repr=False, compare=False)

    @functools.cached_property
    def scenarios(self) -> tuple[C.ScenarioConfig, ...]:
        """The expanded, validated scenarios (built on first use)."""
        return tuple(self.expand())

    @property
    def swept_fields(self) -> tuple[str, ...]:
        return tuple(f for a in self.axes for f in a.fields)

    def describe(self) -> str:
        """Human-readable grid summary (used by ``hlip-sweep show``)."""
        lines = [f"sweep {self.name!r} ({self.source})"]
        if self.description:
            lines.append(f"  {self.description}")
        lines.append(f"  paths ({len(self.paths)}): {', '.join(self.paths)}")
        if not self.axes:
            lines.append("  grid: none (one scenario per path)")
        for a in self.axes:
            kind = "zip" if a.zipped else "product"
            shown = a.values if len(a) <= 12 else a.values[:8] + a.values[-2:]
            if len(a.fields) == 1:
                texts = [_fmt(as_written(v[0])) for v in shown]
            else:
                texts = ["(" + ", ".join(_fmt(as_written(x)) for x in v) + ")" for v in shown]
            if len(shown) < len(a):
                texts[8:8] = [f"... ({len(a) - 10} more)"]
            vals = ", ".join(texts)
            lines.append(f"  axis [{kind}] {', '.join(a.fields)}: {len(a)} values: {vals}")
        n_grid = math.prod(len(a) for a in self.axes) if self.axes else 1
        lines.append(f"  scenarios: {len(self.paths)} paths x {n_grid} grid points = {self.total}"
                     + (f" (limited to {self.n_scenarios})" if self.n_scenarios != self.total
                        else ""))
        return printable("\n".join(lines))


def _resolve_field(field: str, where: str) -> list:
    """Split a dotted grid field into keys, checking it against the config schema.

    Returns the key list (list indices as int).  ``path.<param>`` is checked later against
    each path's shape spec.
    """
    if not isinstance(field, str) or not field:
        raise SweepError(f"{where}: grid field names must be non-empty strings")
    parts = field.split(".")
    if parts[0] == "path":
        if len(parts) != 2 or not parts[1]:
            raise SweepError(f"{where}.{field!r}: path fields are 'path.<parameter>' "
                             f"(e.g. 'path.peak_speed')")
        if parts[1] in PATH_RESERVED:
            raise SweepError(f"{where}.{field!r}: {parts[1]!r} cannot be swept; add [[paths]] "
                             f"entries instead")
        return parts
    if parts[0] == "base" and len(parts) > 1:
        raise SweepError(f"{where}.{field!r}: grid fields name a scenario's fields without "
                         f"'base.'; did you mean {'.'.join(parts[1:])!r}?")
    if parts[0] == "impl" or (parts[0] == "cassie" and len(parts) == 2
                              and parts[1] in C.IMPL_FIELDS):
        raise SweepError(f"{where}.{field!r}: an implementation setting cannot be swept (one "
                         f"value per sweep, in its [impl] table)")
    cls, keys, prefix = C.ScenarioConfig, [], ""
    i = 0
    while i < len(parts):
        key = parts[i]
        fields = _fields(cls, BASE_EXCLUDE if cls is C.ScenarioConfig else ())
        if key not in fields:
            known = [prefix + k for k in fields] + (["path.<parameter>"] if not prefix else [])
            near = difflib.get_close_matches(prefix + key, known, n=1, cutoff=0.6)
            hint = f"; did you mean {near[0]!r}?" if near else ""
            if not field.isascii():     # a look-alike letter (Cyrillic а) shown as itself
                odd = "".join(dict.fromkeys(c for c in field if not c.isascii()))
                hint = f" (holds {ascii(odd)}, not ASCII){hint}"
            raise SweepError(f"{where}.{ascii(field) if not field.isascii() else repr(field)}: "
                             f"unknown grid field{hint} "
                             f"(known here: {', '.join(known)})")
        f = fields[key]
        keys.append(key)
        if key in LIST_ITEMS:
            if i + 1 >= len(parts) or not (parts[i + 1].isascii() and parts[i + 1].isdigit()):
                first = next(iter(_fields(LIST_ITEMS[key])))
                raise SweepError(f"{where}.{field!r}: list field '{prefix}{key}' needs an index "
                                 f"and a member, e.g. '{prefix}{key}.0.{first}'")
            keys.append(int(parts[i + 1]))
            cls, prefix, i = LIST_ITEMS[key], f"{prefix}{key}.{parts[i + 1]}.", i + 2
            if i >= len(parts):
                raise SweepError(f"{where}.{field!r}: name a member of the list entry, e.g. "
                                 f"'{prefix}{next(iter(_fields(cls)))}'")
            continue
        sub = _nested_cls(f)
        if sub is not None:
            if i + 1 >= len(parts):
                raise SweepError(f"{where}.{field!r}: '{prefix}{key}' is a table; sweep one of its "
                                 f"fields, e.g. '{prefix}{key}.{next(iter(_fields(sub)))}'")
            cls, prefix = sub, f"{prefix}{key}."
        elif i + 1 < len(parts):
            raise SweepError(f"{where}.{field!r}: '{prefix}{key}' is a value, not a table")
        i += 1
    return keys


def _field_meta(field: str):
    """(kind, metadata) of a non-path grid field, for checking its values up front."""
    cls = C.ScenarioConfig
    parts = field.split(".")
    i = 0
    while True:
        key = parts[i]
        f = _fields(cls)[key]
        if key in LIST_ITEMS:
            cls, i = LIST_ITEMS[key], i + 2
            continue
        sub = _nested_cls(f)
        if sub is None:
            return _kind(f), dict(f.metadata)
        cls, i = sub, i + 1


def _parse_axes(grid, where="grid") -> tuple[Axis, ...]:
    if grid is None:
        return ()
    if not isinstance(grid, dict):
        raise SweepError(f"{where}: expected a table with 'product' and/or 'zip', got {_tname(grid)}")
    for k in grid:
        if k not in GRID_KEYS:
            raise _unknown_key(k, GRID_KEYS, where)
    axes: list[Axis] = []
    seen: dict[str, str] = {}

    def add_field(field, loc):
        # the resolved keys, so that aliases of one field ("pushes.0" and "pushes.00") count once
        key = ".".join(map(str, _resolve_field(field, loc)))
        if key in seen:
            raise SweepError(f"{loc}.{field!r}: field is swept twice (also in {seen[key]})")
        seen[key] = f"{loc}.{field!r}"

    def check_values(field, vals, loc):
        if not isinstance(vals, list):
            raise SweepError(f"{loc}.{field!r}: expected an array of values, got "
                             f"{_tname(vals)} {_fmt(vals)}")
        if len(vals) == 0:
            raise SweepError(f"{loc}.{field!r}: empty grid axis; give at least one value")
        if len(vals) > MAX_AXIS_VALUES:
            raise SweepError(f"{loc}.{field!r}: {len(vals)} values; allowed: at most "
                             f"{MAX_AXIS_VALUES} per axis (every value is validated)")
        if field.split(".")[0] != "path":
            kind, meta = _field_meta(field)
            vals = [check_scalar(v, kind, meta, f"{loc}.{field!r}[{j}]") for j, v in enumerate(vals)]
        else:
            for j, v in enumerate(vals):
                if isinstance(v, (list, dict)) or (isinstance(v, float) and not math.isfinite(v)):
                    raise SweepError(f"{loc}.{field!r}[{j}]: {_fmt(v)} is not a finite scalar")
        return vals

    def check_distinct(rows, loc):
        first: dict = {}
        for j, dup in enumerate(rows):
            if first.setdefault(_point_key(dup), j) != j:
                raise SweepError(f"{loc}: repeated grid point {_fmt(list(dup)) if isinstance(dup, tuple) else _fmt(dup)}; "
                                 f"each grid point must be distinct (equal numbers are one point)")

    prod = grid.get("product", {})
    if not isinstance(prod, dict):
        raise SweepError(f"{where}.product: expected a table of field = [values], got {_tname(prod)}")
    for field, vals in prod.items():
        loc = f"{where}.product"
        add_field(field, loc)
        vals = check_values(field, vals, loc)
        check_distinct(vals, f"{loc}.{field!r}")
        axes.append(Axis((field,), tuple((v,) for v in vals)))
    zips = grid.get("zip", [])
    if isinstance(zips, dict):
        zips = [zips]
    if not isinstance(zips, list):
        raise SweepError(f"{where}.zip: expected an array of tables ([[grid.zip]]), got {_tname(zips)}")
    for zi, z in enumerate(zips):
        loc = f"{where}.zip.{zi}"
        if not isinstance(z, dict) or not z:
            raise SweepError(f"{loc}: expected a non-empty table of field = [values]")
        cols, lens = [], {}
        for field, vals in z.items():
            add_field(field, loc)
            vals = check_values(field, vals, loc)
            cols.append(vals)
            lens[field] = len(vals)
        if len(set(lens.values())) != 1:
            desc = ", ".join(f"{f!r}: {n}" for f, n in lens.items())
            raise SweepError(f"{loc}: zipped axes must have equal lengths, got {desc}")
        rows = list(zip(*cols))
        check_distinct(rows, f"{loc} ({', '.join(map(repr, z))})")
        axes.append(Axis(tuple(z), tuple(rows), zipped=True))
    return tuple(axes)


def _set_dotted(d: dict, keys: list, value, where: str) -> None:
    """Set ``d[k0][k1]...`` (creating tables; list entries must exist)."""
    cur = d
    for j, k in enumerate(keys[:-1]):
        if isinstance(k, int):
            if not isinstance(cur, list) or k >= len(cur):
                n = len(cur) if isinstance(cur, list) else 0
                raise SweepError(f"{where}: list '{'.'.join(map(str, keys[:j]))}' has {n} "
                                 f"entr{'y' if n == 1 else 'ies'}; index {k} does not exist "
                                 f"(allowed: 0..{n - 1})" if n else
                                 f"{where}: list '{'.'.join(map(str, keys[:j]))}' is empty in "
                                 f"the base settings; index {k} does not exist")
            cur = cur[k]
        else:
            nxt = keys[j + 1]
            if k not in cur:
                cur[k] = [] if isinstance(nxt, int) else {}
            cur = cur[k]
    cur[keys[-1]] = value


def _deep_merge(base: dict, over: dict) -> dict:
    out = json.loads(json.dumps(base))
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _deep_merge(out[k], v)
        else:
            out[k] = json.loads(json.dumps(v))
    return out


def _with_gait(raw: dict, where: str) -> dict:
    """``raw`` with its plant presets' fields filled in (the Cassie gait,
    :func:`hlip_jax.plants.with_presets`)."""
    try:
        return plants.with_presets(raw)
    except ValueError as err:
        raise SweepError(f"{where}: {err}") from None


def _derive_seed(seed: int, name: str) -> int:
    return zlib.crc32(f"{seed}:{name}".encode()) & 0x7FFFFFFF


def _value_label(v) -> str:
    """A grid value in a scenario's name: %g for a float when it names the value exactly, else
    its full repr (two values that %g prints alike get different names)."""
    if isinstance(v, float):
        short = f"{v:g}"
        return short if float(short) == v else repr(v)
    return str(v)


def parse_sweep(text: str, *, source: str = "<string>", plant: str | None = None,
                duration: float | None = None, limit: int | None = None,
                default_name: str = "sweep", physics: str | None = None) -> Sweep:
    """Parse, validate and expand a sweep file's text.

    Args:
      text: TOML text.
      source: file name for messages.
      plant, duration, physics: command-line overrides applied to every scenario (validated
        like the file; ``physics`` sets ``impl.physics``).
      limit: keep only the first ``limit`` scenarios (≥ 1).
      default_name: sweep name when the file sets none.
    Raises:
      SweepError: with a one-line message naming the field, the value and what is allowed.
    """
    doc = _loads(text, source)
    if "extends" in doc:
        raise SweepError(f"{source}: extends: only a sweep file can extend another (the name "
                         "is resolved next to the file); use hlip-sweep with the file's path")
    return _expand_doc(doc, text, source, (plant, duration, physics), limit, default_name)


def _loads(text: str, source: str) -> dict:
    if text.startswith("\ufeff"):
        raise SweepError(f"{source}: starts with a byte-order mark (U+FEFF); allowed: UTF-8 "
                         "without a BOM (save the file as plain UTF-8)")
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise SweepError(f"{source}: not valid TOML: {err}") from None
    except ValueError as err:       # an integer over Python's digit limit (4300 digits)
        raise SweepError(f"{source}: a number is too long to read ({err}); allowed: numbers "
                         "of at most 4300 digits") from None
    except RecursionError:
        raise SweepError(f"{source}: not valid TOML: tables or arrays nested too deeply; "
                         f"allowed: at most {MAX_DEPTH} levels") from None


def _depth(doc, limit: int) -> int:
    """Nesting depth of tables and arrays in ``doc``, counted without recursion up to ``limit``
    + 1."""
    level, deepest = [doc], 0
    while level and deepest <= limit:
        deepest += 1
        level = [v for x in level for v in (x.values() if isinstance(x, dict) else x)
                 if isinstance(v, (dict, list))]
    return deepest


def _expand_doc(doc, text, source, overrides, limit, default_name) -> Sweep:
    for key, value in doc.items():
        if isinstance(value, (dict, list)) and _depth(value, MAX_DEPTH - 1) >= MAX_DEPTH:
            raise SweepError(f"{source}: {key}: tables or arrays nested more than {MAX_DEPTH} "
                             f"levels deep; allowed: at most {MAX_DEPTH} levels")
    try:
        return _expand(doc, text, source, overrides, limit, default_name)
    except SweepError as err:
        msg = str(err)
        raise SweepError(msg if msg.startswith(source) else f"{source}: {msg}") from None


def shown_path(path, n: int = 200) -> str:
    """``path`` (any path-like) for a message: as it is, or cut to ``n`` characters with its
    length said (a 5,000-character path does not fill the screen)."""
    s = os.fspath(path)
    return s if len(s) <= n else f"{s[:n]}... ({len(s)} characters)"


def _short(s: str, n: int = 40) -> str:
    """``repr`` of ``s``, cut to about ``n`` characters for messages."""
    return repr(s) if len(s) <= n else repr(s[:n]) + f"... ({len(s)} characters)"


def _check_name(value, where: str, max_len: int, origin: str = "") -> str:
    """A sweep or path name, which becomes a file or directory name: 1..``max_len`` characters
    of :data:`_NAME_RE`, no leading '.' (so never '.' or '..'), no surrounding spaces."""
    allowed = f"allowed: 1-{max_len} {_NAME_ALLOWED}, not starting with '.'"
    if not isinstance(value, str):
        raise SweepError(f"{where}: expected a string, got {_tname(value)} {_fmt(value)}; {allowed}")
    bad = "".join(sorted(set(_NAME_RE.sub("", value))))
    if not value.strip():
        why = "is empty"
    elif bad:
        why = f"holds characters not allowed in a file name ({ascii(bad)})"
    elif len(value) > max_len:
        why = f"is {len(value)} characters long"
    elif value.startswith("."):
        why = "starts with '.'"
    elif value != value.strip():
        why = "has leading or trailing spaces"
    else:
        return value
    raise SweepError(f"{where}: {_short(value)}{origin} {why}; {allowed}")


def file_slug(name: str) -> str:
    """The file-name slug of a path name: the report names its figures with it."""
    out = "".join(c if c.isalnum() or c in "-_" else "_" for c in name)
    return out.strip("_") or "x"


@dataclass(frozen=True)
class _PathEntry:
    """One [[paths]] entry, validated: its name, shape, parameters, merged base table and the
    config that table builds (for the static-settings check)."""
    index: int
    name: str
    shape: str
    params: dict
    raw: dict
    cfg: C.ScenarioConfig


def _expand(doc, text, source, overrides, limit, default_name) -> Sweep:
    for k in doc:
        if k not in TOP_KEYS:
            raise _unknown_key(k, TOP_KEYS, "")
    origin = "" if "name" in doc else " (the file's stem; set name = \"...\")"
    name = _check_name(doc.get("name", default_name), "name", MAX_NAME_LEN, origin)
    desc = doc.get("description", "")
    if not isinstance(desc, str):
        raise SweepError(f"description: expected a string, got {_tname(desc)}")
    try:
        analysis = analysis_settings.from_dict(doc.get("analysis"))
    except ValueError as err:
        raise SweepError(str(err)) from None
    profile, impl_fields = _impl_table(doc.get("impl"))
    base, base_path = _base_tables(doc, *overrides, impl=impl_fields)
    entries = _parse_paths(doc, base, base_path)
    axes = _parse_axes(doc.get("grid"))
    n_grid = math.prod(len(a) for a in axes) if axes else 1
    total = len(entries) * n_grid
    if total >= MAX_SCENARIOS:
        raise SweepError(f"grid: {total} scenarios ({len(entries)} paths x {n_grid} grid "
                         f"points); allowed: fewer than {MAX_SCENARIOS}")
    if limit is not None:
        if isinstance(limit, bool) or not isinstance(limit, int) or limit < 1:
            raise SweepError(f"--limit: expected an integer >= 1, got {_fmt(limit)}")
    keymap = {f: _resolve_field(f, "grid") for a in axes for f in a.fields}
    _check_path_fields(entries, keymap)
    _check_static(entries, axes)
    stop = total if limit is None else min(limit, total)
    if total <= EAGER_SCENARIOS:
        scenarios = tuple(itertools.islice(_iter_scenarios(entries, axes, keymap), stop))
        checked, expand = scenarios, lambda: scenarios
    else:
        checked = [_scenario_at(e, axes, keymap, pt) for e in entries
                   for pt in _validation_points(axes)]
        expand = lambda: tuple(itertools.islice(_iter_scenarios(entries, axes, keymap), stop))  # noqa: E731
    _check_table_sizes(checked)
    _check_static_scenarios(checked)
    return Sweep(name=name, description=desc, source=source, text=text,
                 paths=tuple(e.name for e in entries), axes=axes, total=total,
                 n_scenarios=stop, analysis=analysis, impl_profile=profile,
                 impl_explicit=frozenset(base["impl"]), expand=expand)


def _impl_table(raw) -> tuple[str, dict]:
    """(profile, {field: value}) of the ``[impl]`` table ("auto" and none without one);
    SweepError naming the field."""
    if raw is None:
        return "auto", {}
    if not isinstance(raw, dict):
        raise SweepError(f"impl: expected a table, got {_tname(raw)} {_fmt(raw)}")
    for k in raw:
        if k != "profile" and k not in C.IMPL_FIELDS:
            raise _unknown_key(k, ("profile",) + C.IMPL_FIELDS, "impl")
    prof = raw.get("profile", "auto")
    if prof not in impl_mod.PROFILES:
        raise SweepError(f"impl.profile: {_fmt(prof)} is not allowed; allowed: "
                         f"{', '.join(impl_mod.PROFILES)}")
    fields = {k: v for k, v in raw.items() if k != "profile"}
    _build(C.ImplConfig, fields, "impl")
    return prof, fields


def _refuse_impl_elsewhere(table, where: str) -> None:
    """SweepError when a scenario table (``[base]``, a path's overrides) sets an
    implementation field: they live in the sweep's ``[impl]`` table (one value per sweep)."""
    if not isinstance(table, dict):
        return
    if "impl" in table:
        raise SweepError(f"{where}.impl: implementation settings belong in the sweep's [impl] "
                         f"table (one value per sweep; allowed there: {', '.join(C.IMPL_FIELDS)})")
    cassie = table.get("cassie")
    for k in (cassie if isinstance(cassie, dict) else ()):
        if k in C.IMPL_FIELDS:
            raise SweepError(f"{where}.cassie.{k}: an implementation setting; write it in the "
                             f"sweep's [impl] table ({k} = {_fmt(cassie[k])})")


def _base_tables(doc: dict, plant, duration, physics=None, impl=None) -> tuple[dict, dict]:
    """([base] with the command-line overrides and the ``[impl]`` fields ``impl`` as its
    ``impl`` table, [base.path]), the base validated alone so its errors name base.* fields."""
    base = doc.get("base", {})
    if not isinstance(base, dict):
        raise SweepError(f"base: expected a table, got {_tname(base)} {_fmt(base)}")
    _refuse_impl_elsewhere(base, "base")
    base = dict(base)
    base["impl"] = dict(impl or {})
    base_path = base.pop("path", {})
    if not isinstance(base_path, dict):
        raise SweepError(f"base.path: expected a table of path parameters, got {_tname(base_path)}")
    if plant is not None:
        base["plant"] = plant
    if duration is not None:            # named as the option, not as the file's base.duration
        kind, meta = _field_meta("duration")
        base["duration"] = check_scalar(duration, kind, meta, "--duration")
    if physics is not None:
        base["impl"]["physics"] = physics
    _build(C.ScenarioConfig, base, "base", exclude=BASE_EXCLUDE)
    return base, base_path


def _parse_paths(doc: dict, base: dict, base_path: dict) -> list[_PathEntry]:
    """The validated [[paths]] entries: unique names with unique file slugs, parameters
    checked against the shape, overrides merged into the base."""
    shapes = known_shapes()
    paths_raw = doc.get("paths")
    if paths_raw is None:
        raise SweepError("paths: missing; add at least one [[paths]] entry with a shape "
                         f"(one of {', '.join(shapes)})")
    if not isinstance(paths_raw, list) or not paths_raw:
        raise SweepError(f"paths: expected a non-empty array of tables ([[paths]]), got {_fmt(paths_raw)}")
    entries: list[_PathEntry] = []
    names_seen: dict[str, int] = {}
    for i, p in enumerate(paths_raw):
        loc = f"paths.{i}"
        if not isinstance(p, dict):
            raise SweepError(f"{loc}: expected a table, got {_tname(p)} {_fmt(p)}")
        shape = p.get("shape")
        if shape is None:
            raise SweepError(f"{loc}.shape: missing; allowed: one of {', '.join(map(repr, shapes))}")
        check_scalar(shape, "str", {"choices": shapes}, f"{loc}.shape")
        pname = p.get("name")
        if pname is None:
            names_seen[shape] = names_seen.get(shape, 0) + 1
            pname = shape if names_seen[shape] == 1 else f"{shape}-{names_seen[shape]}"
        _check_name(pname, f"{loc}.name", MAX_PATH_NAME_LEN)
        for e in entries:
            if e.name == pname:
                raise SweepError(f"{loc}.name: {pname!r} is used by two paths; names must be unique")
            if file_slug(e.name) == file_slug(pname):
                raise SweepError(f"{loc}.name: {pname!r} and {e.name!r} (paths.{e.index}) give the "
                                 f"same file name {file_slug(pname)!r} for their figures; allowed: "
                                 f"names that differ in letters, digits, '-' or '_'")
        own = {k: v for k, v in p.items() if k not in PATH_RESERVED}
        inherited = {k: v for k, v in base_path.items() if k not in own}
        params = {**_check_path_params(shape, inherited, "base.path",
                                       lambda k: f"base.path.{k} (path {loc}, shape {shape!r})"),
                  **_check_path_params(shape, own, loc)}
        over = p.get("overrides", {})
        if not isinstance(over, dict):
            raise SweepError(f"{loc}.overrides: expected a table, got {_tname(over)}")
        _refuse_impl_elsewhere(over, f"{loc}.overrides")
        merged = _deep_merge(base, over)
        cfg = _build(C.ScenarioConfig, _with_gait(merged, f"{loc}.overrides"), f"{loc}.overrides",
                     exclude=BASE_EXCLUDE)
        entries.append(_PathEntry(i, pname, shape, params, merged, cfg))
    return entries


def _check_path_fields(entries: list[_PathEntry], keymap: dict) -> None:
    """Every swept ``path.<param>`` must be a parameter of every path's shape."""
    for f, keys in keymap.items():
        if keys[0] != "path":
            continue
        for e in entries:
            spec = path_param_spec(e.shape)
            if keys[1] not in spec:
                near = difflib.get_close_matches(keys[1], list(spec), n=1)
                hint = f"; did you mean 'path.{near[0]}'?" if near else ""
                raise SweepError(f"grid.{f!r}: path {e.name!r} (shape {e.shape!r}) has no "
                                 f"parameter {keys[1]!r}{hint} (known: {', '.join(spec)})")


def _check_static(entries: list[_PathEntry], axes: tuple[Axis, ...]) -> None:
    """:data:`STATIC_FIELDS` must take one value across the sweep: swept over one value at
    most, and equal in every path's settings where not swept."""
    why = ("is a static setting (array shapes or compiled solver settings, equal for every "
           "scenario of a run)")
    swept = {}
    for a in axes:
        for j, f in enumerate(a.fields):
            if f in STATIC_FIELDS:
                vals = sorted({v[j] for v in a.values}, key=repr)
                if len(vals) > 1:
                    raise SweepError(f"grid.{f!r}: swept over {len(vals)} values "
                                     f"({', '.join(map(_fmt, vals))}), but {f} {why}; allowed: "
                                     f"one value per sweep (run one sweep per value)")
                swept[f] = vals[0]
    first = entries[0]
    for f in STATIC_FIELDS:
        if f in swept:
            continue
        v0 = C.field_value(first.cfg, f)
        for e in entries[1:]:
            v = C.field_value(e.cfg, f)
            if v != v0:
                raise SweepError(f"paths.{e.index}.overrides: {f} = {_fmt(v)} differs from "
                                 f"{f} = {_fmt(v0)} of path {first.name!r}, but {f} {why}; "
                                 f"allowed: the same value in every path")


def _check_static_scenarios(scenarios) -> None:
    """:data:`STATIC_FIELDS` equal across the built scenarios: catches what no single axis or
    path sets, e.g. a swept ``cassie.gait`` whose presets fill different static values."""
    first = scenarios[0] if scenarios else None
    for cfg in scenarios[1:]:
        for f in STATIC_FIELDS:
            v, v0 = C.field_value(cfg, f), C.field_value(first, f)
            if v != v0:
                raise SweepError(f"scenario {cfg.name!r}: {f} = {_fmt(v)} differs from {f} = "
                                 f"{_fmt(v0)} of scenario {first.name!r}, but {f} is a static "
                                 f"setting (equal for every scenario of a run); allowed: one "
                                 f"value per sweep")


def _check_table_sizes(scenarios) -> None:
    """Every path of a sweep needs the same ``n_samples`` (a static table size)."""
    sizes, specs = {}, {}
    for cfg in scenarios:
        shape = cfg.path.shape
        spec = specs[shape] if shape in specs else specs.setdefault(shape, path_param_spec(shape))
        if "n_samples" in spec:
            sizes.setdefault(cfg.path.params.get("n_samples", spec["n_samples"]["default"]),
                             cfg.swept["path"])
    if len(sizes) > 1:
        desc_sizes = ", ".join(f"{v!r}: {k}" for k, v in sizes.items())
        raise SweepError(f"path.n_samples: every path of a sweep needs the same table size (a "
                         f"static shape), got {desc_sizes}; allowed: one value (set it in "
                         f"[base.path])")


#: grid fields whose values are checked on their own only (no cross-field check involves them)
_INDEPENDENT = ("seed", "gain.", "mpc.")


def _independent(field: str) -> bool:
    return field.startswith(_INDEPENDENT) and not field.startswith("mpc.step_")


def _validation_points(axes: tuple[Axis, ...]):
    """Grid points (one value tuple per axis) that exercise every check of a large grid: the
    product of the axes that take part in cross-field checks (durations, step limits,
    disturbances, obstacles, path parameters, plant), the others at their first value; then
    every value of each other axis once."""
    dep = [i for i, a in enumerate(axes) if not all(_independent(f) for f in a.fields)]
    first = [a.values[0] for a in axes]
    for combo in itertools.product(*[axes[i].values for i in dep]):
        pt = list(first)
        for i, v in zip(dep, combo):
            pt[i] = v
        yield tuple(pt)
    for i, a in enumerate(axes):
        if i in dep:
            continue
        for v in a.values[1:]:
            pt = list(first)
            pt[i] = v
            yield tuple(pt)


def _iter_scenarios(entries: list[_PathEntry], axes: tuple[Axis, ...], keymap: dict):
    """Every scenario, path-major, then the grid points in product order."""
    for e in entries:
        for point in itertools.product(*[a.values for a in axes]):
            yield _scenario_at(e, axes, keymap, point)


def _scenario_at(e: _PathEntry, axes: tuple[Axis, ...], keymap: dict, point) -> C.ScenarioConfig:
    """The validated scenario of path ``e`` at grid ``point`` (one value tuple per axis)."""
    raw = json.loads(json.dumps(e.raw))
    pparams = dict(e.params)
    swept: dict[str, Any] = {"path": e.name}
    labels = []
    for a, vals in zip(axes, point):
        for f, v in zip(a.fields, vals):
            keys = keymap[f]
            where = f"grid.{f!r} = {_fmt(v)} (path {e.name!r})"
            if keys[0] == "path":
                pparams.update(_check_path_params(
                    e.shape, {keys[1]: v}, "grid",
                    lambda k: f"grid.{f!r} (path {e.name!r}, shape {e.shape!r})"))
            else:
                _set_dotted(raw, keys, str.__str__(v) if isinstance(v, str) else v, where)
            swept[f] = as_written(v)
            labels.append(f"{f}={_value_label(as_written(v))}")
    sname = e.name + ("/" + ",".join(labels) if labels else "")
    where = f"scenario {sname!r}"
    cfg = _build(C.ScenarioConfig, _with_gait(raw, where), where, exclude=BASE_EXCLUDE)
    cfg = dataclasses.replace(cfg, name=sname, seed=_derive_seed(cfg.seed, sname),
                              path=C.PathConfig(shape=e.shape, params=pparams), swept=swept)
    _cross_checks(cfg, where)
    return cfg


MAX_EXTENDS = 8   # longest chain of sweep files extending one another


def load_sweep(path, *, plant: str | None = None, duration: float | None = None,
               limit: int | None = None, physics: str | None = None) -> Sweep:
    """Read and expand a sweep file (see :func:`parse_sweep` for the keyword overrides).

    A file may start from another with ``extends = "paper.toml"`` (a path relative to the file;
    ``.toml`` may be left out): the parent's ``[base]`` is deep-merged under the file's own, and
    ``paths`` and ``description`` are the file's where it sets them, else the parent's; of the
    ``grid``, the file's ``product`` replaces the parent's ``product`` and its ``zip`` the
    parent's ``zip``, each kind the file leaves out inherited (a variant that only changes the
    seeds keeps its parent's zipped axes); the ``[analysis]`` table is merged key by key (the
    file's keys win); the name is always the file's own (or its stem).  Chains of up to
    :data:`MAX_EXTENDS` files, no cycles.  The manifest keeps every file's text."""
    p = Path(path)
    doc, text = _resolve_extends(p, str(path), ())
    return _expand_doc(doc, text, str(path), (plant, duration, physics), limit, p.stem)


def _read_sweep_file(p: Path, source: str) -> str:
    if not p.is_file():         # stat only: a FIFO or a device is never opened (no hang)
        if p.is_dir():
            raise SweepError(f"{source}: sweep file not found (it is a directory)")
        if os.path.exists(p):
            raise SweepError(f"{source}: not a regular file (a FIFO, a device or a socket); "
                             "a sweep file is a regular TOML file")
        raise SweepError(f"{source}: sweep file not found")
    try:
        data = p.read_bytes()
    except OSError as err:
        raise SweepError(f"{source}: cannot read the sweep file: {err}") from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as err:
        raise SweepError(f"{source}: {_not_utf8(data, err)}; allowed: UTF-8 text (TOML "
                         "files are UTF-8: save it as UTF-8, e.g. `iconv -t utf-8`)") from None


#: byte-order marks of the encodings a sweep file saved by an editor is most often in
_BOMS = ((b"\xff\xfe\x00\x00", "UTF-32"), (b"\x00\x00\xfe\xff", "UTF-32"),
         (b"\xff\xfe", "UTF-16"), (b"\xfe\xff", "UTF-16"))


def _not_utf8(data: bytes, err: UnicodeDecodeError) -> str:
    """What is not UTF-8 in a file's bytes ``data``: the encoding its byte-order mark names,
    or the line and the first byte that cannot be decoded."""
    bom = next((name for mark, name in _BOMS if data.startswith(mark)), None)
    if bom is not None:
        return f"a {bom} file (it begins with a {bom} byte-order mark)"
    line = data.count(b"\n", 0, err.start) + 1
    return (f"line {line}: byte 0x{data[err.start]:02x} is not UTF-8 (a Latin-1 or Windows "
            "character?)")


#: fields that name a file; a relative path in a sweep file is read from that file's directory
FILE_FIELDS = ("mpc.w_hull_file", "s2s.file")


class _Anchored(str):
    """A file path of a grid axis joined to its sweep file's directory, which remembers the
    value as written (``written``): a scenario's name, seed and swept value take that, so
    they do not depend on where the sweep's folder lies."""
    written: str

    def __new__(cls, path: str, written: str):
        obj = super().__new__(cls, path)
        obj.written = written
        return obj


def as_written(v):
    """A grid value as the sweep file wrote it (a file path before it was joined to the
    file's directory); any other value as it is."""
    return str.__str__(v.written) if isinstance(v, _Anchored) else v


def _anchored(value, base: Path, remember: bool = False):
    """``value`` (a path string, or a list of them) with relative paths joined to ``base``;
    anything else as it is (its type is checked where the field is validated).  ``remember``
    (grid axes): the joined path keeps the value as written (:class:`_Anchored`)."""
    if isinstance(value, list):
        return [_anchored(v, base, remember) for v in value]
    if isinstance(value, str) and value and not Path(value).is_absolute():
        return _Anchored(str(base / value), value) if remember else str(base / value)
    return value


def _anchor_files(doc: dict, base: Path) -> None:
    """Resolve the relative :data:`FILE_FIELDS` of a sweep document against ``base`` (the
    file's directory), in place: in ``[base]``, in the paths' overrides and in grid axes."""
    tables = [doc.get("base")] + [e.get("overrides") for e in doc.get("paths", [])
                                   if isinstance(e, dict)]
    for field in FILE_FIELDS:
        section, name = field.split(".")
        for t in tables:
            sub = t.get(section) if isinstance(t, dict) else None
            if isinstance(sub, dict) and name in sub:
                sub[name] = _anchored(sub[name], base)
        grid = doc.get("grid") if isinstance(doc.get("grid"), dict) else {}
        for axes in [grid.get("product")] + list(_as_list(grid.get("zip"))):
            if isinstance(axes, dict) and field in axes:
                axes[field] = _anchored(axes[field], base, remember=True)


def _point_key(row) -> str:
    """A grid point as compared by the repeated-point check: numbers by value (``1`` and
    ``1.0``, ``0.0`` and ``-0.0`` are one point: one setting, and names that read alike)."""
    def norm(v):
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            return float(v) + 0.0 if abs(v) < 2 ** 53 else v
        return v
    return repr(tuple(map(norm, row)) if isinstance(row, tuple) else norm(row))


def _as_list(v) -> list:
    return v if isinstance(v, list) else [] if v is None else [v]


def _resolve_extends(p: Path, source: str, chain: tuple) -> tuple[dict, str]:
    """(document, text) of sweep file ``p`` with its ``extends`` chain merged in; each file's
    relative :data:`FILE_FIELDS` are read from its own directory."""
    text = _read_sweep_file(p, source)
    doc = _loads(text, source)
    _anchor_files(doc, p.parent)
    parent = doc.pop("extends", None)
    if parent is None:
        return doc, text
    if not isinstance(parent, str) or not parent.strip():
        raise SweepError(f"{source}: extends: expected the path of another sweep file, got "
                         f"{_tname(parent)} {_fmt(parent)}")
    if "\0" in parent:       # the system cannot take it as a path (ValueError in resolve)
        raise SweepError(f"{source}: extends: {_fmt(parent)} holds a NUL character; allowed: "
                         "the path of another sweep file")
    q = p.parent / (parent if parent.endswith(".toml") else parent + ".toml")
    key = q.resolve()
    if key in chain or key == p.resolve():
        raise SweepError(f"{source}: extends: {_fmt(parent)} extends this file again (a cycle)")
    if len(chain) + 1 >= MAX_EXTENDS:
        raise SweepError(f"{source}: extends: more than {MAX_EXTENDS} files in the chain")
    where = f"{source}: extends {_fmt(parent)}"
    if not os.path.exists(q):      # (a shipped sweep's name is not looked up here)
        raise SweepError(f"{where}: sweep file not found (looked for {_short(str(q), 200)}: "
                         "a path relative to this file)")
    base_doc, base_text = _resolve_extends(q, where, chain + (p.resolve(),))
    for k in base_doc:          # a file that is not a sweep is named, not the one extending it
        if k not in TOP_KEYS:
            raise SweepError(f"{where}: {_unknown_key(k, TOP_KEYS, '')}")
    merged = {k: v for k, v in base_doc.items() if k != "name"}
    for k, v in doc.items():
        both_tables = isinstance(v, dict) and isinstance(merged.get(k), dict)
        if k == "base" and both_tables:
            merged[k] = _deep_merge(merged[k], v)
        elif k in ("grid", "analysis") and both_tables:
            merged[k] = {**merged[k], **v}
        else:
            merged[k] = v
    return merged, f"{text}\n# ---- extends {parent} ----\n{base_text}"


# --------------------------------------------------------------------------------------------
# serialisation


def config_to_dict(cfg: C.ScenarioConfig) -> dict:
    """JSON-ready nested dict of a scenario (tuples become lists)."""
    return json.loads(json.dumps(dataclasses.asdict(cfg)))


def config_from_dict(d: dict) -> C.ScenarioConfig:
    """The inverse of :func:`config_to_dict` (validated like a sweep file's table)."""
    raw = _with_impl_table({k: v for k, v in d.items() if k not in BASE_EXCLUDE})
    cfg = _build(C.ScenarioConfig, raw, f"scenario {d.get('name')!r}", exclude=BASE_EXCLUDE)
    path = C.PathConfig(shape=d["path"]["shape"], params=dict(d["path"]["params"]))
    return dataclasses.replace(cfg, name=d["name"], path=path, swept=dict(d.get("swept", {})))


def _with_impl_table(raw: dict) -> dict:
    """A stored scenario table with the implementation fields in its ``impl`` table: results
    written before :class:`hlip_jax.simulation.config.ImplConfig` kept them in ``cassie``."""
    cassie = raw.get("cassie")
    if not isinstance(cassie, dict) or not any(k in C.IMPL_FIELDS for k in cassie):
        return raw
    impl = dict(raw.get("impl") or {})
    impl.update({k: v for k, v in cassie.items() if k in C.IMPL_FIELDS})
    return {**raw, "cassie": {k: v for k, v in cassie.items() if k not in C.IMPL_FIELDS},
            "impl": impl}


def config_hash(configs, extra: dict | None = None) -> str:
    """SHA-256 of the canonical JSON of the expanded configs (and ``extra``, e.g. the chunk size)."""
    return dicts_hash([config_to_dict(c) for c in configs], extra)


def dicts_hash(config_dicts: list, extra: dict | None = None) -> str:
    """:func:`config_hash` of configs already as dicts (a manifest's ``configs``)."""
    return json_digest({"configs": config_dicts, "extra": extra or {}})


def json_digest(payload) -> str:
    """SHA-256 (hex) of the canonical JSON of ``payload`` (keys sorted, no spaces): the same
    digest for equal data however its dicts were built."""
    s = json.dumps(payload, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(s.encode()).hexdigest()


def data_files(configs) -> dict[str, str]:
    """{path: field} of every data file (:data:`FILE_FIELDS`) the configs name, in order."""
    out: dict[str, str] = {}
    for c in configs:
        for field in FILE_FIELDS:
            section, name = field.split(".")
            path = getattr(getattr(c, section), name)
            if path:
                out.setdefault(path, field)
    return out


def file_digest(path: str) -> str:
    """SHA-256 of a data file's bytes (OSError if it cannot be read)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def file_digests(configs) -> dict[str, str]:
    """{path: SHA-256} of every data file the configs name (part of a run's identity: a W
    or model file edited between a run and its ``--resume`` is another run)."""
    out = {}
    for path, field in data_files(configs).items():
        try:
            out[path] = file_digest(path)
        except OSError as err:
            raise SweepError(f"{field}: {_short(path, 200)}: cannot read it: "
                             f"{err.strerror or err}") from None
    return out
