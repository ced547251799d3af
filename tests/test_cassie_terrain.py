"""The ground step (hlip_jax.plants.cassie.terrain): its geometry in closed form, the scene's
robot indices, MJX's contacts on the block against C MuJoCo, and contact detection on it."""

import types

import mujoco
import numpy as np
import pytest

from hlip_jax.plants.cassie import model, realism, terrain
from hlip_jax import config as C

HALF = terrain.HALF[0]


@pytest.mark.parametrize("h, floor, top", [(0.04, 0.0, 0.04), (-0.05, -0.05, 0.0),
                                           (0.0, 0.0, terrain.BURIED)])
def test_height_is_the_step_in_closed_form(h, floor, top):
    """Ground height along x for a step at x_s = 2 m: z = 0 before it and h after (exact; the
    block's far edge is HALF beyond the step, out of any run's reach)."""
    t = terrain.make(h, 2.0)
    assert (float(t.floor), float(t.top)) == (floor, top)
    x = np.array([-3.0, 0.0, 1.99, 2.01, 5.0, 30.0])
    z = np.asarray(terrain.height(t, np.stack([x, np.full_like(x, 0.7)], axis=-1)))
    np.testing.assert_array_equal(z, np.where(x < 2.0, 0.0, h))


def test_scene_appends_the_block_after_the_robot():
    """The robot's bodies, geoms and sites keep their ids; the block collides like the floor."""
    m, _ = terrain.scene()
    flat = model.load().mj_model
    assert (m.nbody, m.ngeom, m.nsite, m.nq) == (flat.nbody + 1, flat.ngeom + 1, flat.nsite, flat.nq)
    for name in ("geom_bodyid", "geom_type", "geom_size", "geom_contype", "geom_conaffinity",
                 "site_bodyid", "body_parentid"):
        a, b = getattr(m, name), getattr(flat, name)
        np.testing.assert_array_equal(a[:len(b)], b, err_msg=name)
    fl, blk = terrain.geoms()
    for name in ("geom_contype", "geom_conaffinity", "geom_condim", "geom_friction"):
        np.testing.assert_array_equal(getattr(m, name)[blk], getattr(m, name)[fl], err_msg=name)


def test_place_moves_the_floor_and_the_block():
    _, mx = terrain.scene()
    fl, blk = terrain.geoms()
    mx = mx.replace(geom_friction=mx.geom_friction.at[fl, 0].set(0.4))
    out = terrain.place(mx, terrain.make(-0.06, 3.0))
    np.testing.assert_allclose(np.asarray(out.geom_pos[fl]), [0.0, 0.0, -0.06])
    np.testing.assert_allclose(np.asarray(out.geom_pos[blk]),
                               [3.0 - HALF, 0.0, -terrain.HALF[2]])
    assert float(out.geom_friction[blk, 0]) == pytest.approx(0.4)


def test_touching_measures_from_the_ground_under_the_site():
    """The ideal detector counts a sphere as touching within the gap of the ground under it:
    on the block's top over the block, on the floor beyond its edge."""
    c = model.load()
    real = realism.make(C.RealismConfig(step_height=0.03))
    t = terrain.make(0.03, 2.0)
    r = model.FOOT_SPHERE_RADIUS
    sites = np.array([[2.5, 0.1, 0.03 + r + 0.002], [2.5, 0.1, 0.03 + r + 0.01],
                      [1.5, -0.1, r + 0.001], [1.5, -0.1, 0.03 + r + 0.001]])
    d = types.SimpleNamespace(qpos=np.zeros(c.mj_model.nq), site_xpos=np.zeros((c.mj_model.nsite, 3)))
    got = realism.touching(c, real, d, d, sites, 0.004, t)
    np.testing.assert_array_equal(np.asarray(got), [True, False, True, False])


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_standing_on_the_block_matches_c_mujoco(float64):
    """Cassie at its stand pose on the block (a step down ahead, the floor 5 cm below) and left
    passive for 0.1 s: MJX-JAX and C MuJoCo agree on the state within 1e-4 (measured 6.5e-6 in
    qpos, the same as with the block buried and the feet on the floor: the block's placement
    and its box contacts add nothing), and the feet rest on the block's top (z = 0), not on
    the floor below it."""
    import jax
    from mujoco import mjx
    t = terrain.make(-0.05, 1.0)
    mx = terrain.place(terrain.scene()[1], t)
    m = _reference_scene(t)
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, model.index_map(m).stand_key)
    mujoco.mj_forward(m, d)
    dx = mjx.put_data(m, d)
    step = jax.jit(mjx.step)
    for _ in range(200):
        mujoco.mj_step(m, d)
        dx = step(mx, dx)
    assert np.max(np.abs(np.asarray(dx.qpos) - d.qpos)) < 1e-4
    feet = d.site_xpos[list(model.index_map(m).contact_sites), 2]
    assert np.all(feet < model.FOOT_SPHERE_RADIUS + 0.005)     # on the block (z = 0), not the floor


def _reference_scene(t):
    """C MuJoCo's scene for ``t`` built from the MJCF directly (floor moved, a box placed in the
    world by hand in a static body after the robot's, the layout MJX's data needs), not by the
    module under test."""
    spec = mujoco.MjSpec.from_file(str(model.SCENE_XML))
    spec.geom("floor").pos = [0.0, 0.0, float(t.floor)]
    spec.worldbody.add_body().add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=list(terrain.HALF),
                            pos=[float(t.centre_x), 0.0, float(t.top) - terrain.HALF[2]],
                            contype=0, conaffinity=1, condim=3)
    return spec.compile()


def test_a_step_makes_the_batch_carry_the_block_and_warp_is_refused():
    """Only a batch with a stepped scenario builds the terrain scene (the flat batches stay the
    plain scene, bit for bit); a stepped scenario outside such a batch is an error, and the
    Warp physics (no block) refuses a step with a message naming the field."""
    from hlip_jax import plants, rollout
    from hlip_jax.plants.cassie import plant
    flat = C.ScenarioConfig(plant="cassie", duration=2.0)
    step = C.ScenarioConfig(plant="cassie", duration=2.0,
                            realism=C.RealismConfig(step_height=0.03))
    assert not rollout.shapes_of([flat]).terrain and rollout.shapes_of([flat, step]).terrain
    assert plant.make_params(flat, 1, 0.0, True, False).terrain is None
    assert float(plant.make_params(step, 1, 0.0, True, True).terrain.top) == 0.03
    with pytest.raises(ValueError, match="realism.step_height"):
        plant.make_params(step, 1, 0.0, True, False)
    warp = C.ScenarioConfig(plant="cassie", realism=C.RealismConfig(step_height=0.03),
                            cassie=C.CassieConfig(physics="warp"))
    assert plants.check(warp).startswith("realism.step_height: 0.03 needs the MJX-JAX physics")


@pytest.mark.parametrize("stance", [0, 1])
def test_height_reference_is_the_stance_sole_when_asked(stance):
    """``cassie.height_reference``: the coming SSP's stance foot's sole (toe/heel sphere
    bottoms' mean; the default), and exactly 0 when measured from the ground."""
    import jax.numpy as jnp
    from hlip_jax.plants.cassie import plant, tick
    r = model.FOOT_SPHERE_RADIUS
    z = np.array([-0.04, -0.05, 0.02, 0.03]) + r          # left toe, left heel, right toe, right heel
    terms = types.SimpleNamespace(site_pos=jnp.asarray(np.c_[np.zeros((4, 2)), z]))
    sole = [-0.045, 0.025][stance]
    for ref, want in (("ground", 0.0), ("stance_foot", sole)):
        g = plant.make_gait(C.CassieConfig(height_reference=ref))
        ctx = types.SimpleNamespace(new_st=jnp.int32(stance), gait=g)
        assert float(tick.height_reference(ctx, terms)) == pytest.approx(want, abs=1e-12)
    assert C.CassieConfig().height_reference == "stance_foot"
