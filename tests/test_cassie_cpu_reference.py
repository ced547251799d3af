"""Tests of the CPU reference of the standing CLF-QP (C MuJoCo + numpy + OSQP) against the JAX
controller (CPU, float64).

One JAX compile in this module: a single control tick (:func:`control.control` plus
:func:`clfqp.build` on the same condensed dynamics), evaluated at two states.

Tolerances:

* model terms, outputs, condensed dynamics and the QP data (P, q, A, l, u, V):
  1e-8 × the largest entry of each array.  Both paths evaluate the same float64 formulas; they
  differ only in summation order, in the solver for M⁻¹ (MuJoCo's sparse L'DL vs a dense
  Cholesky) and in the LAPACK eigen-solver of G's pseudo-inverse — round-off of ~1e-12
  relative (G's condition number on the kept eigenvalues is ~1e9).
* torques: 1e-2 × each motor's torque limit.  Both solve the QP with OSQP's ADMM at
  ε_abs = ε_rel = 1e-4 within at most ``SETTINGS.max_iter`` = 1000 iterations (the walking
  tick's budget is 150; with one CLF row per output group the perturbed state's QP is then
  only "solved inaccurate", up to 15 % of the hip-roll limit from the optimum — a property of
  the controller's iteration budget, docs/cassie_gait.md, not a difference between the two
  implementations, which this module tests), and that tolerance bounds the residuals,
  not the distance to the optimum; the same iterations from (numerically) the same data agree
  much more closely in practice (1e-11 to 1e-3 of the limit), but only the tolerance-level
  agreement is part of the contract.  An accurately solved OSQP (ε = 1e-10) is the third
  opinion; both must be within 3e-2 of each limit of it (at ε = 1e-4 the ADMM stops ≈ 0.012 N m
  from the optimum on the foot motors, whose limit is only 0.9 N m; ≤ 2e-3 of the limit on the
  others).
* ``loop_res`` (chain-closure residual, ~1e-9 m at the keyframe) is the difference of two world
  points ~1 m from the origin, so its round-off is relative to 1 m, not to its own size.
"""

import jax


import jax.numpy as jnp
import mujoco
import numpy as np
import osqp
import pytest
import scipy.sparse as sp
from mujoco import mjx

from hlip_jax.core import qp
from hlip_jax.plants.cassie import clfqp, control, dynamics, outputs

from support import cassie_cpu_reference as cpu_reference

#: (hinge offsets [rad], velocity noise [m/s, rad/s], seed) of the compared states
STATES = {"calm": (0.0, 0.05, 1), "perturbed": (0.01, 0.2, 3)}
MATRIX_RTOL = 1e-8
TORQUE_TOL = 1e-2     # × the torque limit of each motor (reference vs JAX)
OPTIMUM_TOL = 3e-2    # × the torque limit of each motor (either vs the accurate QP solution)
SETTINGS = clfqp.DEFAULT_SETTINGS._replace(max_iter=1000)   # ADMM budget of both solvers


@pytest.fixture(scope="module")
def cassie():
    return control.load()


@pytest.fixture(scope="module")
def ref_static():
    return cpu_reference.static(cpu_reference.load_model())


@pytest.fixture(scope="module")
def jax_tick(cassie):
    """The JAX control tick from zero warm start at the state of ``dx``, standing target ``tg``."""
    lo = jnp.asarray(cassie.ctrl_range[:, 0])
    hi = jnp.asarray(cassie.ctrl_range[:, 1])
    contact = jnp.ones(4)

    @jax.jit
    def tick(dx, tg):
        des = outputs.stand_desired(tg[2], tg[:2], tg[3])
        res, meas, terms = control.control(cassie, dx, des, contact, lo, hi, control.STAND_GAINS,
                                           control.warm_zeros(cassie, jnp.float64), SETTINGS)
        cond = dynamics.condense(terms, cassie.actuation, contact, dynamics.spring_dofs(cassie))
        prob = clfqp.build(meas, des, cond, contact, lo, hi, control.STAND_GAINS)
        return terms, meas, cond, prob, res

    return tick


def _state(m, key, qpos_noise, qvel_noise, seed):
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, key)
    rng = np.random.default_rng(seed)
    hinge = [m.jnt_qposadr[j] for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE]
    d.qpos[hinge] += rng.uniform(-qpos_noise, qpos_noise, len(hinge))
    d.qvel[:] = rng.uniform(-qvel_noise, qvel_noise, m.nv)
    mujoco.mj_forward(m, d)
    return d


@pytest.fixture(scope="module", params=list(STATES))
def pair(request, cassie, ref_static, jax_tick):
    """Both controllers at one state: (jax (terms, meas, cond, prob, res), reference
    (terms, meas, cond, prob, res), static)."""
    m = cassie.mj_model
    d = _state(m, cassie.index.stand_key, *STATES[request.param])
    c = d.subtree_com[cassie.index.pelvis_body]
    tg = np.array([c[0] + 0.01, c[1] - 0.01, c[2] - 0.02, 0.05])
    jx = jax.tree.map(np.asarray, jax_tick(mjx.put_data(m, d), jnp.asarray(tg)))
    s = ref_static
    robot = cpu_reference.Robot(s, qpos=d.qpos, qvel=d.qvel, settings=SETTINGS)
    des = cpu_reference.stand_desired(tg[2], tg[:2], tg[3])
    res, terms, prob = robot.control(des)
    meas = cpu_reference.measure(terms, robot.d.qvel, s.idx.root_dof)
    cond = cpu_reference.condense(terms, s.B, np.ones(4), s.springs, robot.solve_M)
    return jx, (terms, meas, cond, prob, res), s


def _close(name, got, ref, rtol=MATRIX_RTOL, floor=1e-300):
    got, ref = np.asarray(got, float), np.asarray(ref, float)
    assert got.shape == ref.shape, name
    fin = np.isfinite(ref)
    np.testing.assert_array_equal(np.isfinite(got), fin, err_msg=f"{name}: ±inf pattern")
    np.testing.assert_array_equal(got[~fin], ref[~fin], err_msg=f"{name}: infinite entries")
    if fin.any():
        scale = np.abs(ref[fin]).max()
        np.testing.assert_allclose(got[fin], ref[fin], rtol=0, atol=rtol * max(scale, floor),
                                   err_msg=name)


# -------------------------------------------------------------------------------- model


def test_model_matches_control_load(cassie, ref_static):
    """Same MJCF, spring damping, actuation, limits and spring dofs as the JAX controller."""
    m, s = cassie.mj_model, ref_static
    np.testing.assert_array_equal(s.m.dof_damping, m.dof_damping)
    assert np.all(s.m.dof_damping[list(s.springs)] == control.SPRING_DAMPING)
    assert s.springs == dynamics.spring_dofs(cassie)
    np.testing.assert_array_equal(s.B, cassie.actuation)
    np.testing.assert_array_equal(s.tau_min, cassie.ctrl_range[:, 0])
    np.testing.assert_array_equal(s.tau_max, cassie.ctrl_range[:, 1])
    assert s.m.opt.timestep * cpu_reference.SUBSTEPS == pytest.approx(control.CONTROL_DT)


def test_jdot_qdot_matches_mj_jacDot(ref_static):
    """The vectorised analytic J̇q̇ equals C MuJoCo's ``mj_jacDot(point, body) @ qvel`` at every
    point of the batch (sites, loop anchors, body COMs) to round-off."""
    s = ref_static
    m = s.m
    d = _state(m, s.idx.stand_key, 0.02, 1.0, 7)
    terms = cpu_reference.robot_terms(s, d)
    p1 = d.xpos[s.loop_b1] + np.einsum("kij,kj->ki", d.xmat[s.loop_b1].reshape(4, 3, 3), s.loop_a1)
    p2 = d.xpos[s.loop_b2] + np.einsum("kij,kj->ki", d.xmat[s.loop_b2].reshape(4, 3, 3), s.loop_a2)
    pts = np.concatenate([terms.site_pos, p1, p2, d.xipos[s.com_bodies]])
    acc = cpu_reference.point_jdot_qdot(s, d, pts)
    ref = np.empty_like(acc)
    jd = np.empty((3, m.nv))
    for k, (p, b) in enumerate(zip(pts, s.pt_bodies)):
        mujoco.mj_jacDot(m, d, jd, None, p, int(b))
        ref[k] = jd @ d.qvel
    assert np.abs(ref).max() > 0.1                  # the state does exercise the terms
    np.testing.assert_allclose(acc, ref, rtol=0, atol=1e-12 * np.abs(ref).max())
    np.testing.assert_allclose(terms.com_jdqd, s.com_w @ ref[12:], rtol=0, atol=1e-13)


# ------------------------------------------------------------------- reference vs JAX tick


def test_terms_and_condensed_dynamics_match_jax(pair):
    (jterms, jmeas, jcond, _, _), (terms, meas, cond, _, _), _ = pair
    for k in cpu_reference.Terms._fields:
        _close(f"terms.{k}", getattr(terms, k), getattr(jterms, k),
               floor=1.0 if k == "loop_res" else 1e-300)   # [m]: see the module doc
    for k in outputs.Measured._fields:
        _close(f"meas.{k}", getattr(meas, k), getattr(jmeas, k))
    for k in dynamics.Condensed._fields:
        _close(f"cond.{k}", getattr(cond, k), getattr(jcond, k))


def test_qp_matrices_match_jax(pair):
    (_, _, _, jprob, _), (_, _, _, prob, _), _ = pair
    for k in clfqp.Problem._fields:
        _close(f"prob.{k}", getattr(prob, k), getattr(jprob, k))


def test_torque_matches_jax(pair):
    (_, _, _, jprob, jres), (_, _, _, prob, res), s = pair
    lim = np.maximum(np.abs(s.tau_min), np.abs(s.tau_max))
    assert res.status in (qp.SOLVED, qp.SOLVED_INACCURATE)
    assert int(jres.status) in (qp.SOLVED, qp.SOLVED_INACCURATE)
    np.testing.assert_array_less(np.abs(res.tau - jres.tau), TORQUE_TOL * lim)
    # both near the accurately solved QP
    o = osqp.OSQP()
    o.setup(sp.csc_matrix(np.triu(prob.P)), prob.q, sp.csc_matrix(prob.A),
            np.maximum(prob.l, -1e30), np.minimum(prob.u, 1e30), verbose=False,
            eps_abs=1e-10, eps_rel=1e-10, max_iter=200000, polishing=True)
    best = o.solve(raise_error=False)
    assert best.info.status_val == qp.SOLVED
    tau_best = np.clip(best.x[:s.m.nu], s.tau_min, s.tau_max)
    np.testing.assert_array_less(np.abs(res.tau - tau_best), OPTIMUM_TOL * lim)
    np.testing.assert_array_less(np.abs(jres.tau - tau_best), OPTIMUM_TOL * lim)
    assert np.all(res.tau >= s.tau_min) and np.all(res.tau <= s.tau_max)


# -------------------------------------------------------------------------------- standing


def test_reference_stands_one_second(ref_static):
    """1 s from the keyframe with the COM target 2 cm below the start: the COM height never
    leaves the 2 cm band around the target, converges, and the robot stays upright."""
    robot = cpu_reference.Robot(ref_static)
    target = cpu_reference.default_target(robot)
    log = cpu_reference.stand(1.0, target, robot=robot)
    assert log.com.shape == (1000, 3)
    err = np.abs(log.com[:, 2] - target[2])
    assert err.max() <= 0.02 + 1e-9, err.max()     # tick 0 is exactly 2 cm above
    assert err[-100:].max() < 0.005, err[-100:].max()
    assert np.abs(log.com[:, :2] - target[:2]).max() < 0.02
    assert np.all(log.pelvis_z > 0.8)
    assert np.all(np.abs(log.rpy[:, :2]) < 0.1)
    s = ref_static
    assert np.all(log.tau >= s.tau_min) and np.all(log.tau <= s.tau_max)
    assert np.all(np.isin(log.status, [qp.SOLVED, qp.SOLVED_INACCURATE]))


def test_throughput_is_positive():
    assert cpu_reference.throughput(20) > 0
    with pytest.raises(ValueError, match="n_ticks"):
        cpu_reference.throughput(0)
