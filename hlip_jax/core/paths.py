"""Time-parameterised reference paths as fixed-size tables.

A :class:`Path` samples the desired planar pose and its rates on a uniform time grid
``t_i = i·dt``, ``i = 0 … n−1`` (t0 = 0, ``n`` is static through the array shapes, ``dt`` and
the motion's ``duration`` are data).  Paths of different shapes built with the same
``n_samples`` therefore stack into one batch and share one compile; :func:`reference`
interpolates a table at any time, under ``jit`` and ``vmap``.

How a path is made (plain numpy at configuration time):

* The geometry is a chain of *moves*, each a curve parameterised by arc length s ∈ [0, L]
  (tangent angle ψ(s), curvature κ(s) = dψ/ds).  The robot is at rest at both ends of every
  move; between moves (square corners, polyline corners, the cusp of a cardioid between laps)
  and before the first move (when ``align_start`` is false and ``heading0`` differs from the
  start tangent) it *turns in place* at the constant rate ``turn_rate`` [rad/s], the shorter
  way round (a half turn goes the way the shape turns).
* Along a move the arc length follows a speed profile s(τ) (see :func:`speed_profile`):
  ``"trapezoid"`` — accelerate at ``accel`` to ``peak_speed``, cruise, decelerate at
  ``accel``;
  if L < peak_speed²/accel the peak cannot be reached and the profile degrades to a triangle
  with peak √(accel·L).  ``"triangle"`` — accelerate to ``peak_speed`` at mid length and
  decelerate, i.e. acceleration peak_speed²/L; if that exceeds ``accel`` the peak is lowered
  to √(accel·L) (so ``accel`` is an upper bound for both profiles).
* Pose and rates: position r(s(τ)); velocity ṡ·(cos ψ, sin ψ); heading θ = ψ (+ a multiple of
  2π so that θ is continuous: it is never wrapped); heading rate θ̇ = κ·ṡ while moving,
  ±turn_rate while turning, 0 at rest.  The heading-rate limit applies to turns in place
  only; along a curve θ̇ = κ·ṡ is whatever the curve and the speed demand.
* After the last move the path rests at its end.  If the motion is longer than ``t_final``
  the table stops at ``t_final`` (``Path.duration`` still holds the full motion time, so
  ``duration > (n−1)·dt`` tells a truncated path).

Shapes (:data:`SHAPES`, build with :func:`make_path`): ``line``, ``circle``, ``sinusoid``,
``cardioid``, ``square``, ``figure_eight``, ``polyline``.  Every parameter, its unit, default
and allowed range is data in :data:`PARAM_SPECS` (``shape → name → ParamSpec``), which
:func:`validate_params` and the sweep loader both use.  Units: m, s, rad throughout.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from scipy.interpolate import CubicSpline

from hlip_jax.core.fields import FMT_MAX_CHARS, show_value

__all__ = [
    "Path", "Reference", "ParamSpec", "SpeedProfile", "PARAM_SPECS", "SHAPES",
    "reference", "make_path", "validate_params", "speed_profile", "stack_paths",
    "sample_times",
    "line", "circle", "sinusoid", "cardioid", "square", "figure_eight", "polyline",
]

TWO_PI = 2.0 * math.pi


# --------------------------------------------------------------------------------------------
# the table and its interpolation


class Path(NamedTuple):
    """Reference path sampled at ``t_i = i·dt`` (i = 0 … n−1, n = ``x.shape[-1]``).

    dt: sample interval [s] (scalar).   x, y: position [m] (n,).
    theta: heading [rad] (n,), continuous (unwrapped).   vx, vy: velocity [m/s] (n,).
    omega: heading rate θ̇ [rad/s] (n,).
    duration: time the motion ends [s] (scalar); the path rests at its end afterwards.  It
      may exceed the table's end (n−1)·dt when the motion was cut at ``t_final``.
    """
    dt: jax.Array
    x: jax.Array
    y: jax.Array
    theta: jax.Array
    vx: jax.Array
    vy: jax.Array
    omega: jax.Array
    duration: jax.Array


class Reference(NamedTuple):
    """Desired state at one time: position (2,) [m], velocity (2,) [m/s], heading [rad],
    heading rate [rad/s]."""
    position: jax.Array
    velocity: jax.Array
    heading: jax.Array
    heading_rate: jax.Array


def reference(path: Path, t) -> Reference:
    """Desired pose and rates at time ``t`` [s] by linear interpolation of the table.

    For t < 0 the start pose is held, for t ≥ min(duration, (n−1)·dt) the final pose of the
    table is held; in both cases velocity and heading rate are zero.  Pure ``jax.numpy``:
    jit, vmap over paths (a stacked :class:`Path`) and over t.  ``t`` is a scalar (vmap for
    several times).
    """
    n = path.x.shape[-1]
    dt = path.dt
    t = jnp.asarray(t, dtype=path.x.dtype)
    u = t / dt
    i0 = jnp.clip(jnp.floor(u), 0, n - 2).astype(jnp.int32)
    w = jnp.clip(u - i0, 0.0, 1.0)

    def lerp(a):
        return a[i0] * (1.0 - w) + a[i0 + 1] * w

    t_end = jnp.minimum(path.duration, (n - 1) * dt)
    moving = (t >= 0.0) & (t < t_end)
    zero = jnp.zeros_like(w)
    vel = jnp.stack([jnp.where(moving, lerp(path.vx), zero),
                     jnp.where(moving, lerp(path.vy), zero)])
    return Reference(position=jnp.stack([lerp(path.x), lerp(path.y)]),
                     velocity=vel,
                     heading=lerp(path.theta),
                     heading_rate=jnp.where(moving, lerp(path.omega), zero))


def sample_times(path: Path) -> jax.Array:
    """The table's time grid t_i = i·dt [s], shape (n,) (or (batch, n) for a stacked path)."""
    n = path.x.shape[-1]
    return jnp.arange(n, dtype=path.x.dtype) * jnp.asarray(path.dt)[..., None]


def stack_paths(paths) -> Path:
    """Stack paths of equal ``n_samples`` into one batched :class:`Path` (leading axis)."""
    paths = list(paths)
    sizes = {p.x.shape[-1] for p in paths}
    if len(sizes) != 1:
        raise ValueError(f"stack_paths: all paths need the same n_samples; got {sorted(sizes)}")
    return jax.tree.map(lambda *a: jnp.stack(a), *paths)


# --------------------------------------------------------------------------------------------
# speed profiles


class SpeedProfile(NamedTuple):
    """Arc-length profile of one move (all floats).  ``peak`` [m/s] is the speed reached,
    ``accel`` [m/s²] the acceleration used, ``t_acc`` the time to reach the peak (also the
    deceleration time), ``t_cruise`` the time at the peak, ``duration = 2 t_acc + t_cruise``."""
    length: float
    peak: float
    accel: float
    t_acc: float
    t_cruise: float
    duration: float


def speed_profile(length: float, peak_speed: float, accel: float,
                  kind: str = "trapezoid") -> SpeedProfile:
    """Closed-form rest-to-rest speed profile over ``length`` [m].

    trapezoid: v = min(peak_speed, √(accel·L)); t_acc = v/accel;
      t_cruise = (L − v²/accel)/v;  duration = L/v + v/accel (= 2√(L/accel) when degraded).
    triangle:  v = min(peak_speed, √(accel·L)); acceleration a = v²/L (peak at mid length);
      t_acc = L/v;  t_cruise = 0;  duration = 2L/v.
    """
    if length <= 0.0:
        return SpeedProfile(0.0, 0.0, accel, 0.0, 0.0, 0.0)
    v = min(peak_speed, math.sqrt(accel * length))
    if kind == "trapezoid":
        a = accel
        t_acc = v / a
        t_cruise = max(length - v * v / a, 0.0) / v
    elif kind == "triangle":
        a = v * v / length
        t_acc = length / v
        t_cruise = 0.0
    else:
        raise ValueError(f"speed profile: 'profile' = {kind!r}; allowed: 'trapezoid', 'triangle'")
    return SpeedProfile(length, v, a, t_acc, t_cruise, 2.0 * t_acc + t_cruise)


def _profile_eval(p: SpeedProfile, tau):
    """(s, ṡ) at time τ [s] into the move (numpy, clamped to [0, duration])."""
    tau = np.clip(tau, 0.0, p.duration)
    t1 = p.t_acc
    t2 = p.t_acc + p.t_cruise
    rem = p.duration - tau
    s = np.where(tau < t1, 0.5 * p.accel * tau**2,
                 np.where(tau < t2, 0.5 * p.accel * t1**2 + p.peak * (tau - t1),
                          p.length - 0.5 * p.accel * rem**2))
    sd = np.where(tau < t1, p.accel * tau, np.where(tau < t2, p.peak, p.accel * rem))
    return np.clip(s, 0.0, p.length), np.maximum(sd, 0.0)


# --------------------------------------------------------------------------------------------
# curves parameterised by arc length (local frame: start at the origin)


class _Curve:
    """Arc-length curve: ``length`` [m] and ``eval(s) → (x, y, ψ, κ)`` with ψ continuous."""
    length: float

    def eval(self, s):  # pragma: no cover - interface
        raise NotImplementedError


class _Line(_Curve):
    def __init__(self, length):
        self.length = float(length)

    def eval(self, s):
        z = np.zeros_like(s)
        return s, z, z, z


class _Arc(_Curve):
    """Counter-clockwise circle of radius R through the origin, start tangent +x (centre
    (0, R)), ``turns`` full turns."""

    def __init__(self, radius, turns):
        self.R = float(radius)
        self.length = TWO_PI * self.R * turns

    def eval(self, s):
        a = s / self.R
        return self.R * np.sin(a), self.R * (1.0 - np.cos(a)), a, np.full_like(s, 1.0 / self.R)


class _Cardioid(_Curve):
    """One lap of r = a(1 − cos φ) from the cusp (origin) back to it, counter-clockwise,
    start tangent +x.  ψ = 3φ/2, s(φ) = 4a(1 − cos(φ/2)), L = 8a, κ = 3/(4a sin(φ/2))."""

    def __init__(self, a):
        self.a = float(a)
        self.length = 8.0 * self.a

    def eval(self, s):
        a = self.a
        first = s <= 4.0 * a
        sh = np.where(first, s, 8.0 * a - s)
        half = np.arccos(np.clip(1.0 - sh / (4.0 * a), -1.0, 1.0))  # φ/2 on the first half
        phi = np.where(first, 2.0 * half, TWO_PI - 2.0 * half)
        r = a * (1.0 - np.cos(phi))
        # curvature is unbounded at the cusp, where ṡ = 0: clamp so that κ·ṡ stays finite
        kappa = 3.0 / (4.0 * a * np.maximum(np.sin(0.5 * phi), 1e-12))
        return r * np.cos(phi), r * np.sin(phi), 1.5 * phi, kappa


class _Parametric(_Curve):
    """Smooth regular curve r(τ), τ ∈ [0, τ_end], given r, r′, r″ (numpy).  The arc length is
    integrated on a dense grid (Simpson) and inverted with a cubic spline."""

    def __init__(self, r, dr, ddr, tau_end, n_dense=200_001):
        from scipy.integrate import cumulative_simpson

        self.r, self.dr, self.ddr = r, dr, ddr
        tau = np.linspace(0.0, tau_end, n_dense)
        dx, dy = dr(tau)
        speed = np.hypot(dx, dy)
        if speed.min() <= 1e-12 * speed.max():
            raise ValueError("parametric curve has a zero-speed point; not regular")
        s = cumulative_simpson(speed, x=tau, initial=0.0)
        self.length = float(s[-1])
        self._tau_of_s = CubicSpline(s, tau)
        self._tau = tau
        self._psi = np.unwrap(np.arctan2(dy, dx))
        self._r0 = np.array(r(np.zeros(1)))[:, 0]

    def eval(self, s):
        tau = self._tau_of_s(np.clip(s, 0.0, self.length))
        x, y = self.r(tau)
        dx, dy = self.dr(tau)
        ddx, ddy = self.ddr(tau)
        psi_w = np.arctan2(dy, dx)
        psi_ref = np.interp(tau, self._tau, self._psi)
        psi = psi_w + TWO_PI * np.round((psi_ref - psi_w) / TWO_PI)
        sp = np.hypot(dx, dy)
        kappa = (dx * ddy - dy * ddx) / sp**3
        return x - self._r0[0], y - self._r0[1], psi, kappa


class _Placed:
    """A local curve mirrored (y → −y when ``mirror``), rotated by ``rot`` and moved to
    ``origin``: world-frame (x, y, ψ, κ)."""

    def __init__(self, curve: _Curve, origin=(0.0, 0.0), rot=0.0, mirror=False):
        self.curve = curve
        self.length = curve.length
        self.ox, self.oy = float(origin[0]), float(origin[1])
        self.rot = float(rot)
        self.sgn = -1.0 if mirror else 1.0

    def eval(self, s):
        x, y, psi, kappa = self.curve.eval(np.asarray(s, float))
        y, psi, kappa = self.sgn * y, self.sgn * psi, self.sgn * kappa
        c, sn = math.cos(self.rot), math.sin(self.rot)
        return (self.ox + c * x - sn * y, self.oy + sn * x + c * y, psi + self.rot, kappa)

    def start_end(self):
        x, y, psi, _ = self.eval(np.array([0.0, self.length]))
        return (x[0], y[0], psi[0]), (x[1], y[1], psi[1])


# --------------------------------------------------------------------------------------------
# assembling moves and turns into the table


def _assemble(moves, *, n_samples, t_final, peak_speed, accel, profile, turn_rate,
              heading0, align_start, turn_sign=1.0) -> Path:
    """Sample the chain ``moves`` (list of _Placed) with turns in place between them."""
    phases = []  # (kind, duration, data)
    (x_s, y_s, psi_s), _ = moves[0].start_end()
    theta = psi_s if align_start else float(heading0)
    for m in moves:
        (xa, ya, psa), (_, _, pse) = m.start_end()
        d = (psa - theta + math.pi) % TWO_PI - math.pi  # in [−π, π)
        if abs(abs(d) - math.pi) < 1e-9:
            d = math.copysign(math.pi, turn_sign)
        if abs(d) > 1e-12:
            phases.append(("turn", abs(d) / turn_rate, (xa, ya, theta, math.copysign(1.0, d))))
        theta += d
        prof = speed_profile(m.length, peak_speed, accel, profile)
        offset = theta - psa
        phases.append(("move", prof.duration, (m, prof, offset)))
        theta = pse + offset

    n = int(n_samples)
    dt = float(t_final) / (n - 1)
    t = np.arange(n) * dt
    # rest at the end of the last move
    m, prof, offset = phases[-1][2]
    _, (xe, ye, _) = m.start_end()
    x = np.full(n, xe)
    y = np.full(n, ye)
    th = np.full(n, theta)
    vx = np.zeros(n)
    vy = np.zeros(n)
    om = np.zeros(n)
    t0 = 0.0
    for kind, dur, data in phases:
        sel = (t >= t0) & (t < t0 + dur)
        tau = t[sel] - t0
        if kind == "turn":
            xa, ya, th0, sgn = data
            x[sel], y[sel] = xa, ya
            th[sel] = th0 + sgn * turn_rate * tau
            om[sel] = sgn * turn_rate
        else:
            m, prof, offset = data
            s, sd = _profile_eval(prof, tau)
            px, py, psi, kappa = m.eval(s)
            x[sel], y[sel] = px, py
            th[sel] = psi + offset
            vx[sel] = sd * np.cos(psi)
            vy[sel] = sd * np.sin(psi)
            om[sel] = kappa * sd
        t0 += dur
    arr = lambda a: jnp.asarray(a)  # noqa: E731  (float32 unless x64 is enabled)
    return Path(dt=arr(dt), x=arr(x), y=arr(y), theta=arr(th), vx=arr(vx), vy=arr(vy),
                omega=arr(om), duration=arr(t0))


# --------------------------------------------------------------------------------------------
# parameter specs


@dataclasses.dataclass(frozen=True)
class ParamSpec:
    """One path parameter: default, allowed closed range [lo, hi] (numbers), unit, meaning,
    ``kind`` ("float" | "int" | "str" | "bool" | "points") and ``choices`` (for "str")."""
    default: Any
    lo: float = -math.inf
    hi: float = math.inf
    doc: str = ""
    unit: str = ""
    kind: str = "float"
    choices: tuple | None = None


_MOTION = {
    "n_samples": ParamSpec(4096, 2, 1_000_000, "number of table samples (static shape; equal "
                           "for every path of a sweep)", "", "int"),
    "t_final": ParamSpec(60.0, 0.1, 36_000.0, "time covered by the table; the path rests "
                         "at its end if it finishes earlier, and is cut if it finishes later", "s"),
    "peak_speed": ParamSpec(0.5, 0.01, 3.0, "peak walking speed along the path", "m/s"),
    "accel": ParamSpec(0.25, 0.01, 10.0, "tangential acceleration (upper bound for the "
                       "triangle profile)", "m/s²"),
    "profile": ParamSpec("trapezoid", doc="speed profile along arc length of every move",
                         kind="str", choices=("trapezoid", "triangle")),
    "turn_rate": ParamSpec(0.5, 0.01, 10.0, "heading rate of turns in place", "rad/s"),
    "align_start": ParamSpec(True, doc="true: start facing along the path's start tangent; "
                             "false: start at heading0 and turn in place first", kind="bool"),
    "heading0": ParamSpec(0.0, -TWO_PI, TWO_PI, "initial heading (used when align_start is "
                          "false)", "rad"),
}
_PLACE = {
    "x0": ParamSpec(0.0, -1e4, 1e4, "start point x", "m"),
    "y0": ParamSpec(0.0, -1e4, 1e4, "start point y", "m"),
    "rotation": ParamSpec(0.0, -TWO_PI, TWO_PI, "rotation of the whole shape about the start "
                          "point (0: the shape's axis / start tangent along +x)", "rad"),
}
_DIRECTION = ParamSpec("ccw", doc="sense of rotation (ccw: turning left)", kind="str",
                       choices=("ccw", "cw"))


# shapes that stop at corners default to a triangle profile per side
_MOTION_STOPS = {**_MOTION,
                 "profile": dataclasses.replace(_MOTION["profile"], default="triangle")}


def _laps(doc="number of laps"):
    return ParamSpec(1, 1, 100, doc, "", "int")


PARAM_SPECS: dict[str, dict[str, ParamSpec]] = {
    "line": {"length": ParamSpec(4.0, 0.01, 1e4, "length", "m"), **_PLACE, **_MOTION},
    "circle": {"radius": ParamSpec(1.5, 0.1, 1e3, "radius; centre at the start point + radius "
                                   "to the left (ccw) or right (cw) of the start tangent", "m"),
               "direction": _DIRECTION, "laps": _laps(), **_PLACE, **_MOTION},
    "sinusoid": {"amplitude": ParamSpec(0.5, 0.0, 100.0, "lateral amplitude A of "
                                        "y = A sin(2π x / wavelength)", "m"),
                 "wavelength": ParamSpec(4.0, 0.1, 1e4, "wavelength along the axis", "m"),
                 "periods": ParamSpec(2.0, 0.05, 1e3, "number of wavelengths walked", ""),
                 "direction": ParamSpec("ccw", doc="ccw: first bend to the left (y > 0); "
                                        "cw: to the right", kind="str", choices=("ccw", "cw")),
                 **_PLACE, **_MOTION},
    "cardioid": {"size": ParamSpec(1.0, 0.05, 1e3, "a in r = a(1 − cos φ): 2a long on its "
                                   "axis, 8a around; starts and ends at the cusp, stops there "
                                   "between laps and turns half a turn in place", "m"),
                 "direction": _DIRECTION, "laps": _laps(), **_PLACE, **_MOTION},
    "square": {"side": ParamSpec(2.0, 0.05, 1e4, "side length; stops and turns in place at "
                                 "every corner", "m"),
               "direction": _DIRECTION, "laps": _laps(), **_PLACE, **_MOTION_STOPS},
    "figure_eight": {"size": ParamSpec(2.0, 0.05, 1e3, "a in x = a sin τ, y = ∓(a/2) sin 2τ "
                                       "(2a long, a wide); starts at the crossing; the "
                                       "tightest bends have curvature ≈ 4.8/a", "m"),
                     "direction": ParamSpec("ccw", doc="sense of the first lobe", kind="str",
                                            choices=("ccw", "cw")),
                     "laps": _laps(), **_PLACE, **_MOTION},
    "polyline": {"waypoints": ParamSpec(((0.0, 0.0), (2.0, 0.0), (2.0, 2.0)), -1e4, 1e4,
                                        "at least 2 points [[x, y], ...] in world coordinates "
                                        "(no two consecutive equal); stops and turns in place "
                                        "at every corner", "m", "points"),
                 "closed": ParamSpec(False, doc="true: return to the first waypoint",
                                     kind="bool"),
                 **_MOTION_STOPS},
}


def _fail(shape, name, value, spec: ParamSpec, why=None):
    unit = f" {spec.unit}" if spec.unit else ""
    if why is None:
        if spec.kind == "str":
            why = f"allowed: {', '.join(repr(c) for c in spec.choices)}"
        elif spec.kind == "bool":
            why = "allowed: true or false"
        else:
            kind = "an integer" if spec.kind == "int" else "a number"
            why = f"allowed: {kind} in [{spec.lo:g}, {spec.hi:g}]{unit}"
    shown = repr(value)
    if len(shown) > FMT_MAX_CHARS:      # a long value cut short as every message cuts it
        shown = show_value(value)
    raise ValueError(f"path shape {shape!r}: parameter {name!r} = {shown} is invalid; {why}"
                     f" ({spec.doc})")


def _check(shape, name, value, spec: ParamSpec):
    if spec.kind == "str":
        if not isinstance(value, str) or value not in spec.choices:
            _fail(shape, name, value, spec)
        return value
    if spec.kind == "bool":
        if not isinstance(value, (bool, np.bool_)):
            _fail(shape, name, value, spec)
        return bool(value)
    if spec.kind == "points":
        try:
            flat = np.asarray(value, dtype=object).ravel() if np.ndim(value) else [value]
        except ValueError:                      # ragged: not pairs
            flat = [None]
        if not all(isinstance(x, (int, float, np.integer, np.floating))
                   and not isinstance(x, (bool, np.bool_)) for x in flat):
            _fail(shape, name, value, spec, "allowed: a list of [x, y] pairs of numbers "
                  "(not strings or booleans)")
        try:
            pts = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            _fail(shape, name, value, spec, "allowed: a list of [x, y] pairs")
        if pts.ndim != 2 or pts.shape[1] != 2 or pts.shape[0] < 2:
            _fail(shape, name, value, spec, "allowed: a list of at least 2 [x, y] pairs")
        if not np.all(np.isfinite(pts)) or np.any(np.abs(pts) > spec.hi):
            _fail(shape, name, value, spec,
                  f"allowed: finite coordinates in [{spec.lo:g}, {spec.hi:g}] {spec.unit}")
        seg = np.hypot(*np.diff(pts, axis=0).T)
        if np.any(seg < 1e-6):
            i = int(np.argmax(seg < 1e-6))
            _fail(shape, name, value, spec,
                  f"waypoints {i} and {i + 1} coincide; allowed: consecutive points "
                  "≥ 1e-6 m apart")
        return pts
    if (isinstance(value, (bool, np.bool_)) or isinstance(value, str) or np.ndim(value) != 0
            or not np.issubdtype(np.asarray(value).dtype, np.number)
            or np.iscomplexobj(value)):
        _fail(shape, name, value, spec)  # numbers only (Python, numpy or 0-d JAX scalars)
    if not math.isfinite(float(value)):
        _fail(shape, name, value, spec)
    if spec.kind == "int":
        if float(value) != int(value):
            _fail(shape, name, value, spec)
        value = int(value)
    else:
        value = float(value)
    if not spec.lo <= value <= spec.hi:
        _fail(shape, name, value, spec)
    return value


def validate_params(shape: str, params: dict) -> dict:
    """Check ``params`` for ``shape`` against :data:`PARAM_SPECS` and fill in defaults.

    Raises ValueError naming the shape, the field, the value and what is allowed (unknown
    shape: lists the known ones; unknown parameter: lists the allowed names).
    """
    if shape not in PARAM_SPECS:
        raise ValueError(f"unknown path shape {shape!r}; known shapes: {', '.join(SHAPES)}")
    spec = PARAM_SPECS[shape]
    unknown = [k for k in params if k not in spec]
    if unknown:
        raise ValueError(f"path shape {shape!r}: unknown parameter {unknown[0]!r}; allowed: "
                         f"{', '.join(spec)}")
    out = {k: (np.asarray(s.default, float) if s.kind == "points" else s.default)
           for k, s in spec.items()}
    for k, v in params.items():
        out[k] = _check(shape, k, v, spec[k])
    return out


# --------------------------------------------------------------------------------------------
# builders


def _motion(p):
    return {k: p[k] for k in _MOTION}


def _line(p):
    m = _Placed(_Line(p["length"]), (p["x0"], p["y0"]), p["rotation"])
    return [m], 1.0


def _circle(p):
    m = _Placed(_Arc(p["radius"], p["laps"]), (p["x0"], p["y0"]), p["rotation"],
                mirror=p["direction"] == "cw")
    return [m], 1.0


def _sinusoid(p):
    A, k = p["amplitude"], TWO_PI / p["wavelength"]
    curve = _Parametric(lambda t: (t, A * np.sin(k * t)),
                        lambda t: (np.ones_like(t), A * k * np.cos(k * t)),
                        lambda t: (np.zeros_like(t), -A * k * k * np.sin(k * t)),
                        p["periods"] * p["wavelength"],
                        n_dense=int(min(max(20_001, 4_000 * p["periods"]), 400_001)))
    m = _Placed(curve, (p["x0"], p["y0"]), p["rotation"], mirror=p["direction"] == "cw")
    return [m], 1.0


def _cardioid(p):
    cw = p["direction"] == "cw"
    lap = _Placed(_Cardioid(p["size"]), (p["x0"], p["y0"]), p["rotation"], mirror=cw)
    return [lap] * p["laps"], (-1.0 if cw else 1.0)


def _square(p):
    cw = p["direction"] == "cw"
    L = p["side"]
    corners = [(0.0, 0.0), (L, 0.0), (L, L), (0.0, L)]
    c, s = math.cos(p["rotation"]), math.sin(p["rotation"])
    sg = -1.0 if cw else 1.0
    moves = []
    for _ in range(p["laps"]):
        for i, (cx, cy) in enumerate(corners):
            cy = sg * cy
            start = (p["x0"] + c * cx - s * cy, p["y0"] + s * cx + c * cy)
            moves.append(_Placed(_Line(L), start, p["rotation"] + sg * i * 0.5 * math.pi))
    return moves, sg


def _figure_eight(p):
    a = p["size"]
    curve = _Parametric(lambda t: (a * np.sin(t), -0.5 * a * np.sin(2 * t)),
                        lambda t: (a * np.cos(t), -a * np.cos(2 * t)),
                        lambda t: (-a * np.sin(t), 2 * a * np.sin(2 * t)),
                        TWO_PI * p["laps"], n_dense=int(min(50_001 * p["laps"], 1_000_001)))
    m = _Placed(curve, (p["x0"], p["y0"]), p["rotation"], mirror=p["direction"] == "cw")
    return [m], 1.0


def _polyline(p):
    pts = np.asarray(p["waypoints"], float)
    if p["closed"] and np.hypot(*(pts[-1] - pts[0])) > 1e-6:
        pts = np.vstack([pts, pts[:1]])
    moves = []
    for a, b in zip(pts[:-1], pts[1:]):
        d = b - a
        moves.append(_Placed(_Line(float(np.hypot(*d))), a, math.atan2(d[1], d[0])))
    return moves, 1.0


_GEOMETRY: dict[str, Callable] = {
    "line": _line, "circle": _circle, "sinusoid": _sinusoid, "cardioid": _cardioid,
    "square": _square, "figure_eight": _figure_eight, "polyline": _polyline,
}


def _doc_params(shape):
    lines = []
    for k, s in PARAM_SPECS[shape].items():
        if s.kind == "str":
            rng = " | ".join(repr(c) for c in s.choices)
        elif s.kind == "bool":
            rng = "true | false"
        elif s.kind == "points":
            rng = f"points, coordinates in [{s.lo:g}, {s.hi:g}]"
        else:
            rng = f"[{s.lo:g}, {s.hi:g}]"
        unit = f" [{s.unit}]" if s.unit else ""
        lines.append(f"      {k}{unit}: {s.doc}. Default {s.default!r}; allowed {rng}.")
    return "\n".join(lines)


def _make_builder(shape, summary):
    def build(**params) -> Path:
        p = validate_params(shape, params)
        moves, turn_sign = _GEOMETRY[shape](p)
        return _assemble(moves, turn_sign=turn_sign, **_motion(p))

    build.__name__ = build.__qualname__ = shape
    build.__doc__ = f"{summary}\n\n    Parameters (keyword only):\n{_doc_params(shape)}\n"
    return build


line = _make_builder("line", "Straight line from the start point along ``rotation``.")
circle = _make_builder("circle", "Circle through the start point, start tangent along "
                       "``rotation``, ``laps`` turns walked in one move.")
sinusoid = _make_builder("sinusoid", "Sinusoid y = A sin(2π x/λ) along the axis "
                         "``rotation`` from the start point, ``periods`` wavelengths.")
cardioid = _make_builder("cardioid", "Cardioid r = a(1 − cos φ) from its cusp at the start "
                         "point (start tangent along ``rotation``); one move per lap.")
square = _make_builder("square", "Square with a corner at the start point, first side along "
                       "``rotation``; every side is its own move (stop and turn at corners).")
figure_eight = _make_builder("figure_eight", "Figure eight (lemniscate of Gerono) through "
                             "the start point, axis along ``rotation``; laps in one move.")
polyline = _make_builder("polyline", "Waypoint polyline; every segment is its own move "
                         "(stop and turn at corners).")

SHAPES: dict[str, Callable[..., Path]] = {
    "line": line, "circle": circle, "sinusoid": sinusoid, "cardioid": cardioid,
    "square": square, "figure_eight": figure_eight, "polyline": polyline,
}


def make_path(shape: str, **params) -> Path:
    """Build the :class:`Path` of ``shape`` (a key of :data:`SHAPES`) from keyword
    parameters; every parameter, unit, default and range is in :data:`PARAM_SPECS` and in
    each builder's docstring.  Bad input raises ValueError naming the field, the value and
    the allowed range; an unknown shape lists the known ones.
    """
    if shape not in SHAPES:
        raise ValueError(f"unknown path shape {shape!r}; known shapes: {', '.join(SHAPES)}")
    return SHAPES[shape](**params)
