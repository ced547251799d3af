"""Uneven ground: a step, or a patch of rough ground; the scene that holds them, and the ground
height under a point.

**A step** (``realism.step_height`` h, ``realism.step_x`` x_s): the ground is flat at z = 0
for world x < x_s and at z = h beyond, for every y: h > 0 is a step up, h < 0 a step down.  The
scene gets one static box, ``2 HALF[0]`` long and ``2 HALF[1]`` wide:

    step up   (h > 0):  floor plane at z = 0, box top at z = h over x ≥ x_s
    step down (h < 0):  floor plane at z = h, box top at z = 0 over x ≤ x_s
    no step   (h = 0):  floor plane at z = 0, box top at z = −1 m (under the floor: no contact)

**Rough ground** (``realism.rough_height`` a > 0, from x_s on): a MuJoCo height field is the
ground, nodes every ``CELL`` m on a ``2 HF_HALF[0]`` × ``2 HF_HALF[1]`` m patch centred at
(``HF_CENTRE_X``, 0) (world x from −10 to 40 m, y from −15 to 15 m).  Each node's height is
drawn uniformly from [0, a] (the scenario's seed fixes the draw), nodes before x_s are 0, and
the surface is MuJoCo's: two triangles per cell, split along the diagonal from node (i, j) to
(i + 1, j + 1) (:func:`hfield_height`).  The floor plane drops to z = ``BURIED`` (a plane at
z = 0 would touch the feet together with the field's flat part, doubling those contacts), so
off the patch the ground ends.  Without rough ground the field lies buried at z = ``BURIED``
− 1 m.

Both bodies, ``terrain`` (the box) and ``rough`` (the field), are appended after the robot, so
no index of the robot's bodies, joints, geoms or sites moves.  Only their positions and the
field's heights change between scenarios, so one compiled program serves every step height and
every rough draw (MJX takes them as model arrays).  A batch's ground is one of ``hlip_jax.plants.base.GROUND_KINDS``
(``arrays.Shapes.terrain``): "flat", no terrain at all (the plain scene, bit for bit); "step",
the block alone (a batch with steps walks the same scene whether or not the field exists);
"rough", the block and the field, the unused one buried.

The controller is blind to the terrain: its model keeps the flat ground, and its COM-height
target and swing profile are measured from the stance foot's sole, wherever it stands
(``cassie.height_reference = "stance_foot"``, the default; "ground" measures from z = 0); only
the contact detection of an ideal robot (the distance of a foot sphere to the ground under it,
:func:`height`) sees the terrain.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from hlip_jax.plants.cassie import model
from hlip_jax.plants.cassie.mjx_import import mjx

#: half-sizes [m] of the terrain block: length (x), width (y), thickness (z)
HALF = (50.0, 50.0, 0.5)
#: top of the block when the scenario has no step [m] (under the floor)
BURIED = -1.0
NAME = "terrain"

#: rough patch: node spacing [m], half-extent (x, y) [m], centre x [m], elevation scale [m]
#: (MuJoCo's hfield size[2]: the largest height a node can take), prism base depth [m]
CELL = 0.2
HF_HALF = (25.0, 15.0)
HF_CENTRE_X = 15.0
HF_TOP = 0.1
HF_BASE = 0.1
HF_NCOL = int(round(2 * HF_HALF[0] / CELL)) + 1     # nodes along x
HF_NROW = int(round(2 * HF_HALF[1] / CELL)) + 1     # nodes along y
HF_NAME = "rough"
#: stream of the scenario seed that draws the rough heights (apart from the step noise's)
ROUGH_STREAM = 7


class Terrain(NamedTuple):
    """A scenario's ground (arrays; :func:`make` builds them)."""
    floor: jax.Array      # z of the floor plane [m]
    centre_x: jax.Array   # x of the block's centre [m]
    top: jax.Array        # z of the block's top face [m]
    rough_z: jax.Array    # z of the height field's zero level [m] (buried without rough ground)
    bumps: jax.Array | None  # (HF_NROW * HF_NCOL,) node heights / HF_TOP, row-major (row = y);
                             # None in a batch without the field ("step")


def make(step_height: float, step_x: float, rough_height: float = 0.0, seed: int = 0,
         field: bool = False) -> Terrain:
    """:class:`Terrain` (numpy) of a step of ``step_height`` [m] at world x = ``step_x`` [m], or
    of rough ground of heights up to ``rough_height`` [m] from ``step_x`` on (drawn from
    ``seed``); not both.  ``field``: the batch's scene has the height field (its ground kind is
    "rough"), which rough ground needs."""
    if step_height != 0.0 and rough_height != 0.0:
        raise ValueError("realism.step_height and realism.rough_height: a scenario has a step "
                         "or rough ground, not both")
    if rough_height != 0.0 and not field:
        raise ValueError("realism.rough_height: rough ground needs the scene with the height "
                         "field (field=True; arrays.shapes_of sets the batch's kind 'rough')")
    f = np.float64
    if step_height > 0:
        floor, centre, top = f(0.0), f(step_x + HALF[0]), f(step_height)
    elif step_height < 0:
        floor, centre, top = f(step_height), f(step_x - HALF[0]), f(0.0)
    else:
        floor = f(0.0) if rough_height == 0 else f(BURIED)      # the field is the ground
        centre, top = f(step_x + HALF[0]), f(BURIED)
    bumps = np.zeros((HF_NROW, HF_NCOL))
    if rough_height > 0:
        rng = np.random.default_rng([int(seed) % 2**32, ROUGH_STREAM])
        bumps = rng.uniform(0.0, rough_height / HF_TOP, bumps.shape)
        bumps[:, node_x() < step_x] = 0.0
    rough_z = f(0.0) if rough_height > 0 else f(BURIED - 1.0)
    return Terrain(floor=floor, centre_x=centre, top=top, rough_z=rough_z,
                   bumps=bumps.ravel() if field else None)


def node_x() -> np.ndarray:
    """(HF_NCOL,) world x of the height field's node columns [m]."""
    return HF_CENTRE_X - HF_HALF[0] + CELL * np.arange(HF_NCOL)


def hfield_height(t: Terrain, xy) -> jax.Array:
    """Height [m] of the height field's surface under the points ``xy`` (..., 2); −inf off the
    patch or without a field.  In a cell with corner heights h00 (node i, j), h10 (i + 1, j),
    h01 (i, j + 1) and h11, at fractions (u, v) ∈ [0, 1]² along x and y, MuJoCo's two
    triangles give

        u ≥ v:  h00 + u (h10 − h00) + v (h11 − h10)
        u < v:  h00 + v (h01 − h00) + u (h11 − h01)."""
    if t.bumps is None:
        return jnp.full(jnp.shape(xy)[:-1], -jnp.inf)
    gx = (xy[..., 0] - HF_CENTRE_X + HF_HALF[0]) / CELL
    gy = (xy[..., 1] + HF_HALF[1]) / CELL
    inside = (gx >= 0) & (gx <= HF_NCOL - 1) & (gy >= 0) & (gy <= HF_NROW - 1)
    i = jnp.clip(jnp.floor(gx), 0, HF_NCOL - 2).astype(jnp.int32)
    j = jnp.clip(jnp.floor(gy), 0, HF_NROW - 2).astype(jnp.int32)
    u, v = jnp.clip(gx - i, 0.0, 1.0), jnp.clip(gy - j, 0.0, 1.0)
    h = lambda di, dj: t.bumps[(j + dj) * HF_NCOL + i + di]
    h00, h10, h01, h11 = h(0, 0), h(1, 0), h(0, 1), h(1, 1)
    lower = h00 + u * (h10 - h00) + v * (h11 - h10)
    upper = h00 + v * (h01 - h00) + u * (h11 - h01)
    z = t.rough_z + HF_TOP * jnp.where(u >= v, lower, upper)
    return jnp.where(inside, z, -jnp.inf)


def height(t: Terrain, xy) -> jax.Array:
    """Ground height [m] under the points ``xy`` (..., 2): the highest of the floor, the block's
    top where the point lies over the block, and the height field's surface on its patch."""
    over = jnp.abs(xy[..., 0] - t.centre_x) <= HALF[0]
    step = jnp.where(over, jnp.maximum(t.top, t.floor), t.floor)
    return jnp.maximum(step, hfield_height(t, xy))


@functools.lru_cache(maxsize=2)
def scene(field: bool = False) -> tuple[mujoco.MjModel, mjx.Model]:
    """(C MuJoCo model, MJX-JAX model) of the walking scene with the terrain block and, with
    ``field``, the height field (both buried).  Both collide like the floor (same contact
    type, affinity, friction and condim)."""
    spec = mujoco.MjSpec.from_file(str(model.SCENE_XML))
    floor = spec.geom("floor")
    like_floor = dict(contype=floor.contype, conaffinity=floor.conaffinity, condim=floor.condim,
                      friction=list(floor.friction))
    body = spec.worldbody.add_body(name=NAME)     # at the origin: geom_pos is in the world
    body.add_geom(name=NAME, type=mujoco.mjtGeom.mjGEOM_BOX, size=list(HALF),
                  pos=[HALF[0], 0.0, BURIED - HALF[2]], rgba=[0.45, 0.42, 0.38, 1.0], **like_floor)
    if field:
        spec.add_hfield(name=HF_NAME, nrow=HF_NROW, ncol=HF_NCOL,
                        size=[HF_HALF[0], HF_HALF[1], HF_TOP, HF_BASE],
                        userdata=[0.0] * (HF_NROW * HF_NCOL))
        spec.worldbody.add_body(name=HF_NAME).add_geom(
            name=HF_NAME, type=mujoco.mjtGeom.mjGEOM_HFIELD, hfieldname=HF_NAME,
            pos=[HF_CENTRE_X, 0.0, BURIED - 1.0], rgba=[0.40, 0.45, 0.38, 1.0], **like_floor)
    m = spec.compile()
    with jax.ensure_compile_time_eval():      # first called while tracing: keep it concrete
        return m, mjx.put_model(m)


def geoms() -> tuple[int, int, int]:
    """(floor, block, height-field) geom ids in :func:`scene` (the field's id in the scene
    with it; the floor's and the block's are the same in both)."""
    m = scene(field=True)[0]
    return tuple(mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, n)
                 for n in ("floor", NAME, HF_NAME))


def scene_of(t: Terrain) -> tuple[mujoco.MjModel, mjx.Model]:
    """:func:`scene` with the height field exactly when ``t`` carries one."""
    return scene(field=t.bumps is not None)


def place(mx: mjx.Model, t: Terrain) -> mjx.Model:
    """``mx`` (built on :func:`scene_of` ``t``) with the floor, the block and the height field
    where ``t`` puts them, and the field's heights; block and field take the floor's friction
    (which the scenario's realism may have set)."""
    fl, blk, hf = geoms()
    dt = mx.geom_pos.dtype
    z = lambda a: jnp.asarray(a, dt)
    pos = mx.geom_pos.at[fl, 2].set(z(t.floor))
    pos = pos.at[blk].set(jnp.stack([z(t.centre_x), z(0.0), z(t.top) - HALF[2]]))
    friction = mx.geom_friction.at[blk].set(mx.geom_friction[fl])
    if t.bumps is None:
        return mx.replace(geom_pos=pos, geom_friction=friction)
    return mx.replace(geom_pos=pos.at[hf, 2].set(z(t.rough_z)),
                      geom_friction=friction.at[hf].set(mx.geom_friction[fl]),
                      hfield_data=jnp.asarray(t.bumps, mx.hfield_data.dtype))
