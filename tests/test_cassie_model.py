"""Tests of the Cassie MJCF and of hlip_jax.plants.cassie.model (CPU, float64, batches ≤ 4).

References are independent of the code under test: C MuJoCo's own functions (mj_fullM,
mj_jacSite, mj_jacSubtreeCom, the connect rows of efc_J) and central finite differences.
"""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

from hlip_jax.plants.cassie import model as cm


@pytest.fixture(scope="module")
def cassie():
    return cm.load()


def _random_state(cassie, rng, vel=0.5, dq=0.02, sink=0.0):
    """C MjData near the stand keyframe: hinge offsets ±dq [rad], velocities ±vel, random ctrl."""
    m = cassie.mj_model
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, cassie.index.stand_key)
    hinge = [m.jnt_qposadr[j] for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE]
    d.qpos[hinge] += rng.uniform(-dq, dq, len(hinge))
    d.qpos[2] -= sink
    d.qvel[:] = rng.uniform(-vel, vel, m.nv)
    d.ctrl[:] = rng.uniform(-1, 1, m.nu) * cassie.ctrl_range[:, 1]
    mujoco.mj_forward(m, d)
    return d


@pytest.fixture(scope="module")
def terms_fn(cassie):
    return jax.jit(lambda d: cm.robot_terms(cassie, d))


# ----------------------------------------------------------------------------- model facts


def test_sizes_and_mass(cassie):
    m = cassie.mj_model
    assert (m.nq, m.nv, m.nu, m.neq) == (35, 32, 10, 4)
    # Agility's published link masses sum to 33.31 kg (pelvis 10.33 + 2 x 11.49 legs).
    assert 31.0 <= cassie.total_mass <= 33.5
    assert cassie.total_mass == pytest.approx(m.body_mass.sum())


def test_index_map_names(cassie):
    m, idx = cassie.mj_model, cassie.index
    for s, side in enumerate(cm.SIDES):
        for j in cm.LEG_JOINTS:
            jid = m.joint(f"{side}_{j}").id
            assert getattr(idx.qpos[s], j) == m.jnt_qposadr[jid]
            assert getattr(idx.dof[s], j) == m.jnt_dofadr[jid]
        for k, j in enumerate(cm.MOTOR_JOINTS):
            a = idx.actuators[s][k]
            assert m.actuator(a).name == f"{side}_{j}"
            assert m.jnt_dofadr[m.actuator_trnid[a, 0]] == getattr(idx.dof[s], j)
            assert idx.actuated_dofs[a] == getattr(idx.dof[s], j)
        assert m.body(idx.foot_body[s]).name == f"{side}_foot"
        assert m.site(idx.toe_site[s]).name == f"{side}_toe"
        assert m.site(idx.heel_site[s]).name == f"{side}_heel"
    assert [m.site(i).name for i in idx.contact_sites] == list(cm.CONTACT_SITES)
    assert [m.equality(i).name for i in idx.loops] == list(cm.LOOPS)
    assert m.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE and idx.root_qpos == 0
    # springs where they should be (N m / rad)
    for s in range(2):
        assert m.jnt_stiffness[m.dof_jntid[idx.dof[s].shin]] == 1500
        assert m.jnt_stiffness[m.dof_jntid[idx.dof[s].heel_spring]] == 1250


def test_only_feet_collide(cassie):
    m = cassie.mj_model
    colliding = [m.geom(g).name for g in range(m.ngeom) if m.geom_contype[g] or m.geom_conaffinity[g]]
    assert sorted(colliding) == sorted(["floor", *cm.CONTACT_SITES])


def test_actuation_matrix_matches_qfrc_actuator(cassie):
    # independent: C MuJoCo's actuator force mapping for a random ctrl
    d = _random_state(cassie, np.random.default_rng(3))
    np.testing.assert_allclose(cassie.actuation @ d.ctrl, d.qfrc_actuator, atol=1e-12)
    np.testing.assert_allclose(cassie.joint_torque_limit, [112.5, 112.5, 195.2, 195.2, 45.0] * 2)


# ----------------------------------------------------------------------------- keyframe


def test_stand_keyframe(cassie):
    m = cassie.mj_model
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, cassie.index.stand_key)
    mujoco.mj_forward(m, d)
    eq = d.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY
    # 9 significant digits in the keyframe -> chains closed to ~1e-9 m; 1e-7 m leaves margin
    assert eq.sum() == 12 and np.abs(d.efc_pos[eq]).max() < 1e-7
    sites = d.site_xpos[list(cassie.index.contact_sites)]
    np.testing.assert_allclose(sites[:, 2], cm.FOOT_SPHERE_RADIUS, atol=1e-6)  # feet on floor
    toe, heel = sites[[0, 2]], sites[[1, 3]]
    assert np.all(toe[:, 0] > heel[:, 0])                                       # toes point +x
    com = d.subtree_com[1]
    assert heel[0, 0] < com[0] < toe[0, 0] and abs(com[1]) < 0.01              # COM over feet
    assert 0.8 < com[2] < 1.0 and 0.95 < d.qpos[2] < 1.1


@pytest.mark.timeout(120)
def test_passive_drop_c_mujoco(cassie):
    """0.5 s with zero torque from the stand pose: the robot sags, feet stay on the floor,
    nothing blows up (C MuJoCo, model solver settings)."""
    m = cassie.mj_model
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, cassie.index.stand_key)
    for _ in range(int(0.5 / m.opt.timestep)):
        mujoco.mj_step(m, d)
        assert np.all(np.isfinite(d.qacc))
    z = d.site_xpos[list(cassie.index.contact_sites), 2]
    assert np.all(np.abs(z - cm.FOOT_SPHERE_RADIUS) < 5e-3)  # sphere bottoms within 5 mm of z = 0
    assert d.ncon == 4 and np.abs(d.qvel).max() < 50.0 and d.qpos[2] > 0.1
    eq = d.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY
    assert np.abs(d.efc_pos[eq]).max() < 5e-3  # closed chains stay closed within 5 mm


# ----------------------------------------------------------------------------- dynamics terms


@pytest.mark.timeout(120)
@pytest.mark.slow
def test_terms_match_c_mujoco(cassie, terms_fn):
    """M, h, passive, Jacobians and COM equal C MuJoCo's to round-off (1e-9: float64 sums of
    ~30 terms of size ≤ 1e2)."""
    m = cassie.mj_model
    rng = np.random.default_rng(0)
    for _ in range(2):
        d = _random_state(cassie, rng, vel=1.0, dq=0.05)
        T = terms_fn(mjx.put_data(m, d))
        M = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, M)
        np.testing.assert_allclose(T.M, M, atol=1e-9)
        np.testing.assert_allclose(T.bias, d.qfrc_bias, atol=1e-9)
        np.testing.assert_allclose(T.passive, d.qfrc_passive, atol=1e-9)
        for k, s in enumerate(cassie.index.contact_sites):
            jp = np.zeros((3, m.nv))
            mujoco.mj_jacSite(m, d, jp, None, s)
            np.testing.assert_allclose(T.site_J[k], jp, atol=1e-9)
            np.testing.assert_allclose(T.site_pos[k], d.site_xpos[s], atol=1e-9)
        eq = d.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY
        np.testing.assert_allclose(T.loop_J, d.efc_J.reshape(d.nefc, m.nv)[eq], atol=1e-9)
        np.testing.assert_allclose(T.loop_res, d.efc_pos[eq], atol=1e-9)
        jc = np.zeros((3, m.nv))
        mujoco.mj_jacSubtreeCom(m, d, jc, cassie.index.pelvis_body)
        np.testing.assert_allclose(T.com_J, jc, atol=1e-9)
        np.testing.assert_allclose(T.com, d.subtree_com[cassie.index.pelvis_body], atol=1e-9)
        np.testing.assert_allclose(T.com_vel, jc @ d.qvel, atol=1e-9)
        np.testing.assert_allclose(T.pelvis_R, d.xmat[1].reshape(3, 3), atol=1e-9)
        for k, b in enumerate(cassie.index.foot_body):
            jr = np.zeros((3, m.nv))
            mujoco.mj_jacBody(m, d, None, jr, b)
            np.testing.assert_allclose(T.foot_Jw[k], jr, atol=1e-9)
        jr = np.zeros((3, m.nv))
        mujoco.mj_jacBody(m, d, None, jr, cassie.index.pelvis_body)
        np.testing.assert_allclose(T.pelvis_Jw, jr, atol=1e-9)
        np.testing.assert_allclose(T.pelvis_omega, jr @ d.qvel, atol=1e-9)
        right = jax.jit(cm.foot_contact)(T, jnp.int32(1))  # traced side selects the right foot
        np.testing.assert_allclose(right.J, T.site_J[2:4])
        np.testing.assert_allclose(right.pos[1], d.site_xpos[cassie.index.heel_site.right], atol=1e-9)
        np.testing.assert_allclose(T.foot_R, d.site_xmat[list(cassie.index.toe_site)].reshape(2, 3, 3),
                                   atol=1e-9)


def _fd_jdot_qdot(m, d, jac_fn, h=1e-6):
    """Central difference of J(q(t)) q̇ along q(t) = q ⊕ t q̇ (C MuJoCo Jacobians)."""
    out = []
    for sgn in (1.0, -1.0):
        q = d.qpos.copy()
        mujoco.mj_integratePos(m, q, d.qvel, sgn * h)
        dd = mujoco.MjData(m)
        dd.qpos[:] = q
        mujoco.mj_fwdPosition(m, dd)
        out.append(jac_fn(dd) @ d.qvel)
    return (out[0] - out[1]) / (2 * h)


@pytest.mark.timeout(120)
@pytest.mark.slow
def test_jdot_qdot_matches_finite_differences(cassie, terms_fn):
    # Tolerance 1e-6 m/s²: with h = 1e-6 the truncation error is O(h² |d³p/dt³|) ~ 1e-10 and
    # round-off ~ 1e-16 |J q̇| / h ~ 1e-9; values themselves are O(1-10).
    m = cassie.mj_model
    d = _random_state(cassie, np.random.default_rng(1), vel=2.0, dq=0.05)
    T = terms_fn(mjx.put_data(m, d))

    def sites_J(dd):
        rows = []
        for s in cassie.index.contact_sites:
            jp = np.zeros((3, m.nv))
            mujoco.mj_jacSite(m, dd, jp, None, s)
            rows.append(jp)
        return np.concatenate(rows)

    def com_J(dd):
        jc = np.zeros((3, m.nv))
        mujoco.mj_jacSubtreeCom(m, dd, jc, cassie.index.pelvis_body)
        return jc

    def loop_J(dd):
        eq = dd.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY
        return dd.efc_J.reshape(dd.nefc, m.nv)[eq]

    def feet_Jw(dd):
        rows = []
        for b in cassie.index.foot_body:
            jr = np.zeros((3, m.nv))
            mujoco.mj_jacBody(m, dd, None, jr, b)
            rows.append(jr)
        return np.concatenate(rows)

    np.testing.assert_allclose(T.foot_Jw_dqd.reshape(-1), _fd_jdot_qdot(m, d, feet_Jw), atol=1e-6)
    np.testing.assert_allclose(T.pelvis_Jw_dqd, 0.0, atol=1e-12)
    fd = _fd_jdot_qdot(m, d, sites_J)
    assert np.abs(fd).max() > 0.1  # non-trivial state
    np.testing.assert_allclose(T.site_jdqd.reshape(-1), fd, atol=1e-6)
    np.testing.assert_allclose(T.com_jdqd, _fd_jdot_qdot(m, d, com_J), atol=1e-6)
    np.testing.assert_allclose(T.loop_jdqd, _fd_jdot_qdot(m, d, loop_J), atol=1e-6)


def test_stance_projection_closes_chains_and_grounds_feet(cassie):
    """Random ±0.03 rad hinge offsets open the chains by up to ~2 cm; after the projection C
    MuJoCo's own equality residuals (efc_pos of the connect rows, not the code under test) and
    the contact-sphere heights are zero to 1e-8 m (the Gauss–Newton stops at 1e-9 m; float64
    kinematics is exact to ~1e-15 m), and the keyframe (already consistent) is unchanged."""
    m = cassie.mj_model
    key = m.key_qpos[cassie.index.stand_key].copy()
    q, res = cm.stance_projection(cassie, key[None])
    assert np.abs(q[0] - key).max() < 1e-7 and res[0] < 1e-8
    rng = np.random.default_rng(5)
    hinge = [m.jnt_qposadr[j] for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE]
    Q = np.repeat(key[None], 6, 0)
    Q[:, hinge] += rng.uniform(-0.03, 0.03, (6, len(hinge)))
    P, res = cm.stance_projection(cassie, Q)
    assert np.all(res < 1e-8)
    # the residual returned is the one of the configuration returned: after a single
    # Gauss–Newton step it is smaller than at the start but not yet converged
    _, r0 = cm.stance_projection(cassie, Q, max_iter=0)
    _, r1 = cm.stance_projection(cassie, Q, max_iter=1)
    assert np.all(r1 < r0) and r1.max() > 1e-9
    d = mujoco.MjData(m)
    opened = []
    for q0, q1 in zip(Q, P):
        for q, check in ((q0, False), (q1, True)):
            d.qpos[:] = q
            d.qvel[:] = 0
            mujoco.mj_forward(m, d)
            eq = d.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY
            z = d.site_xpos[list(cassie.index.contact_sites), 2] - cm.FOOT_SPHERE_RADIUS
            if check:
                assert np.abs(d.efc_pos[eq]).max() < 1e-8 and np.abs(z).max() < 1e-8
                assert abs(np.linalg.norm(q[3:7]) - 1) < 1e-12
            else:
                opened.append(max(np.abs(d.efc_pos[eq]).max(), np.abs(z).max()))
    assert max(opened) > 1e-3                       # the offsets did open the chains
    # the minimum-norm correction keeps the configurations random (and distinct)
    assert np.all(np.abs(P[:, hinge] - key[hinge]).max(axis=1) > 0.005)


def test_c_mujoco_equality_reference_includes_jdot_qdot(cassie, terms_fn):
    """C MuJoCo 4.x writes the connect rows' reference acceleration as
    aref = −b·(J q̇) − k·imp·r − J̇q̇; MJX 3.17 omits the −J̇q̇ term. Checking the C rows
    against our J̇q̇ is a second independent check of it and documents why MJX and C
    MuJoCo qacc differ slightly when the rods move fast (1e-6: float64 round-off)."""
    m = cassie.mj_model
    d = _random_state(cassie, np.random.default_rng(2), vel=1.0)
    T = terms_fn(mjx.put_data(m, d))
    eq = d.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY
    k, b, imp = d.efc_KBIP[eq, 0], d.efc_KBIP[eq, 1], d.efc_KBIP[eq, 2]
    base = -b * d.efc_vel[eq] - k * imp * d.efc_pos[eq]
    np.testing.assert_allclose(d.efc_aref[eq] - base, -np.asarray(T.loop_jdqd), atol=1e-6)


@pytest.mark.timeout(240)
@pytest.mark.slow
def test_mjx_forward_matches_c_mujoco(cassie):
    """qacc from mjx.forward equals C MuJoCo's on random states with feet ≈5 mm in the floor
    (4 contacts active) and joint limits. The equality rows are switched off in both for this
    comparison: their reference accelerations differ by design between C MuJoCo 4.x and MJX
    3.17 (see the test above). Both solvers run to convergence (50 iterations, tolerance
    1e-12), so the tolerance 1e-6·max|qacc| covers solver round-off only."""
    m = mujoco.MjModel.from_xml_path(str(cm.SCENE_XML))
    m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_EQUALITY
    m.opt.iterations, m.opt.ls_iterations, m.opt.tolerance = 50, 50, 1e-12
    c2 = cm.Cassie(**{**cassie.__dict__, "mj_model": m})
    mx = mjx.put_model(m, impl="jax")
    fwd = jax.jit(mjx.forward)
    rng = np.random.default_rng(4)
    for _ in range(3):
        d = _random_state(c2, rng, vel=0.5, dq=0.005, sink=0.005)
        assert d.ncon == 4
        out = fwd(mx, mjx.put_data(m, d))
        scale = np.abs(d.qacc).max()
        np.testing.assert_allclose(out.qacc_smooth, d.qacc_smooth, atol=1e-8 * scale)
        np.testing.assert_allclose(out.qacc, d.qacc, atol=1e-6 * scale)


# ----------------------------------------------------------------------------- batching


@pytest.mark.timeout(180)
@pytest.mark.slow
def test_make_batch_and_vmapped_terms(cassie, terms_fn):
    key = jax.random.PRNGKey(0)
    batch = cm.make_batch(cassie, 3, key, qpos_noise=0.01, qvel_noise=0.1, forward=False)
    assert batch.qpos.shape == (3, 35) and batch.qvel.shape == (3, 32)
    dq = np.asarray(batch.qpos) - cassie.stand_qpos
    assert np.abs(dq).max() <= 0.01 + 1e-12 and np.abs(dq).max() > 0
    np.testing.assert_array_equal(dq[:, :7], 0.0)  # pelvis untouched
    assert np.abs(np.asarray(batch.qvel)).max() <= 0.1 + 1e-12
    # a light vmapped function (the full robot_terms compiles in the test above)
    mx = cassie.mjx_model

    def light(d):
        d = mjx.com_pos(mx, mjx.kinematics(mx, d))
        return cm.site_jacobians(cassie, d), cm.loop_jacobian(cassie, d), cm.loop_residual(cassie, d)

    J, Jl, r = jax.jit(jax.vmap(light))(batch)
    assert J.shape == (3, 4, 3, 32) and Jl.shape == (3, 12, 32)
    # each batch member equals C MuJoCo at its own state (vmap does not mix robots)
    m = cassie.mj_model
    for b in range(3):
        d = mujoco.MjData(m)
        d.qpos[:] = np.asarray(batch.qpos[b])
        mujoco.mj_fwdPosition(m, d)
        jp = np.zeros((3, m.nv))
        mujoco.mj_jacSite(m, d, jp, None, cassie.index.heel_site.right)
        np.testing.assert_allclose(J[b, 3], jp, atol=1e-9)
        eq = d.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY
        np.testing.assert_allclose(r[b], d.efc_pos[eq], atol=1e-9)
    assert np.abs(np.asarray(r)).max() > 1e-5  # joint offsets open the chains, as documented
    with pytest.raises(ValueError, match="batch_size"):
        cm.make_batch(cassie, 0, key)
    with pytest.raises(ValueError, match="qpos_noise"):
        cm.make_batch(cassie, 2, key, qpos_noise=-1.0)


def test_rpy_and_quat_helpers():
    # independent: scipy-free closed form, R = Rz(y) Ry(p) Rx(r)
    r, p, y = 0.1, -0.2, 0.3
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    R = (np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
         @ np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
         @ np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]]))
    np.testing.assert_allclose(cm.rpy_from_mat(jnp.asarray(R)), [r, p, y], atol=1e-12)
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, R.reshape(-1))
    np.testing.assert_allclose(cm.quat_to_mat(jnp.asarray(q)), R, atol=1e-12)
