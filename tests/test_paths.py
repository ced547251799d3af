"""Tests for hlip_jax.core.paths: tables, speed profiles, turns in place, validation, reference().

Checks are independent of the builders' own formulas: finite differences and cumulative
integrals of the sampled tables, the shapes' implicit equations, profile closed forms worked
out by hand, and numpy's np.interp for the interpolation.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hlip_jax.core import paths as P

# Fine tables for the derivative checks: dt = 2 ms.
FINE = dict(n_samples=25_001, t_final=50.0)  # every default shape fits in 50 s
ALL_SHAPES = list(P.SHAPES)


def _np(path):
    return {k: np.asarray(v) for k, v in path._asdict().items()}


def _moving_mask(p):
    n = p["x"].shape[0]
    return np.arange(n) * p["dt"] < p["duration"]


@pytest.fixture(scope="module")
def fine_paths():
    return {s: _np(P.make_path(s, **FINE)) for s in ALL_SHAPES}


# ---------------------------------------------------------------------------------------
# derivatives are consistent
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("shape", ALL_SHAPES)
def test_velocity_is_derivative_of_position(fine_paths, shape):
    p = fine_paths[shape]
    dt = float(p["dt"])
    # Central differences: O(dt²·jerk) ≈ 1e-6 m/s on smooth parts; at a speed-profile kink
    # (acceleration jumps by ≤ 2·accel = 0.5 m/s²) the error is ≤ dt·Δa/4 ≈ 2.5e-4 m/s.
    # Tolerance 1e-3 m/s = 0.2 % of the 0.5 m/s peak speed.
    for pos, vel in (("x", "vx"), ("y", "vy")):
        fd = (p[pos][2:] - p[pos][:-2]) / (2 * dt)
        np.testing.assert_allclose(p[vel][1:-1], fd, atol=1e-3, err_msg=f"{shape}: {vel}")
    # Position is the integral of velocity (trapezoid rule, error O(dt²) per unit time):
    # over ~30 s the drift stays below 1e-4 m.
    for pos, vel in (("x", "vx"), ("y", "vy")):
        steps = 0.5 * (p[vel][1:] + p[vel][:-1]) * dt
        integ = p[pos][0] + np.concatenate([[0.0], np.cumsum(steps)])
        np.testing.assert_allclose(p[pos], integ, atol=1e-4, err_msg=f"{shape}: {pos}")


@pytest.mark.parametrize("shape", ALL_SHAPES)
def test_heading_is_integral_of_heading_rate_and_continuous(fine_paths, shape):
    p = fine_paths[shape]
    dt = float(p["dt"])
    th, om = p["theta"], p["omega"]
    # Heading rate jumps (turn start/stop, the cardioid's cusp) make pointwise finite
    # differences meaningless at a few samples, so compare the integral: each jump costs at
    # most dt·|jump|/2 ≈ 1e-3 rad, smooth parts O(dt²).  Tolerance 1e-2 rad over ≤ 12 jumps.
    integ = th[0] + np.concatenate([[0.0], np.cumsum(0.5 * (om[1:] + om[:-1]) * dt)])
    np.testing.assert_allclose(th, integ, atol=1e-2, err_msg=shape)
    # continuous (never wrapped): a step moves at most max|θ̇|·dt (+ rounding)
    assert np.max(np.abs(np.diff(th))) <= np.max(np.abs(om)) * dt + 1e-9
    # heading is the direction of travel wherever the path moves
    sp = np.hypot(p["vx"], p["vy"])
    mv = sp > 1e-6
    ang = np.arctan2(p["vy"][mv], p["vx"][mv])
    diff = (th[mv] - ang + np.pi) % (2 * np.pi) - np.pi
    assert np.max(np.abs(diff)) < 1e-9


def test_heading_unwrapped_over_laps():
    # two ccw circle laps turn the heading by exactly 4π; cw by −4π
    for d, sign in (("ccw", 1.0), ("cw", -1.0)):
        p = P.make_path("circle", laps=2, direction=d, t_final=80.0)
        assert float(p.theta[-1] - p.theta[0]) == pytest.approx(sign * 4 * np.pi, abs=1e-12)
    # two cardioid laps: 3π per lap plus a half turn at the cusp between them
    p = P.make_path("cardioid", laps=2, t_final=80.0)
    assert float(p.theta[-1] - p.theta[0]) == pytest.approx(7 * np.pi, abs=1e-12)


# ---------------------------------------------------------------------------------------
# speed profiles: peak and duration against closed forms
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("profile,L,v,a,peak,dur", [
    # trapezoid reaches v: duration L/v + v/a
    ("trapezoid", 4.0, 0.5, 0.25, 0.5, 4.0 / 0.5 + 0.5 / 0.25),
    ("trapezoid", 10.0, 0.8, 0.5, 0.8, 10.0 / 0.8 + 0.8 / 0.5),
    # too short for v (L < v²/a): triangle with peak √(aL), duration 2√(L/a)
    ("trapezoid", 0.5, 0.8, 0.5, math.sqrt(0.25), 2 * math.sqrt(0.5 / 0.5)),
    # triangle: peak v at mid length, duration 2L/v
    ("triangle", 4.0, 0.5, 0.25, 0.5, 2 * 4.0 / 0.5),
    # triangle needing a = v²/L = 1.28 > 0.25: peak lowered to √(aL) = 0.5
    ("triangle", 0.5, 0.8, 0.5, 0.5, 2 * 0.5 / 0.5),
])
def test_profile_peak_and_duration(profile, L, v, a, peak, dur):
    p = _np(P.make_path("line", length=L, peak_speed=v, accel=a, profile=profile, **FINE))
    assert float(p["duration"]) == pytest.approx(dur, rel=1e-12)
    sp = np.hypot(p["vx"], p["vy"])
    # the table's maximum misses the apex of a triangle by at most accel·dt (2 ms × a)
    assert sp.max() <= peak + 1e-12
    assert sp.max() >= peak - a * float(p["dt"]) - 1e-12
    # the peak of a triangle is at mid length
    if profile == "triangle" or L < v * v / a:
        i = int(np.argmax(sp))
        assert p["x"][i] == pytest.approx(0.5 * L, abs=peak * float(p["dt"]))
    # ends at rest at the far end, length exactly L
    assert p["x"][-1] == pytest.approx(L, abs=1e-12)
    assert sp[-1] == 0.0
    # the profile record agrees
    sp_rec = P.speed_profile(L, v, a, profile)
    assert sp_rec.duration == pytest.approx(dur, rel=1e-12) and sp_rec.peak == pytest.approx(peak)


def test_square_duration_closed_form():
    L, v, a, w = 2.0, 0.5, 0.25, 0.5
    p = P.make_path("square", side=L, peak_speed=v, accel=a, turn_rate=w, laps=2,
                    t_final=120.0)
    # triangle per side (v²/L = 0.125 ≤ a): 2L/v; 8 sides, 7 quarter turns at rate w
    assert float(p.duration) == pytest.approx(8 * 2 * L / v + 7 * (np.pi / 2) / w, rel=1e-12)


def test_initial_turn_in_place():
    p = _np(P.make_path("line", align_start=False, heading0=np.pi / 2, turn_rate=0.4, **FINE))
    t_turn = (np.pi / 2) / 0.4
    assert float(p["duration"]) == pytest.approx(t_turn + 4.0 / 0.5 + 0.5 / 0.25, rel=1e-12)
    t = np.arange(p["x"].shape[0]) * float(p["dt"])
    turning = t < t_turn
    assert p["theta"][0] == pytest.approx(np.pi / 2)
    np.testing.assert_array_equal(p["omega"][turning], -0.4)  # shorter way: clockwise
    np.testing.assert_array_equal(p["x"][turning], 0.0)
    assert abs(p["theta"][~turning]).max() < 1e-12


def test_truncated_path_keeps_full_duration():
    p = P.make_path("circle", t_final=5.0, n_samples=101)
    assert float(p.duration) > 5.0  # cut: the table ends before the motion
    r = P.reference(p, 100.0)
    np.testing.assert_allclose(r.position, [p.x[-1], p.y[-1]])
    np.testing.assert_array_equal(r.velocity, 0.0)


# ---------------------------------------------------------------------------------------
# geometry
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("direction,sign", [("ccw", 1.0), ("cw", -1.0)])
def test_circle_stays_on_radius(direction, sign):
    R, x0, y0, rot = 1.7, 0.3, -0.4, 0.6
    p = _np(P.make_path("circle", radius=R, direction=direction, x0=x0, y0=y0, rotation=rot,
                        laps=2, t_final=80.0))
    # centre: R to the left (ccw) / right (cw) of the start tangent
    cx, cy = x0 - sign * R * np.sin(rot), y0 + sign * R * np.cos(rot)
    np.testing.assert_allclose(np.hypot(p["x"] - cx, p["y"] - cy), R, atol=1e-12)
    # heading rate = ±speed / R while moving
    sp = np.hypot(p["vx"], p["vy"])
    np.testing.assert_allclose(p["omega"], sign * sp / R, atol=1e-12)


def test_shapes_on_their_implicit_curves(fine_paths):
    # sinusoid: y = A sin(2π x / λ)
    p = fine_paths["sinusoid"]
    np.testing.assert_allclose(p["y"], 0.5 * np.sin(2 * np.pi * p["x"] / 4.0), atol=1e-9)
    # figure eight x = a sin τ, y = −(a/2) sin 2τ  ⇒  a² y² = x² (a² − x²)
    p = fine_paths["figure_eight"]
    a = 2.0
    np.testing.assert_allclose(a**2 * p["y"] ** 2, p["x"] ** 2 * (a**2 - p["x"] ** 2), atol=1e-9)
    # cardioid r = a(1 − cos φ), cusp at the origin: (x² + y² + a x)² = a² (x² + y²)
    p = fine_paths["cardioid"]
    a = 1.0
    r2 = p["x"] ** 2 + p["y"] ** 2
    np.testing.assert_allclose((r2 + a * p["x"]) ** 2, a**2 * r2, atol=1e-9)
    # each closed shape ends where it started
    for s in ("circle", "cardioid", "square", "figure_eight"):
        q = fine_paths[s]
        assert np.hypot(q["x"][-1] - q["x"][0], q["y"][-1] - q["y"][0]) < 1e-9, s


@pytest.mark.parametrize("direction", ["ccw", "cw"])
def test_square_corners_stop_and_turn_at_rate_limit(direction):
    w, L = 0.7, 2.0
    p = _np(P.make_path("square", side=L, turn_rate=w, direction=direction, **FINE))
    sign = 1.0 if direction == "ccw" else -1.0
    sp = np.hypot(p["vx"], p["vy"])
    turning = p["omega"] != 0.0
    # whenever the heading changes the robot stands still, at a corner, turning at ±w
    assert np.all(sp[turning] == 0.0)
    np.testing.assert_array_equal(p["omega"][turning], sign * w)
    corners = {(0.0, 0.0), (L, 0.0), (L, sign * L), (0.0, sign * L)}
    for x, y in zip(p["x"][turning], p["y"][turning]):
        assert min(math.hypot(x - cx, y - cy) for cx, cy in corners) < 1e-12
    # three corners, each turning exactly π/2 (one run of turning samples per corner)
    runs = np.flatnonzero(np.diff(turning.astype(int)) == 1)
    assert len(runs) == 3
    # straight sides: heading constant while moving
    assert np.all(p["omega"][sp > 0] == 0.0)
    assert p["theta"][-1] == pytest.approx(sign * 3 * np.pi / 2, abs=1e-12)
    # every side is a triangle profile: zero speed at the corners, peak 0.5 at mid side
    assert sp.max() == pytest.approx(0.5, abs=0.25 * 2 * float(p["dt"]))


def test_polyline_corners_and_closing():
    wp = [(0.0, 0.0), (3.0, 0.0), (3.0, -1.0), (1.0, 1.0)]
    p = _np(P.make_path("polyline", waypoints=wp, closed=True, **FINE))
    turning = p["omega"] != 0
    sp = np.hypot(p["vx"], p["vy"])
    assert np.all(sp[turning] == 0.0)
    assert np.all(np.abs(p["omega"][turning]) == 0.5)
    # segment headings 0, −π/2, 3π/4, −3π/4; turns the shorter way: −π/2, −3π/4, +π/2
    expected = -np.pi / 2 - 3 * np.pi / 4 + np.pi / 2
    assert p["theta"][-1] - p["theta"][0] == pytest.approx(expected, abs=1e-12)
    assert (p["x"][-1], p["y"][-1]) == pytest.approx((0.0, 0.0), abs=1e-12)


# ---------------------------------------------------------------------------------------
# reference(): interpolation, jit + vmap over a batch of shapes
# ---------------------------------------------------------------------------------------
def test_reference_jit_vmap_over_shapes():
    kw = dict(n_samples=1024, t_final=50.0)
    batch = P.stack_paths([P.make_path(s, **kw) for s in ALL_SHAPES]
                          + [P.make_path("line", n_samples=1024, t_final=20.0, length=1.0)])
    ts = jnp.array([-1.0, 0.0, 0.013, 3.3, 7.77, 19.99, 33.3, 49.99, 50.0, 80.0])

    f = jax.jit(jax.vmap(jax.vmap(P.reference, in_axes=(None, 0)), in_axes=(0, None)))
    out = f(batch, ts)
    assert out.position.shape == (len(ALL_SHAPES) + 1, len(ts), 2)

    for b in range(batch.x.shape[0]):
        pb = jax.tree.map(lambda a: np.asarray(a[b]), batch)
        grid = np.arange(pb.x.shape[0]) * pb.dt
        t_end = min(float(pb.duration), grid[-1])
        for j, t in enumerate(np.asarray(ts)):
            moving = 0.0 <= t < t_end
            ref = [np.interp(t, grid, getattr(pb, k)) for k in ("x", "y", "theta")]
            vel = [np.interp(t, grid, getattr(pb, k)) if moving else 0.0
                   for k in ("vx", "vy", "omega")]
            np.testing.assert_allclose(out.position[b, j], ref[:2], atol=1e-12)
            np.testing.assert_allclose(out.heading[b, j], ref[2], atol=1e-12)
            np.testing.assert_allclose(out.velocity[b, j], vel[:2], atol=1e-12)
            np.testing.assert_allclose(out.heading_rate[b, j], vel[2], atol=1e-12)
    # before the start: the start pose; after the end: the final pose, at rest
    np.testing.assert_allclose(out.position[:, 0], np.stack([batch.x[:, 0], batch.y[:, 0]], -1))
    np.testing.assert_allclose(out.position[:, -1], np.stack([batch.x[:, -1], batch.y[:, -1]], -1))
    np.testing.assert_array_equal(out.velocity[:, -1], 0.0)


def test_stack_paths_rejects_mixed_sizes():
    with pytest.raises(ValueError, match="n_samples"):
        P.stack_paths([P.make_path("line", n_samples=10), P.make_path("line", n_samples=11)])


# ---------------------------------------------------------------------------------------
# validation
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("shape,params,field", [
    ("circle", dict(radius=-1.0), "radius"),
    ("circle", dict(radius=float("nan")), "radius"),
    ("circle", dict(laps=1.5), "laps"),
    ("circle", dict(direction="up"), "direction"),
    ("square", dict(side="2"), "side"),
    ("square", dict(laps=True), "laps"),
    ("line", dict(peak_speed=10.0), "peak_speed"),
    ("line", dict(profile="s-curve"), "profile"),
    ("line", dict(n_samples=1), "n_samples"),
    ("sinusoid", dict(wavelength=0.0), "wavelength"),
    ("cardioid", dict(align_start="yes"), "align_start"),
    ("polyline", dict(waypoints=[(0, 0)]), "waypoints"),
    ("polyline", dict(waypoints=[(0, 0), (1, 0), (1, 0)]), "waypoints"),
    ("polyline", dict(waypoints=[(0, 0), (1, float("inf"))]), "waypoints"),
    ("polyline", dict(waypoints=[("0", "0"), ("2", "0")]), "waypoints"),
    ("polyline", dict(waypoints=[(True, 0), (2, 0)]), "waypoints"),
    ("polyline", dict(waypoints=[(0, 0), (2,)]), "waypoints"),
])
def test_bad_parameters_name_the_field(shape, params, field):
    with pytest.raises(ValueError) as exc:
        P.make_path(shape, **params)
    msg = str(exc.value)
    assert repr(field) in msg and repr(shape) in msg and "allowed" in msg


def test_bad_parameter_message_gives_value_and_range():
    with pytest.raises(ValueError, match=r"'radius' = -1.0 .*\[0.1, 1000\] m"):
        P.make_path("circle", radius=-1.0)


def test_numpy_and_jax_scalars_accepted():
    p = P.make_path("circle", radius=np.float32(2.0), laps=np.int64(1), peak_speed=jnp.array(0.4))
    assert float(p.duration) == pytest.approx(2 * np.pi * 2.0 / 0.4 + 0.4 / 0.25, rel=1e-6)
    with pytest.raises(ValueError, match="'radius'"):
        P.make_path("circle", radius=np.array([1.0, 2.0]))


def test_unknown_shape_and_parameter():
    with pytest.raises(ValueError, match="known shapes: line, circle, sinusoid"):
        P.make_path("hexagon")
    with pytest.raises(ValueError, match="unknown parameter 'radus'.*radius"):
        P.make_path("circle", radus=2.0)
    with pytest.raises(ValueError, match="'x0'"):  # polylines are placed by their waypoints
        P.make_path("polyline", x0=1.0)


def test_param_specs_are_data_with_valid_defaults():
    for shape, spec in P.PARAM_SPECS.items():
        assert shape in P.SHAPES
        for name, s in spec.items():
            assert s.kind in ("float", "int", "str", "bool", "points"), (shape, name)
            assert s.doc, (shape, name)
            if s.kind in ("float", "int"):
                assert s.lo <= s.default <= s.hi, (shape, name)
            if s.kind == "str":
                assert s.default in s.choices
        # defaults validate, and every builder's docstring lists every parameter
        P.validate_params(shape, {})
        for name in spec:
            assert name in P.SHAPES[shape].__doc__
