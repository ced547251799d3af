"""Tests of the non-ideal Cassie plant (:mod:`hlip_jax.plants.cassie.realism`): each model
against its closed form, the ideal defaults as the identity, the physics' model against C
MuJoCo with the same edits, and the config → params path."""

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from hlip_jax import plants
from hlip_jax.simulation.config import RealismConfig, ScenarioConfig
from hlip_jax.plants.cassie import model, plant, realism, tick
from hlip_jax.plants.cassie.mjx_import import mjx

DT = 0.001


@pytest.fixture(scope="module", autouse=True)
def _x64():
    """float64 for the whole module (the model is loaded once, in float64)."""
    old = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", True)
    yield
    jax.config.update("jax_enable_x64", old)


@pytest.fixture(scope="module")
def cassie(_x64):
    return tick.cassie()


def _real(**kw):
    """Realism arrays in float64 for a config with ``kw`` set."""
    r = realism.make(RealismConfig(**kw))
    return jax.tree.map(lambda a: jnp.asarray(a, jnp.float64) if np.issubdtype(np.asarray(a).dtype, np.floating)
                        else jnp.asarray(a), r)


def _state(cassie, key=0):
    return realism.init_state(cassie.index.nu, jnp.zeros(3), jax.random.PRNGKey(key), jnp.float64)


def _stand_data(cassie, rng, vel=0.3):
    m = cassie.mj_model
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, cassie.index.stand_key)
    d.qvel[:] = rng.uniform(-vel, vel, m.nv)
    mujoco.mj_forward(m, d)
    return d


def test_ideal_defaults_are_the_identity(cassie):
    """With the config's defaults every stage returns its input bit for bit: the measured data
    is the true data, the applied torques are the commanded ones, the velocity estimate is the
    measurement, the oracle touchdown reads the exact sites, and the physics' model has the
    nominal masses, stiffness, friction and gravity."""
    real = _real()
    rs = _state(cassie)
    m = cassie.mj_model
    d = mjx.put_data(m, _stand_data(cassie, np.random.default_rng(0)))
    dm, _ = realism.sense(cassie, real, rs, d)
    np.testing.assert_array_equal(dm.qpos, d.qpos)
    np.testing.assert_array_equal(dm.qvel, d.qvel)
    tau = jnp.asarray(np.random.default_rng(1).uniform(-4, 4, cassie.index.nu))
    for _ in range(3):
        out, rs = realism.actuate(cassie, real, rs, tau, d.qvel, jnp.bool_(True), DT)
        np.testing.assert_array_equal(out, tau)
    v = jnp.array([0.3, -0.1, 0.02])
    np.testing.assert_array_equal(realism.estimate_velocity(real, rs, v, DT).v_est, v)
    sites = d.site_xpos[np.asarray(cassie.index.contact_sites)] + 1.0     # not d's own sites
    got = realism.touching(cassie, real, d, d, sites, 0.004)
    np.testing.assert_array_equal(got, sites[:, 2] - model.FOOT_SPHERE_RADIUS < 0.004)
    mx = cassie.mjx_model
    mp = realism.plant_model(cassie, real, mx)
    for name in ("body_mass", "body_subtreemass", "body_inertia", "body_ipos", "jnt_stiffness",
                 "geom_friction"):
        np.testing.assert_array_equal(getattr(mp, name), getattr(mx, name), err_msg=name)
    np.testing.assert_array_equal(mp.opt.gravity, m.opt.gravity)


def test_motor_curve_closed_form(cassie):
    """Driving torque: full below c ω0, linear to 0 at ω0, none beyond; braking torque and the
    curve switched off keep the full range (exact arithmetic on chosen points: 1e-12)."""
    real = _real(motor_curve=True, motor_corner=0.6)
    w0, tmax = 300.0, 4.5
    omega = jnp.array([0.0, 100.0, 180.0, 240.0, 300.0, 400.0, -240.0, -240.0])
    tau = jnp.array([4.0, 4.0, 4.0, 4.0, 4.0, 4.0, -4.0, 4.0])
    out = realism.motor_limit(real, tau, omega, jnp.full(8, tmax), jnp.full(8, w0))
    cap = lambda w: tmax * min(max((w0 - abs(w)) / (0.4 * w0), 0.0), 1.0)
    want = [4.0, 4.0, 4.0, cap(240.0), 0.0, 0.0, -cap(240.0), 4.0]
    np.testing.assert_allclose(out, want, atol=1e-12)
    assert 0 < cap(240.0) < 4.0
    off = realism.motor_limit(_real(), tau, omega, jnp.full(8, tmax), jnp.full(8, w0))
    np.testing.assert_array_equal(off, tau)


@pytest.mark.parametrize("latency,period", [(3, 1), (0, 4), (2, 3)])
def test_latency_and_control_period_against_a_queue(cassie, latency, period):
    """The applied torque at tick i is the command of tick i − L, where the command is the
    controller's torque of the last update tick (a multiple of n): exact."""
    real = _real(latency=latency, control_period=period)
    rs = _state(cassie)
    nu = cassie.index.nu
    qvel = jnp.zeros(cassie.index.nv)
    taus = np.random.default_rng(2).uniform(-1, 1, (20, nu))
    cmds, outs = [], []
    for i, t in enumerate(taus):
        cmds.append(t if i % period == 0 else cmds[-1])
        out, rs = realism.actuate(cassie, real, rs, jnp.asarray(t), qvel, jnp.bool_(True), DT)
        outs.append(np.asarray(out))
    for i in range(20):
        want = cmds[i - latency] if i >= latency else np.zeros(nu)
        np.testing.assert_array_equal(outs[i], want)
    # an idle tick (the step is over) leaves the queue and the clock as they are
    _, rs2 = realism.actuate(cassie, real, rs, jnp.ones(nu), qvel, jnp.bool_(False), DT)
    for a, b in zip(jax.tree.leaves(rs2), jax.tree.leaves(rs)):
        np.testing.assert_array_equal(a, b)


def test_motor_lag_and_velocity_filter_step_responses(cassie):
    """A unit step through the first-order lag and the velocity low-pass: after i ticks
    1 − (1 − a)^i with a = Δt / (τ + Δt) (closed form of the recursion; 1e-12)."""
    tau_lag, tau_v = 0.004, 0.02
    real = _real(motor_lag=tau_lag, velocity_filter=tau_v)
    rs = _state(cassie)
    nu = cassie.index.nu
    b, a = DT / (tau_lag + DT), DT / (tau_v + DT)
    for i in range(1, 15):
        out, rs = realism.actuate(cassie, real, rs, jnp.ones(nu), jnp.zeros(cassie.index.nv),
                                  jnp.bool_(True), DT)
        np.testing.assert_allclose(out, 1 - (1 - b) ** i, atol=1e-12)
        rs = realism.estimate_velocity(real, rs, jnp.ones(3), DT)
        np.testing.assert_allclose(rs.v_est, 1 - (1 - a) ** i, atol=1e-12)


def test_sensing_noise_statistics_and_bias(cassie):
    """Encoder noise: only hinge joints move, with sample std within 10 % of σ over 400 draws ×
    20 joints (the std's standard error is 2.5 %); the pelvis quaternion stays unit.  A roll
    bias alone turns the measured pelvis by exactly the bias about its own x axis (1e-12:
    round-off of the quaternion product)."""
    sigma = 0.5   # deg
    real = _real(joint_noise=sigma)
    d = mjx.put_data(cassie.mj_model, _stand_data(cassie, np.random.default_rng(3)))
    lay = realism.layout(cassie)
    sense = jax.jit(lambda k: realism.sense(cassie, real, _state(cassie)._replace(key=k), d)[0].qpos)
    draws = np.stack([np.asarray(sense(jax.random.PRNGKey(i))) for i in range(400)]) - np.asarray(d.qpos)
    other = np.setdiff1d(np.arange(cassie.index.nq), lay.hinge_qpos)
    np.testing.assert_allclose(draws[:, other], 0.0, atol=1e-15)
    std = draws[:, lay.hinge_qpos].std()
    assert abs(std - np.deg2rad(sigma)) < 0.1 * np.deg2rad(sigma)
    real_b = _real(imu_bias_roll=5.0)
    dm, _ = realism.sense(cassie, real_b, _state(cassie), d)
    r0 = cassie.index.root_qpos
    q_true, q_meas = np.asarray(d.qpos[r0 + 3:r0 + 7]), np.asarray(dm.qpos[r0 + 3:r0 + 7])
    assert abs(np.linalg.norm(q_meas) - 1) < 1e-12
    R_rel = model.quat_to_mat(jnp.asarray(q_true)).T @ model.quat_to_mat(jnp.asarray(q_meas))
    np.testing.assert_allclose(model.rpy_from_mat(R_rel), [np.deg2rad(5.0), 0, 0], atol=1e-12)


def test_touchdown_index_follows_the_config_choices():
    """Realism.touchdown indexes realism.TOUCHDOWN, whose order must be the config's choices."""
    field = {f.name: f for f in dataclasses.fields(RealismConfig)}["touchdown"]
    assert tuple(field.metadata["choices"]) == realism.TOUCHDOWN
    for name in realism.TOUCHDOWN:
        assert realism.TOUCHDOWN[int(realism.make(RealismConfig(touchdown=name)).touchdown)] == name


def test_spring_touchdown_reads_the_heel_springs(cassie):
    """With touchdown = 'spring' a foot touches exactly when its measured heel spring is
    compressed (negative deflection) beyond the threshold, whatever the sites' heights."""
    real = _real(touchdown="spring", spring_threshold=2.0)
    d = mjx.put_data(cassie.mj_model, _stand_data(cassie, np.random.default_rng(4)))
    lay = realism.layout(cassie)
    far = jnp.full((4, 3), 10.0)
    for left, right, want in ((-2.5, 2.5, [True, True, False, False]),
                              (-1.9, -2.1, [False, False, True, True])):
        qpos = d.qpos.at[lay.heel_qpos].set(jnp.deg2rad(jnp.array([left, right])))
        got = realism.touching(cassie, real, d, d.replace(qpos=qpos), far, 0.004)
        np.testing.assert_array_equal(got, want)


def test_kinematic_touchdown_reads_heights_relative_to_the_lowest_sphere(cassie):
    """With touchdown = 'kinematic' a foot (both its sites) touches when its lower sphere's
    measured height is within the gap of the lowest sphere's, whatever the ground's height and
    the true state: a foot whose toe is 3 mm above the stance foot touches at a 4 mm gap (its
    heel 6 mm up, as a 3° pitch error makes it, included), 5 mm does not; lifting every sphere
    by 0.3 m changes nothing (the oracle would say none touches)."""
    real = _real(touchdown="kinematic")
    d = mjx.put_data(cassie.mj_model, _stand_data(cassie, np.random.default_rng(5)))
    for base in (0.0, 0.3):
        for right, want in (([0.003, 0.009], True), ([0.005, 0.009], False), ([0.009, 0.0039], True)):
            z = base + jnp.array([0.0, 0.0005] + right)          # left toe, heel; right toe, heel
            sites = jnp.zeros((4, 3)).at[:, 2].set(z)
            got = realism.touching(cassie, real, d, d, sites, 0.004)
            np.testing.assert_array_equal(got, [True, True, want, want])
    oracle = realism.touching(cassie, _real(), d, d, sites, 0.004)
    np.testing.assert_array_equal(oracle, [False] * 4)
    # under sensing noise it still reads the measured sites, not the true state (the true
    # robot stands on both feet; the measurement lifts the right foot 5 cm)
    stand = mjx.put_data(cassie.mj_model, _stand_data(cassie, np.random.default_rng(6), vel=0.0))
    noisy = _real(touchdown="kinematic", joint_noise=0.1)
    lifted = jnp.zeros((4, 3)).at[2:, 2].set(0.05)
    np.testing.assert_array_equal(realism.touching(cassie, noisy, stand, stand, lifted, 0.004),
                                  [True, True, False, False])
    truth = realism.touching(cassie, _real(joint_noise=0.1), stand, stand, lifted, 0.004)
    np.testing.assert_array_equal(truth, [True] * 4)


@pytest.mark.timeout(240)
def test_plant_model_matches_c_mujoco_with_the_same_edits(cassie):
    """qacc_smooth (unconstrained accelerations: masses, inertias, COM, springs, gravity) of
    mjx.forward on the edited MJX model equals C MuJoCo's on a model edited by hand the same
    way (1e-8 · max|qacc|: float64 round-off), and differs from the nominal model's by far more."""
    cfg = dict(mass_scale=1.2, pelvis_com_x=0.03, pelvis_com_y=-0.02, spring_stiffness_scale=0.5,
               friction=0.6, slope_x=8.0)
    real = _real(**cfg)
    m = mujoco.MjModel.from_xml_path(str(model.SCENE_XML))
    m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_EQUALITY
    mx = realism.plant_model(cassie, real, mjx.put_model(m, impl="jax"))
    lay = realism.layout(cassie)
    me = mujoco.MjModel.from_xml_path(str(model.SCENE_XML))
    me.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_EQUALITY
    me.body_mass[:] *= 1.2
    me.body_subtreemass[:] *= 1.2
    me.body_inertia[:] *= 1.2
    me.body_ipos[cassie.index.pelvis_body, :2] += [0.03, -0.02]
    me.jnt_stiffness[lay.spring_jnt] *= 0.5
    a = np.deg2rad(8.0)
    me.opt.gravity[:] = [-9.81 * np.sin(a), 0.0, -9.81 * np.cos(a)]
    np.testing.assert_allclose(np.asarray(mx.geom_friction)[lay.contact_geoms, 0], 0.6)
    rng = np.random.default_rng(5)
    dd = _stand_data(cassie, rng)
    dd.qpos[lay.spring_qpos] += 0.02                    # deflected springs
    fwd = jax.jit(mjx.forward)
    for mm, mjxm in ((me, mx),):
        de = mujoco.MjData(mm)
        de.qpos[:], de.qvel[:] = dd.qpos, dd.qvel
        mujoco.mj_forward(mm, de)
        out = fwd(mjxm, mjx.put_data(m, de))
        scale = np.abs(de.qacc_smooth).max()
        np.testing.assert_allclose(out.qacc_smooth, de.qacc_smooth, atol=1e-8 * scale)
    dn = mujoco.MjData(m)
    dn.qpos[:], dn.qvel[:] = dd.qpos, dd.qvel
    mujoco.mj_forward(m, dn)
    assert np.abs(dn.qacc_smooth - de.qacc_smooth).max() > 1e-2 * scale


def test_config_to_params_and_validation():
    """Degrees become radians, choices become flags; an ideal batch carries no realism data
    (and refuses a scenario that needs it); the rollout's shapes compile the realism stages
    in when any scenario departs; the H-LIP plant refuses realism fields and names the field
    and its allowed value."""
    cfg = ScenarioConfig(plant="cassie", realism=RealismConfig(imu_bias_pitch=2.0, latency=3,
                                                              touchdown="spring", slope_y=-4.0))
    with pytest.raises(ValueError, match="realism: scenario 'scenario' departs from the ideal plant"):
        plant.make_params(cfg, 1)                   # a batch built as ideal carries no realism
    p = plant.make_params(cfg, 1, non_ideal=True)
    assert p.real.latency == 3 and bool(p.real.noisy)
    assert realism.TOUCHDOWN[int(p.real.touchdown)] == "spring"
    np.testing.assert_allclose(p.real.imu_bias, [0.0, np.deg2rad(2.0)])
    np.testing.assert_allclose(p.real.slope, [0.0, np.deg2rad(-4.0)])
    assert plant.make_params(ScenarioConfig(plant="cassie"), 1).real is None
    ideal = plant.make_params(ScenarioConfig(plant="cassie"), 1, non_ideal=True).real
    assert ideal.latency.dtype == np.int32 and not bool(ideal.noisy) and ideal.period == 1
    from hlip_jax.simulation import arrays
    ideal_cfg = ScenarioConfig(plant="cassie")
    assert not arrays.shapes_of([ideal_cfg, ideal_cfg]).non_ideal
    assert arrays.shapes_of([ideal_cfg, cfg]).non_ideal
    msg = plants.check(dataclasses.replace(cfg, plant="hlip"))
    assert msg.startswith("realism.latency: 3 models the Cassie robot; allowed with plant = 'hlip': 0")


@pytest.mark.slow
@pytest.mark.timeout(1200)
def test_the_step_log_keeps_the_estimate_beside_the_truth():
    # Three non-ideal robots walking 1.2 s in one batch (the realism stages compiled in):
    #  - a motor lag only: the controller senses exactly, so its estimate at every SSP⁻ is the
    #    truth (1e-9: the same state through the same kinematics on the same model; the physics'
    #    and the controller's MJX models are equal without model errors);
    #  - a 30 ms COM-velocity filter only: c and p exact (1e-9), v off — a low-pass filter of
    #    a changing velocity lags it;
    #  - encoder and IMU noise: p off by about the noise's effect (nonzero, below 5 cm);
    #  - touchdown from the measured kinematics, sensing exact, beside an ideal robot in the
    #    same batch: on flat ground the stance foot is the ground up to its sphere's penetration
    #    (under a millimetre), so the two detect the same touchdowns to a tick or two and walk
    #    alike (compared below).
    # The CLF-QP starts every tick from the default ADMM step size here: with the preset's ρ
    # carried from tick to tick (cassie.qp_rho_start = "previous") every later QP's starting
    # point depends on the tick history, so a touchdown one tick apart changes all later
    # torques within the solver's tolerance, and the two robots' v differed by 0.062 m/s
    # after three steps (c, p by 2.9 mm): the comparison would measure that, not the detector.
    from hlip_jax.simulation import execution
    from hlip_jax.analysis import metrics
    from hlip_jax.simulation.config import CassieConfig, PathConfig
    base = ScenarioConfig(plant="cassie", duration=1.2, cassie=CassieConfig(qp_rho_start="default"),
                          path=PathConfig(shape="line", params=dict(peak_speed=0.3, length=2.0)))
    cfgs = [dataclasses.replace(base, realism=RealismConfig(**kw)) for kw in (
        dict(motor_lag=0.002), dict(velocity_filter=0.03),
        dict(joint_noise=0.005, imu_noise=0.005), dict(touchdown="kinematic"), dict())]
    log = execution.simulate(cfgs)._asdict()
    valid = log["valid"]
    assert valid[:, :4].all(), valid
    d = (log["x_est"] - log["x_robot"])[valid]            # (n, 2, 3)
    n0 = int(valid[0].sum())
    np.testing.assert_allclose(d[:n0], 0.0, atol=1e-9)
    lagged = (log["x_est"] - log["x_robot"])[1][valid[1]]
    np.testing.assert_allclose(lagged[:, :, :2], 0.0, atol=1e-9)
    assert np.abs(lagged[1:, :, 2]).max() > 1e-3            # after the start from rest
    noisy = (log["x_est"] - log["x_robot"])[2][valid[2]]
    assert 1e-5 < np.abs(noisy[1:, :, 1]).max() < 0.05
    n3 = int(valid[3].sum())
    assert n3 == int(valid[4].sum()) == valid.shape[1]
    dx = np.abs(log["x_robot"][3][:n3] - log["x_robot"][4][:n3])
    dt = np.abs(log["t_plant"][3][:n3] - log["t_plant"][4][:n3])
    # measured (float64): c, p within 3 mm and v within 0.017 m/s after three steps, the
    # kinematic detector firing when the swing sphere is within the gap of the stance sphere
    # (sunk by its penetration) instead of the floor; 5 mm, 0.03 m/s allowed.  Touchdowns:
    # the stance sphere's sub-millimetre penetration at a landing speed of about 0.5 m/s moves
    # a detection by under 2 ms (2 ticks); 3 ms allowed
    assert dx[:, :, :2].max() < 5e-3 and dx[:, :, 2].max() < 0.03, dx
    assert dt.max() < 3e-3, dt
    m = [metrics.scenario_metrics(log, s, with_coverage=False) for s in range(3)]
    assert m[0]["est_err_p"] < 1e-9 and m[0]["est_err_v"] < 1e-9
    assert m[1]["est_err_p"] < 1e-9 and m[1]["est_err_v"] > 1e-4
    assert m[2]["est_err_p"] > 1e-6
