"""The dense smooth terms (:mod:`hlip_jax.plants.cassie.tree_terms`, ``impl.terms = "dense"``)
against C MuJoCo's own stages (mj_forward's kinematics, COM, composite inertia, velocities,
passive forces and RNE; mj_fullM) at random states of Cassie and of a small tree with every
joint type, with parameters edited in the model, and against MJX's stages through
:func:`model.robot_terms`.  Float64 throughout: the two sides compute the same sums in other
orders, so they agree to rounding; 1e-10 of each quantity's largest entry leaves three orders
of magnitude above what was observed (≤ 3e-14 relative) and fails on any wrong term."""

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

from hlip_jax.plants.cassie import model, tree_terms

from support import jaxpr_census

REL = 1e-10

#: every joint type, two joints in one body (a hinge and a slide; a hinge and a ball), a body
#: without joints, a branch
SMALL_TREE = """
<mujoco>
  <option gravity="0.3 -0.2 -9.81"/>
  <default><geom contype="0" conaffinity="0"/></default>
  <worldbody>
    <body name="base" pos="0 0 1">
      <freejoint/>
      <geom type="box" size="0.2 0.1 0.05" mass="4"/>
      <body name="a" pos="0.1 0.2 0" quat="0.9 0.1 0.3 0.2">
        <joint name="h1" type="hinge" axis="0 1 0" pos="0.05 0 0" stiffness="30" springref="0.2"
               damping="0.5" armature="0.01"/>
        <joint name="s1" type="slide" axis="1 0 1" stiffness="100" damping="2"/>
        <geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.03" mass="1.2"/>
        <body name="b" pos="0 0 -0.3">
          <joint name="ball" type="ball" pos="0 0.02 0" damping="0.1"/>
          <geom type="box" size="0.05 0.07 0.02" pos="0.03 0 -0.02" mass="0.7"/>
          <site name="tip" pos="0.1 0 -0.05" quat="0.8 0 0.6 0"/>
        </body>
      </body>
      <body name="rigid" pos="-0.2 0 0.1" euler="0.3 0.1 0">
        <geom type="sphere" size="0.04" mass="0.3"/>
        <body name="c" pos="0 0.1 0">
          <joint name="h2" type="hinge" axis="1 1 0" ref="0.4"/>
          <geom type="ellipsoid" size="0.05 0.03 0.08" mass="0.5" pos="0 0.02 0.01"/>
          <body name="d" pos="0.05 0 -0.1">
            <joint name="h3" type="hinge" axis="0 0 1" pos="0 0 0.02" damping="0.3"/>
            <joint name="ball2" type="ball" pos="0.01 0 0"/>
            <geom type="box" size="0.02 0.03 0.04" mass="0.2" pos="0 0 -0.03"/>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def _reference(m, qpos, qvel):
    """C MuJoCo's terms at (qpos, qvel), by the names of :class:`tree_terms.Smooth`."""
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:] = qpos, qvel
    mujoco.mj_forward(m, d)
    M = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, M)
    qn = d.qpos.copy()
    for j in np.flatnonzero(np.isin(m.jnt_type, (tree_terms.FREE, tree_terms.BALL))):
        a = m.jnt_qposadr[j] + (3 if m.jnt_type[j] == tree_terms.FREE else 0)
        qn[a:a + 4] /= np.linalg.norm(qn[a:a + 4])
    return dict(qpos=qn, xpos=d.xpos, xmat=d.xmat.reshape(-1, 3, 3), xipos=d.xipos,
                ximat=d.ximat.reshape(-1, 3, 3), site_xpos=d.site_xpos,
                site_xmat=d.site_xmat.reshape(-1, 3, 3), subtree_com=d.subtree_com,
                cdof=d.cdof, cdof_dot=d.cdof_dot, cvel=d.cvel, qM=M, qfrc_bias=d.qfrc_bias,
                qfrc_passive=d.qfrc_passive)


def _random_state(m, q0, rng, spread):
    qpos = q0 + spread * rng.standard_normal(m.nq)      # quaternions off unit length on purpose
    return qpos, rng.standard_normal(m.nv)


def _assert_terms(m, mx, qpos, qvel, tree=None):
    tree = tree_terms.tree_of(m) if tree is None else tree
    got = jax.jit(lambda q, v: tree_terms.smooth(tree, mx, q, v))(jnp.asarray(qpos),
                                                                    jnp.asarray(qvel))
    for name, ref in _reference(m, qpos, qvel).items():
        err = np.abs(np.asarray(getattr(got, name)) - ref).max()
        assert err <= REL * max(np.abs(ref).max(), 1.0), (name, err)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_cassie_terms_match_c_mujoco(float64, seed):
    c = model.load()
    qpos, qvel = _random_state(c.mj_model, c.stand_qpos, np.random.default_rng(seed), 0.2)
    _assert_terms(c.mj_model, c.mjx_model, qpos, qvel)


@pytest.mark.parametrize("seed", [0, 1])
def test_every_joint_type_matches_c_mujoco(float64, seed):
    m = mujoco.MjModel.from_xml_string(SMALL_TREE)
    qpos, qvel = _random_state(m, m.qpos0, np.random.default_rng(seed), 0.5)
    _assert_terms(m, mjx.put_model(m), qpos, qvel)


def test_edited_parameters_carry_over(float64):
    # masses, inertias, damping and gravity read from the MJX model passed in: scale them in the
    # C model and in the MJX model alike (the controller's model edits the springs' damping,
    # the plant's scales the masses); the tree stays the unedited model's
    c = model.load()
    m = mujoco.MjModel.from_xml_path(str(model.SCENE_XML))
    scale = 1.0 + 0.1 * np.random.default_rng(3).standard_normal(m.nbody) ** 2
    m.body_mass[:] *= scale
    m.body_inertia[:] *= scale[:, None]
    m.dof_damping[:] += 2.0
    m.opt.gravity[:] = (0.1, 0.0, -9.7)
    mujoco.mj_setConst(m, mujoco.MjData(m))       # C MuJoCo's subtree masses follow the edit
    qpos, qvel = _random_state(m, c.stand_qpos, np.random.default_rng(4), 0.1)
    mx = c.mjx_model.replace(body_mass=jnp.asarray(m.body_mass),
                             body_inertia=jnp.asarray(m.body_inertia),
                             dof_damping=jnp.asarray(m.dof_damping),
                             opt=c.mjx_model.opt.replace(gravity=jnp.asarray(m.opt.gravity)))
    _assert_terms(m, mx, qpos, qvel, c.tree)


@pytest.mark.slow
def test_robot_terms_are_the_same_both_ways(float64):
    # every RobotTerms field (Jacobians, J̇q̇, COM, frames) from the dense terms and from MJX's
    c = model.load()
    rng = np.random.default_rng(5)
    d = mjx.put_data(c.mj_model, mujoco.MjData(c.mj_model))
    qpos, qvel = _random_state(c.mj_model, c.stand_qpos, rng, 0.1)
    d = d.replace(qpos=jnp.asarray(qpos), qvel=jnp.asarray(qvel))
    a = model.robot_terms(c, d, terms="mjx")
    b = model.robot_terms(c, d, terms="dense")
    for name in a._fields:
        x, y = np.asarray(getattr(a, name)), np.asarray(getattr(b, name))
        assert np.abs(x - y).max() <= REL * max(np.abs(x).max(), 1.0), name


def test_no_scatter_in_the_dense_terms(float64):
    # the point of the dense terms: no scatter equations (XLA's deterministic GPU operations
    # sort every scatter whose indices may repeat); MJX's stages have dozens
    c = model.load()
    q, v = jnp.asarray(c.stand_qpos), jnp.zeros(c.mj_model.nv)
    scatters = lambda f: sum(jaxpr_census.census(f, q, v).values())
    assert scatters(lambda q, v: tree_terms.smooth(c.tree, c.mjx_model, q, v)) == 0
    d = mjx.put_data(c.mj_model, mujoco.MjData(c.mj_model))
    assert scatters(lambda q, v: model.smooth(c, d.replace(qpos=q, qvel=v))) > 10


def test_models_the_dense_terms_do_not_cover_are_refused():
    xml = SMALL_TREE.replace('<joint name="ball" type="ball"', '<joint name="ball" type="ball" '
                             'stiffness="3"')
    with pytest.raises(ValueError, match="jnt_stiffness"):
        tree_terms.tree_of(mujoco.MjModel.from_xml_string(xml))
    with pytest.raises(ValueError, match="opt.disableflags"):
        tree_terms.tree_of(mujoco.MjModel.from_xml_string(SMALL_TREE.replace(
            '<option gravity="0.3 -0.2 -9.81"/>',
            '<option gravity="0.3 -0.2 -9.81"><flag gravity="disable"/></option>')))
    with pytest.raises(ValueError, match="terms: 'fast'; allowed"):
        c = model.load()
        model.smooth(c, mjx.put_data(c.mj_model, mujoco.MjData(c.mj_model)), terms="fast")


def test_terms_is_a_static_setting():
    from hlip_jax.simulation import config
    from hlip_jax.plants.cassie import plant
    assert "impl.terms" in config.STATIC_FIELDS
    assert config.field_spec(config.ImplConfig, "terms")["choices"] == model.TERMS
    cfg = config.ScenarioConfig(plant="cassie", impl=config.ImplConfig(terms="dense"))
    assert plant.settings(cfg).terms == "dense"


@pytest.mark.parametrize("noisy", [False, True], ids=["ideal", "sensor-noise"])
def test_a_walking_step_computes_every_term_as_set(monkeypatch, noisy):
    # the ticks, the step's end (the true state the S2S log records) and, with sensor noise,
    # the estimated state all compute the whole-body terms the way impl.terms says
    from hlip_jax.simulation import arrays, config, rollout
    from hlip_jax.sweepio import bench
    base = bench.configs(1, 1.0)[0]
    real = config.RealismConfig(joint_noise=0.5) if noisy else base.realism
    cfg = dataclasses.replace(base, realism=real,
                              impl=dataclasses.replace(base.impl, terms="dense"))
    batch, static = arrays.build([cfg])
    carry = jax.eval_shape(lambda b: rollout.start_batch(b, static), batch)[0]
    seen, inner = [], model.robot_terms

    def recording(cassie, d, mx=None, terms="mjx"):
        seen.append(terms)
        return inner(cassie, d, mx, terms)
    monkeypatch.setattr(model, "robot_terms", recording)
    jax.eval_shape(lambda b, c: rollout.segment_batch(b, c, jax.numpy.arange(1), static),
                   batch, carry)
    assert len(seen) >= (3 if noisy else 2) and set(seen) == {"dense"}, seen


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_closed_loop_with_dense_terms_walks_as_with_mjx_terms(float64):
    # the walking controller with impl.terms = "dense" against "mjx" over 1.5 s at 0.4 m/s,
    # float64.  The terms agree to ~1e-13, but the CLF-QP's ADMM stops at its tolerance
    # (1e-4), so a last-bit difference can end a tick's iterations one check earlier; the
    # torques then differ at the solver's tolerance and the closed loop grows that ~10-30x per
    # step (observed: 3e-8 m after steps 1 and 2, 5e-7 after 3, 1e-5 after 4, 3e-3 after 6).
    # Held: the first three steps within 1e-6 m, every step within 1 cm, both walking.
    from hlip_jax.sweepio import bench
    from hlip_jax.simulation import execution
    base = bench.configs(3, 1.5)[2]
    logs = {t: execution.simulate([dataclasses.replace(
        base, impl=dataclasses.replace(base.impl, terms=t))]) for t in ("mjx", "dense")}
    a, b = logs["mjx"], logs["dense"]
    assert int(a.status[0]) == 0 and int(b.status[0]) == 0
    n = int(a.valid[0].sum())
    assert n >= 5 and int(b.valid[0].sum()) == n
    diff = np.abs(a.x_robot[0, :n] - b.x_robot[0, :n]).reshape(n, -1).max(axis=1)
    assert diff[:4].max() < 1e-6 and diff.max() < 0.01, diff
