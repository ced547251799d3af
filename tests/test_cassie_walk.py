"""Tests of the Cassie walking plant: trajectories and stepping-law pieces (closed forms, finite
differences), touchdown detection, the config → params path, the gait presets, and a short
walk of the shipped underactuated controller on MJX (slow)."""

import math
import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hlip_jax.core import hlip
from hlip_jax.sweepio import sweep
from hlip_jax.simulation.config import (CassieConfig, DisturbanceConfig, HLIPConfig, ImplConfig, PushConfig,
                             ScenarioConfig)
from hlip_jax.plants.base import StepCommand
from hlip_jax.plants.cassie import gaits, model, outputs, plant, tick

from support import cassie_orbits as orbits

Z0, TS, TD = 0.85, 0.25, 0.1


def _cmd(x, u, u_next):
    A, B = hlip.s2s_matrices(Z0, TS, TD)
    x = jnp.asarray(x)
    x_next = x @ A.T + jnp.asarray(u)[:, None] * B
    return StepCommand(t=jnp.zeros(()), stance=jnp.int32(1), x_hlip=x, u_hlip=jnp.asarray(u),
                       x_hlip_next=x_next, u_hlip_next=jnp.asarray(u_next), gain=jnp.zeros((2, 3)),
                       heading=jnp.zeros(()), t_ssp=jnp.asarray(TS), t_dsp=jnp.asarray(TD),
                       z0=jnp.asarray(Z0))


def test_hlip_phase_state_ends_at_next_preimpact():
    cmd = _cmd([[0.1, 0.05, 0.4], [-0.2, 0.11, 0.2]], [0.2, 0.25], [0.2, -0.25])
    # the H-LIP at the end of this step's SSP is the closed loop's x_H,k+1 = A x_H,k + B u_H,k
    # (closed-form flows on both sides; float64 round-off only)
    np.testing.assert_allclose(tick.hlip_at(cmd, TS), cmd.x_hlip_next, atol=1e-12)
    # at SSP⁺ it is the DSP flow (p̈ = 0) with the foot switched: p⁺ = p + v T_D − u, and c
    # moved on by v T_D
    x0 = np.asarray(tick.hlip_at(cmd, 0.0))
    x, u = np.asarray(cmd.x_hlip), np.asarray(cmd.u_hlip)
    np.testing.assert_allclose(x0[:, 1], x[:, 1] + x[:, 2] * TD - u, atol=1e-12)
    np.testing.assert_allclose(x0[:, 0], x[:, 0] + x[:, 2] * TD, atol=1e-12)
    np.testing.assert_allclose(x0[:, 2], x[:, 2], atol=1e-12)


def test_error_flow_to_impact_is_the_lip_flow():
    x = jnp.array([[0.3, 0.04, 0.3], [0.1, -0.1, 0.25]])
    tau = 0.13
    got = tick.flow_to_impact(x, tau, Z0)
    lam = np.sqrt(hlip.GRAVITY / Z0)
    p = np.asarray(x[:, 1]) * np.cosh(lam * tau) + np.asarray(x[:, 2]) * np.sinh(lam * tau) / lam
    v = np.asarray(x[:, 1]) * lam * np.sinh(lam * tau) + np.asarray(x[:, 2]) * np.cosh(lam * tau)
    np.testing.assert_allclose(got[:, 1], p, rtol=1e-12)
    np.testing.assert_allclose(got[:, 2], v, rtol=1e-12)
    np.testing.assert_allclose(got[:, 0] - got[:, 1], x[:, 0] - x[:, 1], atol=1e-12)
    # linear: the flow of a difference is the difference of the flows
    y = jnp.array([[0.0, 0.02, 0.1], [0.0, 0.07, -0.1]])
    np.testing.assert_allclose(tick.flow_to_impact(x - y, tau, Z0),
                               tick.flow_to_impact(x, tau, Z0) - tick.flow_to_impact(y, tau, Z0),
                               atol=1e-12)


def test_heading_clip_limits_length_and_width_in_the_heading_frame():
    """Length along the heading to ±max, width across it to [min, max] on the swing side
    (left swing: +); a step inside the limits is unchanged (closed form, 1e-12)."""
    g = types.SimpleNamespace(step_length_max=0.4, step_width_min=0.1, step_width_max=0.5)
    th = 0.6
    R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    for sw, along, across, want in ((0, 0.2, 0.3, (0.2, 0.3)), (0, 0.9, 0.05, (0.4, 0.1)),
                                    (0, -0.9, -0.2, (-0.4, 0.1)), (1, 0.1, -0.7, (0.1, -0.5)),
                                    (1, 0.1, 0.2, (0.1, -0.1))):
        u = R @ np.array([along, across])
        got = np.asarray(tick.heading_clip(jnp.asarray(u), th, sw, g))
        np.testing.assert_allclose(R.T @ got, want, atol=1e-12)


def _touch_args(z, phase, t_phase, touch):
    """contacts() inputs for a robot whose four contact spheres sit at heights ``z`` (site
    centres; sphere bottoms at z − radius) with the left foot the stance foot of the SSP."""
    site = np.zeros((4, 3))
    site[:, 2] = np.asarray(z) + model.FOOT_SPHERE_RADIUS
    terms = types.SimpleNamespace(site_pos=jnp.asarray(site))
    ctx = types.SimpleNamespace(new_st=jnp.int32(0), real=None, gait=types.SimpleNamespace(early_contact=0.7),
                                cmd=types.SimpleNamespace(t_ssp=0.3))
    s = types.SimpleNamespace(phase=jnp.int32(phase), t_phase=jnp.asarray(t_phase),
                              touch=jnp.int32(touch))
    return ctx, s, terms


def test_contacts_and_touchdown_detection():
    """SSP: only the stance foot's sites are constraints.  A swing-foot touch counts ticks in a
    row; the touchdown needs TOUCHDOWN_TICKS of them and at least early_contact · T_SSP into
    the SSP; a bounce (no touch) resets the count.  DSP: every touching site is a contact."""
    down, up = 0.001, 0.02
    n = tick.TOUCHDOWN_TICKS
    ctx, s, terms = _touch_args([down, down, down, up], tick.SSP, 0.25, n - 1)
    c = tick.contacts(ctx, s, None, terms)
    assert np.asarray(c.sites).tolist() == [1, 1, 0, 0] and np.asarray(c.foot).tolist() == [True, False]
    assert int(c.count) == n and bool(c.touchdown)
    ctx, s, terms = _touch_args([down, down, down, up], tick.SSP, 0.25, n - 2)
    assert not bool(tick.contacts(ctx, s, None, terms).touchdown)            # not long enough yet
    ctx, s, terms = _touch_args([down, down, down, up], tick.SSP, 0.19, n + 5)
    assert not bool(tick.contacts(ctx, s, None, terms).touchdown)            # before 0.7 · 0.3 s
    ctx, s, terms = _touch_args([down, down, up, up], tick.SSP, 0.25, n + 5)
    c = tick.contacts(ctx, s, None, terms)
    assert int(c.count) == 0 and not bool(c.touchdown)                 # bounce resets
    ctx, s, terms = _touch_args([down, up, down, down], tick.DSP, 0.01, 0)
    c = tick.contacts(ctx, s, None, terms)
    assert np.asarray(c.sites).tolist() == [1, 0, 1, 1] and int(c.count) == 0


def test_landing_fraction():
    """The swing profile returns to the ground at s*: the real root in [½, 1] of the quartic
    64 c s (1 − s)³ − σ (3 − 2 s) = 0 (h(s) / s², c = clearance, σ = strike), found here by
    numpy's companion-matrix roots.  Bisection to 2⁻⁴¹ and float64 roots: 1e-9 (and |h| < 1e-9 m
    at s* T_SSP)."""
    for c, sg in ((0.0646, 0.0188), (0.08, 0.01), (0.12, 0.05), (0.05, 0.0)):
        s_star = float(outputs.landing_fraction(jnp.asarray(c), jnp.asarray(sg)))
        if sg == 0.0:
            assert abs(s_star - 1.0) < 1e-9
            continue
        poly = np.polynomial.Polynomial([-3 * sg, 64 * c + 2 * sg, -192 * c, 192 * c, -64 * c])
        real = [r.real for r in poly.roots() if abs(r.imag) < 1e-12 and 0.5 <= r.real <= 1.0]
        assert len(real) == 1, poly.roots()
        assert abs(s_star - real[0]) < 1e-9, (s_star, real)
        assert abs(float(outputs.swing_height(jnp.asarray(s_star * TS), TS, c, sg))) < 1e-9


def test_swing_profile_and_blend():
    h, s = 0.08, 0.01
    f = lambda t: outputs.swing_height(t, TS, h, s)
    assert abs(float(f(0.0))) < 1e-15
    np.testing.assert_allclose(float(f(TS / 2)), h - s / 2, atol=1e-12)   # apex minus half the strike
    np.testing.assert_allclose(float(f(TS)), -s, atol=1e-12)
    # derivatives by nested jvp vs central differences (step 1e-5 s: error ~1e-9 relative)
    for t in (0.03, 0.11, 0.2):
        v, d1, d2 = outputs.with_derivatives(f, jnp.asarray(t))
        e = 1e-5
        np.testing.assert_allclose(float(d1), (float(f(t + e)) - float(f(t - e))) / (2 * e), rtol=1e-6)
        np.testing.assert_allclose(float(d2), (float(f(t + e)) - 2 * float(v) + float(f(t - e))) / e**2,
                                   rtol=1e-4, atol=1e-3)
    # lift-off with zero velocity; c(t): 0 → 1 reached at REACH·T_SSP, zero slope at both ends
    assert abs(float(outputs.with_derivatives(f, jnp.asarray(0.0))[1])) < 1e-12
    c = lambda t: outputs.blend(t, TS, 0.8)
    assert float(c(0.0)) == 0.0 and float(c(0.8 * TS)) == 1.0 and float(c(TS)) == 1.0
    for t in (0.0, 0.8 * TS):
        assert abs(float(outputs.with_derivatives(c, jnp.asarray(t))[1])) < 1e-9


def test_orbit_steps_are_hlip_orbits():
    u, p, v = orbits.orbit_step(Z0, TS, TD, 0.5, 0.0, 0.25, np.zeros(1), 0)
    p1 = hlip.p1_orbit(Z0, TS, TD, 0.5)
    p2 = hlip.p2_orbit(Z0, TS, TD, 0.0, 0.25)
    np.testing.assert_allclose([u[0, 0], p[0, 0], v[0, 0]], [p1.u, p1.p, p1.v], rtol=1e-12)
    np.testing.assert_allclose([u[1, 0], p[1, 0], v[1, 0]], [p2.u_left, p2.p_left, p2.v_left], rtol=1e-12)
    # rotated by the heading
    u90, _, _ = orbits.orbit_step(Z0, TS, TD, 0.5, 0.0, 0.25, np.full(1, np.pi / 2), 0)
    np.testing.assert_allclose(u90[:, 0], [-u[1, 0], u[0, 0]], atol=1e-12)


def test_make_params_pushes_and_validation():
    cfg = ScenarioConfig(plant="cassie", hlip=HLIPConfig(t_ssp=0.3, t_dsp=0.1),
                         disturbance=DisturbanceConfig(pushes=(PushConfig(time=1.0, duration=0.2,
                                                                          force=50.0, direction=90.0),)))
    p = plant.make_params(cfg, 2)
    np.testing.assert_allclose(p.push_force[0], [0.0, 50.0], atol=1e-12)
    assert p.push_start[0] == 1.0 and abs(p.push_end[0] - 1.2) < 1e-12 and p.push_start[1] < 0
    # the tick budget holds the latest touchdown, T_DSP + LATE_SSP · T_SSP / s* ≤ LATE_SSP ·
    # (T_DSP + T_SSP / s*), rounded up to 10 ms; s*, the swing profile's landing fraction, is
    # checked against its polynomial's root in test_landing_fraction
    assert tick.LATE_SSP == 1.2
    s_star = float(outputs.landing_fraction(CassieConfig().clearance, CassieConfig().strike))
    assert 0.5 < s_star < 1.0
    assert p.ticks.shape == (10 * math.ceil(round(120 * (0.1 + 0.3 / s_star), 6)),)
    assert plant.tick_budget(0.45) == 540 and plant.tick_budget(0.28) == 340
    assert plant.make_params(cfg, 2, t_step=0.5).ticks.shape == (600,)   # sweep-wide budget
    # the gait is data: CassieConfig values reach Params.gait, output frequencies its gains
    cfg2 = ScenarioConfig(plant="cassie", cassie=CassieConfig(omega_swing=20.0))
    g = plant.make_params(cfg2, 1).gait
    np.testing.assert_allclose(g.gains.kp[6:14], 400.0)
    np.testing.assert_allclose(g.gains.kd[6:14], 40.0)
    # simulated leaf-spring damping: the model's own by default (shin 0.1, heel 0), per scenario
    np.testing.assert_allclose(g.damping, [0.1, 0.0, 0.1, 0.0])
    gd = plant.make_gait(CassieConfig(shin_damping=2.0, heel_damping=3.0))
    np.testing.assert_allclose(gd.damping, [2.0, 3.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="pushes"):
        plant.make_params(cfg, 0)
    # step noise of the sweep's disturbance table reaches the plant (0 by default)
    assert float(plant.make_params(cfg, 1).noise_v) == 0.0
    cfgn = ScenarioConfig(plant="cassie", disturbance=DisturbanceConfig(noise_v=0.05, step_error=0.02))
    pn = plant.make_params(cfgn, 1)
    assert float(pn.noise_v) == 0.05 and float(pn.step_error) == 0.02
    # the CLF-QP fallback is data too; its ADMM budget and tolerance are static sweep-wide
    assert float(g.hold_unsolved) == 1.0
    cfg3 = ScenarioConfig(plant="cassie", cassie=CassieConfig(qp_fallback="iterate", qp_max_iter=50))
    assert float(plant.make_params(cfg3, 1).gait.hold_unsolved) == 0.0
    from hlip_jax.simulation import arrays
    _, static = arrays.build([cfg3])
    assert static.plant_settings.qp.max_iter == 50 and static.plant_settings.qp.eps_abs == 1e-4
    assert static.plant_settings.physics == "jax"
    with pytest.raises(ValueError, match="cassie.qp_max_iter"):
        arrays.build([cfg2, cfg3])
    assert arrays.build([ScenarioConfig()])[1].plant_settings is None     # H-LIP plant
    # the CLF-QP's block loop is static and sweep-wide too
    assert arrays.build([cfg3])[1].plant_settings.qp.early_exit is True
    cfg4 = ScenarioConfig(plant="cassie", cassie=CassieConfig(qp_max_iter=50),
                          impl=ImplConfig(qp_loop="fixed"))
    assert arrays.build([cfg4])[1].plant_settings.qp.early_exit is False
    with pytest.raises(ValueError, match="impl.qp_loop"):
        arrays.build([cfg3, cfg4])
    cfg6 = ScenarioConfig(plant="cassie", cassie=CassieConfig(qp_max_iter=50),
                          impl=ImplConfig(qp_loop="compact"))
    compact = arrays.build([cfg6])[1].plant_settings
    assert compact.qp.early_exit is True and compact.qp_compact is True
    assert arrays.build([cfg3])[1].plant_settings.qp_compact is False
    # and so is its linear solve
    cfg5 = ScenarioConfig(plant="cassie", cassie=CassieConfig(qp_max_iter=50),
                          impl=ImplConfig(qp_linsys="inverse"))
    assert arrays.build([cfg5])[1].plant_settings.qp.linsys == "inverse"
    assert arrays.build([cfg3])[1].plant_settings.qp.linsys == "cholesky"
    with pytest.raises(ValueError, match="impl.qp_linsys"):
        arrays.build([cfg3, cfg5])


def test_scenario_model_sets_the_spring_damping():
    """The scenario's MJX model carries its own leaf-spring damping and nothing else changes."""
    c = plant.cassie()
    mx = tick.scenario_model(jnp.array([1.0, 2.0, 3.0, 4.0]))
    springs = list(tick.dynamics.spring_dofs(c))
    got = np.asarray(mx.dof_damping)
    np.testing.assert_array_equal(got[springs], [1.0, 2.0, 3.0, 4.0])
    rest = np.setdiff1d(np.arange(c.index.nv), springs)
    np.testing.assert_array_equal(got[rest], c.mj_model.dof_damping[rest])
    np.testing.assert_array_equal(c.mj_model.dof_damping[springs], [0.1, 0.0, 0.1, 0.0])


PRESET_SWEEP = """
name = "g"
[base]
plant = "cassie"
[base.hlip]
t_ssp = 0.3
[base.cassie]
omega_swing = 12.0
[[paths]]
shape = "line"
"""


def test_gait_preset_fills_unset_fields_and_the_file_wins():
    """Every field of the "paper" preset the file leaves unset takes the preset's value (hlip,
    gain, mpc and cassie tables alike); fields the file sets keep the file's value; the
    CassieConfig defaults are the preset's; an unknown gait name is a one-line error listing
    the presets; the H-LIP plant gets no preset."""
    P = gaits.preset("paper")
    cfg = sweep.parse_sweep(PRESET_SWEEP).scenarios[0]
    assert cfg.hlip.t_ssp == 0.3 and cfg.cassie.omega_swing == 12.0
    assert cfg.hlip.z0 == P["hlip.z0"] and cfg.hlip.t_dsp == P["hlip.t_dsp"]
    assert cfg.gain.type == P["gain.type"] and cfg.gain.r == P["gain.r"]
    assert cfg.mpc.step_width_min == P["mpc.step_width_min"]
    assert cfg.cassie.omega_pelvis == P["cassie.omega_pelvis"]
    for k, v in P.items():
        table, name = k.split(".")
        if table == "cassie":
            assert getattr(CassieConfig(), name) == v, k
    bad = PRESET_SWEEP.replace("omega_swing = 12.0", 'gait = "fast"')
    with pytest.raises(sweep.SweepError, match="cassie.gait: 'fast' is not allowed; allowed: one of 'paper'"):
        sweep.parse_sweep(bad)
    hl = sweep.parse_sweep(PRESET_SWEEP.replace('plant = "cassie"', 'plant = "hlip"')).scenarios[0]
    assert hl.hlip.z0 == HLIPConfig().z0


@pytest.mark.slow
@pytest.mark.timeout(1200)
def test_init_faces_the_path_heading():
    """The standing robot turned to heading θ0 about the vertical through its COM: pelvis and
    foot yaw θ0, COM where x0 puts it, the feet 0.261 m apart across the heading and level with
    each other along it — the θ0 = 0 pose rotated (rigid rotation: 1e-9 m / 1e-9 rad in float64)."""
    x0 = jnp.array([[0.3, 0.0, 0.0], [-0.2, 0.0, 0.0]])
    key = jax.random.PRNGKey(0)
    c = plant.cassie()
    init = jax.jit(plant.init)                      # one compile instead of op-by-op MJX
    robot_terms = jax.jit(lambda d: model.robot_terms(c, d))
    ref = init(None, x0, None, None, key, 0.0)
    ref_feet = np.asarray(outputs.foot_centres(robot_terms(ref.d)))
    com = np.array([0.3, -0.2])
    for th in (0.66577, -2.5):
        s = init(None, x0, None, None, key, th)
        terms = robot_terms(s.d)
        R = np.asarray(s.d.xmat[c.index.pelvis_body]).reshape(3, 3)
        assert abs(float(s.yaw) - th) < 1e-12
        assert abs(np.arctan2(R[1, 0], R[0, 0]) - th) < 1e-9
        np.testing.assert_allclose(np.asarray(terms.foot_yaw), th, atol=1e-9)
        np.testing.assert_allclose(np.asarray(s.d.subtree_com[c.index.pelvis_body]),
                                   np.asarray(ref.d.subtree_com[c.index.pelvis_body]), atol=1e-9)
        Rz = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
        feet = np.asarray(outputs.foot_centres(terms))
        np.testing.assert_allclose(feet[:, :2] - com, (ref_feet[:, :2] - com) @ Rz.T, atol=1e-9)
        np.testing.assert_allclose(feet[:, 2], ref_feet[:, 2], atol=1e-9)
        np.testing.assert_allclose(np.asarray(s.land_xy), feet[0, :2], atol=1e-12)
        gap = Rz.T @ (feet[0, :2] - feet[1, :2])                     # left − right, heading frame
        np.testing.assert_allclose(gap, [0.0, 0.261], atol=1e-3)


@pytest.fixture(scope="module")
def short_walk():
    # the walk compiles the whole controller (about 4 minutes on the 2-core CPU): its tests are
    # in the slow tier
    """The shipped controller ("paper" preset, model spring damping, passive stance foot)
    walking 16 steps from standing without MPC: in place, 0.5 m/s forward, turning at 30 °/s,
    and forward with step noise (one simulation shared by the tests below)."""
    P = gaits.preset("paper")
    z0, ts, td = P["hlip.z0"], P["hlip.t_ssp"], P["hlip.t_dsp"]
    k = np.asarray(orbits.lqr_step_gain(z0, ts, td, P["gain.q_c"], P["gain.q_v"], P["gain.r"]))
    n = 16
    log, ticks = orbits.walk_orbits([0.0, 0.5, 0.0, 0.5], [0.0] * 4, [0.0, 0.0, np.deg2rad(30), 0.0],
                                    n, z0=z0, t_ssp=ts, t_dsp=td, width=0.2, gain=np.tile(k, (2, 1)),
                                    noise_v=[0, 0, 0, 0.03], step_error=[0, 0, 0, 0.015],
                                    return_ticks=True)
    return types.SimpleNamespace(log=log, ticks=ticks, n=n, z0=z0, ts=ts, td=td, k=k)


@pytest.mark.slow
def test_short_walk_on_mjx(short_walk):
    """No fall, finite S2S data, alternating steps; the in-place robot stays within 0.1 m over
    its first 10 steps (no MPC here, and the stepping law's position term is weak, q_c 0.1; the
    60 s in-place validation run with the MPC is the target)
    and the turning one averages 30 °/s ± 25 % over steps 4..16 (a short window right after the start;
    the validation sweeps measure the ±10 % targets).  The stance foot's motor is exactly
    passive: every tick whose contact set holds a foot gives that foot's motor zero torque.
    Steps end at detected touchdowns: no step is shorter than T_DSP + early_contact · T_SSP or
    longer than the tick budget allows (T_DSP + LATE_SSP times the swing duration), to one tick.  The forward
    robot moves forward at more than half the H-LIP's predicted speed (the ±10 % target is
    :func:`test_forward_speed_follows_the_hlip`)."""
    log, ticks, n, ts, td = (short_walk.log, short_walk.ticks, short_walk.n, short_walk.ts,
                             short_walk.td)
    assert not log.failed.any(), log.failed
    assert np.all(np.isfinite(log.x_robot)) and np.all(np.isfinite(log.w))
    # passive stance foot: foot motors 4 (left) and 9 (right) are zero whenever their foot is
    # in the contact set (exact: the QP's bounds are 0 and the torque is clipped to them)
    c = plant.cassie()
    for t in ticks:
        for f, sites in ((0, slice(0, 2)), (1, slice(2, 4))):
            on = t.contact[:, :, sites].max(axis=-1) > 0.5
            assert np.all(t.tau[:, :, c.index.actuators[f][4]][on] == 0.0)
    dur = np.diff(log.time, axis=1)
    assert np.all(dur >= td + CassieConfig().early_contact * ts - 1e-3), dur
    swing = float(tick.swing_duration(ts, plant.make_gait(CassieConfig())))
    assert np.all(dur <= td + tick.LATE_SSP * swing + 1e-3), dur
    # lateral steps alternate: right foot (u_y < 0) at SSP⁻_1, left (u_y > 0) at SSP⁻_2, ...
    # (world y is across the heading for the robots that do not turn)
    u_y = log.u_robot[[0, 1, 3], :, 1]
    assert np.all(u_y[:, 1::2] < 0) and np.all(u_y[:, 2::2] > 0), u_y
    speed, speed_hlip = _forward_speeds(short_walk)
    assert speed > 0.5 * speed_hlip, (speed, speed_hlip)
    assert abs(log.x_robot[0, 10, 0, 0] - log.x_robot[0, 0, 0, 0]) < 0.1  # in place stayed
    yaw = np.unwrap(log.pelvis_yaw[2])
    rate = np.rad2deg(yaw[n] - yaw[4]) / (log.time[2, n] - log.time[2, 4])
    print("turn rate [deg/s]:", rate)
    assert abs(rate - 30.0) < 7.5, rate
    # the noisy robot's S2S velocity residual spreads more than the plain forward robot's
    rms_wv = np.sqrt(np.mean(log.w[:, 2:, :, 2] ** 2, axis=(1, 2)))
    print("S2S |w_v| RMS plain / noisy [m/s]:", rms_wv[1], rms_wv[3])
    assert rms_wv[3] > rms_wv[1], rms_wv


def _forward_speeds(walk):
    """(robot, H-LIP-predicted) mean forward speed [m/s] of the 0.5 m/s robot over steps
    6..n.  The prediction is closed form: the stepping law u = u_H + K (x − x_H) from the
    robot's measured SSP⁻_0 state, stepped by the S2S model x_{k+1} = A x_k + B u_k (sagittal
    plane), over n − 6 H-LIP periods."""
    log, n, k = walk.log, walk.n, walk.k
    A, Bm = (np.asarray(a) for a in hlip.s2s_matrices(walk.z0, walk.ts, walk.td))
    x = log.x_robot[1, 0, 0].copy()
    pred = [x[0]]
    for j in range(n):
        x = A @ x + Bm * (log.u_hlip[1, j, 0] + k @ (x - log.x_hlip[1, j, 0]))
        pred.append(x[0])
    a = 6
    speed = (log.x_robot[1, n, 0, 0] - log.x_robot[1, a, 0, 0]) / (log.time[1, n] - log.time[1, a])
    speed_hlip = (pred[n] - pred[a]) / ((n - a) * (walk.ts + walk.td))
    print("forward speed robot / H-LIP prediction [m/s]:", speed, speed_hlip)
    return speed, speed_hlip


@pytest.mark.slow
def test_forward_speed_follows_the_hlip(short_walk):
    """Over steps 6..16 the forward robot holds the commanded 0.5 m/s within 10 % (the issue's
    speed target; 0.510 m/s measured with q_c 0.1, 0.490 with q_c 0.05) and moves within 15 %
    of the H-LIP's predicted speed.  The prediction includes the stepping law's catching up of
    the lag from the start (it reaches 0.55 m/s), which the robot does more slowly: 6.9 % under
    it here with the preset (9.6 % with q_c 0.05), against 0.7 % over steps 4..10 with T_SSP
    0.2 s and T_DSP 0.0532 s.  The window starts at step 6 because the steps are shorter now (0.205 s against
    0.253 s): over steps 4..10, 0.8–2.0 s after standing, the robot is still accelerating
    (13 % under the prediction).  Both bounds catch the lag the robot had before the swing was
    timed to the H-LIP (its profile landed at 0.8 T_SSP while the law assumed T_SSP): it then
    made ~55 % of the prediction."""
    speed, speed_hlip = _forward_speeds(short_walk)
    assert abs(speed - 0.5) < 0.10 * 0.5, speed
    assert abs(speed - speed_hlip) < 0.15 * speed_hlip, (speed, speed_hlip)


def _nominal_run(v_fwd, yaw_rate, n):
    z0, ts, td = (np.array([a]) for a in (0.85, 0.26, 0.02))
    A, Bm = (np.asarray(a) for a in jax.vmap(hlip.s2s_matrices)(z0, ts, td))
    k_h = np.asarray(jax.vmap(hlip.deadbeat_gain)(z0, ts, td))
    vf, vl, w = np.array([v_fwd]), np.zeros(1), np.array([0.15])
    u, p, v = orbits.orbit_step(z0, ts, td, vf, vl, w, np.zeros(1), 0)
    x = np.stack([np.stack([np.zeros(1), p[0], v[0]], -1), np.stack([np.zeros(1), p[1], v[1]], -1)], 1)
    out, corr, stance = [], [], 1
    for k in range(n):
        heading = np.array([yaw_rate * (k + 1) * 0.28])
        x, u_next = orbits.nominal_next(A, Bm, k_h, x, u, z0, ts, td, vf, vl, w, heading, stance)
        corr.append(u_next - orbits.orbit_step(z0, ts, td, vf, vl, w, heading, stance)[0])
        u, stance = u_next, 1 - stance
        out.append(x[0])
    return np.array(out), np.array(corr)


def test_nominal_follows_the_orbit_and_stays_bounded_while_turning():
    """Straight: the nominal is on the P1/P2 orbit, so the correction is zero (to round-off).
    Turning at 30 °/s for 100 steps: |v| stays within the orbit's speed + 10 % (open-loop orbit
    steps reach |v| > 3 m/s within 6 steps)."""
    x, corr = _nominal_run(0.5, 0.0, 20)
    np.testing.assert_allclose(corr, 0.0, atol=1e-12)
    x, _ = _nominal_run(0.5, np.deg2rad(30), 100)
    assert np.abs(x[:, :, 2]).max() < 1.1 * np.hypot(0.5, 0.2), np.abs(x[:, :, 2]).max()
    x, _ = _nominal_run(0.0, np.deg2rad(30), 100)
    assert np.abs(x[:, :, 2]).max() < 0.2 and np.abs(x[:, :, 0]).max() < 0.05
