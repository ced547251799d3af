"""Uneven ground (hlip_jax.plants.cassie.terrain): the step's geometry in closed form, the rough
ground's surface against C MuJoCo's ray casts, the scene's robot indices, MJX's contacts on the
block and on the height field against C MuJoCo, and contact detection on both."""

import types

import mujoco
import numpy as np
import pytest

from hlip_jax.plants.cassie import model, realism, terrain
from hlip_jax.simulation import config as C

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
    """The robot's bodies, geoms and sites keep their ids; the block and the height field
    collide like the floor; the field is there only when asked for."""
    flat = model.load().mj_model
    step = terrain.scene()[0]
    assert (step.nbody, step.ngeom, step.nhfield) == (flat.nbody + 1, flat.ngeom + 1, 0)
    m, _ = terrain.scene(field=True)
    assert (m.nbody, m.ngeom, m.nsite, m.nq) == (flat.nbody + 2, flat.ngeom + 2, flat.nsite,
                                                 flat.nq)
    for name in ("geom_bodyid", "geom_type", "geom_size", "geom_contype", "geom_conaffinity",
                 "site_bodyid", "body_parentid"):
        a, b = getattr(m, name), getattr(flat, name)
        np.testing.assert_array_equal(a[:len(b)], b, err_msg=name)
    fl, blk, hf = terrain.geoms()
    for name in ("geom_contype", "geom_conaffinity", "geom_condim", "geom_friction"):
        np.testing.assert_array_equal(getattr(m, name)[blk], getattr(m, name)[fl], err_msg=name)
        np.testing.assert_array_equal(getattr(m, name)[hf], getattr(m, name)[fl], err_msg=name)


def test_place_moves_the_floor_and_the_block():
    _, mx = terrain.scene(field=True)
    fl, blk, hf = terrain.geoms()
    mx = mx.replace(geom_friction=mx.geom_friction.at[fl, 0].set(0.4))
    out = terrain.place(mx, terrain.make(-0.06, 3.0, field=True))
    np.testing.assert_allclose(np.asarray(out.geom_pos[fl]), [0.0, 0.0, -0.06])
    np.testing.assert_allclose(np.asarray(out.geom_pos[blk]),
                               [3.0 - HALF, 0.0, -terrain.HALF[2]])
    assert float(out.geom_pos[hf, 2]) == terrain.BURIED - 1.0       # no rough ground: buried
    assert float(out.geom_friction[blk, 0]) == float(out.geom_friction[hf, 0]) == pytest.approx(0.4)
    rough = terrain.make(0.0, 3.0, 0.04, seed=5, field=True)
    out = terrain.place(mx, rough)
    assert float(out.geom_pos[fl, 2]) == terrain.BURIED and float(out.geom_pos[hf, 2]) == 0.0
    np.testing.assert_allclose(np.asarray(out.hfield_data), rough.bumps, rtol=1e-6)


def test_rough_heights_are_seeded_bounded_and_start_at_step_x():
    """Node heights lie in [0, a] (a / HF_TOP in MuJoCo's normalised data), are 0 before x_s,
    fill the range after it, repeat for a seed and change with it; a step and rough ground
    together are refused, naming both fields."""
    a, xs = 0.03, 2.0
    t = terrain.make(0.0, xs, a, seed=11, field=True)
    z = t.bumps.reshape(terrain.HF_NROW, terrain.HF_NCOL) * terrain.HF_TOP
    before = terrain.node_x() < xs
    assert np.all(z[:, before] == 0.0)
    assert z[:, ~before].min() >= 0.0 and z[:, ~before].max() <= a
    assert z[:, ~before].min() < 0.01 * a and z[:, ~before].max() > 0.99 * a
    np.testing.assert_array_equal(t.bumps, terrain.make(0.0, xs, a, seed=11, field=True).bumps)
    assert not np.array_equal(t.bumps, terrain.make(0.0, xs, a, seed=12, field=True).bumps)
    assert C.RealismConfig.__dataclass_fields__["rough_height"].metadata["hi"] == terrain.HF_TOP
    with pytest.raises(ValueError, match="step_height and realism.rough_height"):
        terrain.make(0.02, xs, a, field=True)
    with pytest.raises(ValueError, match="needs the scene with the height field"):
        terrain.make(0.0, xs, a)
    assert terrain.make(0.03, xs).bumps is None


def test_rough_surface_matches_c_mujoco_ray_casts():
    """:func:`terrain.height` on rough ground equals the height C MuJoCo's ray cast finds on
    the same height field (mj_ray against the scene's field; independent of the module's
    triangle formula), to 1e-9 m (float64 on both sides; the ray's own rounding), at 400
    random points over the patch and its flat part, and at cell corners and edges."""
    t = terrain.make(0.0, 1.0, 0.05, seed=3, field=True)
    m = _reference_scene(t)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    rng = np.random.default_rng(0)
    pts = np.c_[rng.uniform(-9.9, 39.9, 400), rng.uniform(-14.9, 14.9, 400)]
    pts = np.r_[pts, [[3.0, 0.0], [3.1, 0.2], [3.05, 0.05], [0.9, 0.0]]]
    hf = m.ngeom - 1
    want = []
    for x, y in pts:
        geom = np.zeros(1, np.int32)
        dist = mujoco.mj_ray(m, d, np.array([x, y, 1.0]), np.array([0.0, 0.0, -1.0]),
                             None, 1, -1, geom)
        assert geom[0] == hf
        want.append(1.0 - dist)
    np.testing.assert_allclose(np.asarray(terrain.height(t, pts)), want, atol=1e-9)


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


def test_touching_measures_from_the_rough_surface():
    """On rough ground the ideal detector measures a sphere's gap from the field's surface
    under it (on a bump and on the flat part before x_s)."""
    c = model.load()
    real = realism.make(C.RealismConfig(rough_height=0.05))
    t = terrain.make(0.0, 1.0, 0.05, seed=3, field=True)
    r = model.FOOT_SPHERE_RADIUS
    z = float(terrain.height(t, np.array([3.05, 0.05])))
    assert z > 0.0
    sites = np.array([[3.05, 0.05, z + r + 0.002], [3.05, 0.05, z + r + 0.01],
                      [0.5, 0.0, r + 0.001], [0.5, 0.0, r + 0.01]])
    d = types.SimpleNamespace(qpos=np.zeros(c.mj_model.nq), site_xpos=np.zeros((c.mj_model.nsite, 3)))
    got = realism.touching(c, real, d, d, sites, 0.004, t)
    np.testing.assert_array_equal(np.asarray(got), [True, False, True, False])


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_dropped_on_rough_ground_matches_c_mujoco(float64):
    """Cassie at its stand pose, 4 cm above rough ground of bumps up to 3 cm under both feet,
    dropped and left passive for 0.2 s: MJX-JAX (its height-field prisms) and C MuJoCo (its
    own height-field collider) agree on the state within 1e-4 (measured 2.0e-5 in qpos after
    the landing, 8e-11 before it: the two colliders place the contacts slightly differently),
    and each foot comes to rest on the bumps (a toe or heel sphere within 2 mm of the surface
    under it, none sunk more than 3 mm: a foot may rest tilted on a bump)."""
    t = terrain.make(0.0, -5.0, 0.03, seed=4, field=True)
    m, d, err = _passive_from_stand(t, 400, lift=0.04)
    assert err < 1e-4, err
    sites = list(model.index_map(m).contact_sites)
    ground = np.asarray(terrain.height(t, d.site_xpos[sites, :2]))
    gap = (d.site_xpos[sites, 2] - model.FOOT_SPHERE_RADIUS - ground).reshape(2, 2)
    assert np.all(gap > -0.003), gap                        # no sphere sinks into a bump
    assert np.all(np.min(np.abs(gap), axis=1) < 0.002), gap  # each foot rests on the field


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_standing_on_the_block_matches_c_mujoco(float64):
    """Cassie at its stand pose on the block (a step down ahead, the floor 5 cm below) and left
    passive for 0.1 s: MJX-JAX and C MuJoCo agree on the state within 1e-4 (measured 6.5e-6 in
    qpos, the same as with the block buried and the feet on the floor: the block's placement
    and its box contacts add nothing), and the feet rest on the block's top (z = 0), not on
    the floor below it."""
    t = terrain.make(-0.05, 1.0)
    m, d, err = _passive_from_stand(t, 200)
    assert err < 1e-4, err
    feet = d.site_xpos[list(model.index_map(m).contact_sites), 2]
    assert np.all(feet < model.FOOT_SPHERE_RADIUS + 0.005)     # on the block (z = 0), not the floor


def _passive_from_stand(t, n: int, lift: float = 0.0):
    """(C model, C data, largest |qpos| difference [m or rad]) after ``n`` passive steps of
    C MuJoCo on :func:`_reference_scene` and of MJX-JAX on the module's scene placed for
    ``t``, both from the stand keyframe raised by ``lift`` [m]."""
    import jax
    from mujoco import mjx
    mx = terrain.place(terrain.scene_of(t)[1], t)
    m = _reference_scene(t)
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, model.index_map(m).stand_key)
    d.qpos[model.index_map(m).root_qpos + 2] += lift
    mujoco.mj_forward(m, d)
    dx = mjx.put_data(m, d)
    step = jax.jit(mjx.step)
    for _ in range(n):
        mujoco.mj_step(m, d)
        dx = step(mx, dx)
    return m, d, float(np.max(np.abs(np.asarray(dx.qpos) - d.qpos)))


def _reference_scene(t):
    """C MuJoCo's scene for ``t`` built from the MJCF directly (floor moved, a box and a height
    field placed in the world by hand in static bodies after the robot's, the layout MJX's data
    needs, the field's heights written into the compiled model), not by the module under
    test."""
    spec = mujoco.MjSpec.from_file(str(model.SCENE_XML))
    spec.geom("floor").pos = [0.0, 0.0, float(t.floor)]
    spec.worldbody.add_body().add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=list(terrain.HALF),
                            pos=[float(t.centre_x), 0.0, float(t.top) - terrain.HALF[2]],
                            contype=0, conaffinity=1, condim=3)
    if t.bumps is None:
        return spec.compile()
    nrow, ncol = 151, 251                              # 0.2 m nodes over 50 m × 30 m
    spec.add_hfield(name="ground", nrow=nrow, ncol=ncol, size=[25.0, 15.0, 0.1, 0.1],
                    userdata=[0.0] * (nrow * ncol))
    spec.worldbody.add_body().add_geom(type=mujoco.mjtGeom.mjGEOM_HFIELD, hfieldname="ground",
                                       pos=[15.0, 0.0, float(t.rough_z)],
                                       contype=0, conaffinity=1, condim=3)
    m = spec.compile()
    m.hfield_data[:] = t.bumps
    return m


@pytest.mark.parametrize("field, value, placed, kind", [("step_height", 0.03, "top", "step"),
                                                        ("rough_height", 0.02, "rough_z", "rough")])
def test_uneven_ground_makes_the_batch_carry_the_terrain_and_warp_is_refused(field, value,
                                                                             placed, kind):
    """Only a batch with a step builds the scene with the block, and only one with rough
    ground the scene with the height field too (the flat batches stay the plain scene, and
    the step batches the block's, bit for bit); such a scenario outside such a batch is an
    error, and the Warp physics (no terrain) refuses it with a message naming the field; a
    step and rough ground together are refused."""
    from hlip_jax.simulation import arrays
    from hlip_jax import plants
    from hlip_jax.plants.cassie import plant
    flat = C.ScenarioConfig(plant="cassie", duration=2.0)
    uneven = C.ScenarioConfig(plant="cassie", duration=2.0,
                              realism=C.RealismConfig(**{field: value}))
    assert arrays.shapes_of([flat]).terrain == "flat"
    assert arrays.shapes_of([flat, uneven]).terrain == kind
    assert plant.make_params(flat, 1, 0.0, True, "flat").terrain is None
    want = {"top": value, "rough_z": 0.0}[placed]
    assert float(getattr(plant.make_params(uneven, 1, 0.0, True, kind).terrain, placed)) == want
    with pytest.raises(ValueError, match=f"realism.{field}"):
        plant.make_params(uneven, 1, 0.0, True, "flat")
    warp = C.ScenarioConfig(plant="cassie", realism=C.RealismConfig(**{field: value}),
                            impl=C.ImplConfig(physics="warp"))
    assert plants.check(warp).startswith(f"realism.{field}: {value:g} needs the MJX-JAX physics")
    both = C.ScenarioConfig(plant="cassie", realism=C.RealismConfig(step_height=0.02,
                                                                      rough_height=0.02))
    assert plants.check(both).startswith("realism.rough_height: a scenario has a step")


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
