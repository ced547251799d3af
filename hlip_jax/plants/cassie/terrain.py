"""A step in the ground: the scene with a terrain block, and the ground height under a point.

A scenario's ground (``realism.step_height`` h, ``realism.step_x`` x_s) is flat at z = 0 for
world x < x_s and at z = h beyond, for every y: h > 0 is a step up, h < 0 a step down.  The
scene gets one static box, the body ``terrain`` appended after the robot (so no index of the
robot's bodies, joints, geoms or sites moves), ``2 HALF[0]`` long and ``2 HALF[1]`` wide:

    step up   (h > 0):  floor plane at z = 0, box top at z = h over x ≥ x_s
    step down (h < 0):  floor plane at z = h, box top at z = 0 over x ≤ x_s
    no step   (h = 0):  floor plane at z = 0, box top at z = −1 m (under the floor: no contact)

Only the box's and the floor's positions change between scenarios, so one compiled program
serves every step height (MJX takes them as model arrays).  A batch without a stepped scenario
has no block at all (its scene is the plain one, bit for bit); a batch with one gives every
robot the block.  The controller is blind to the step: its model keeps the flat ground, and its
COM-height target and swing profile are measured from the stance foot's sole, wherever it
stands (``cassie.height_reference = "stance_foot"``, the default; "ground" measures from z = 0);
only the contact detection of an ideal robot (the distance of a foot sphere to the ground
under it, :func:`height`) sees the terrain.
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


class Terrain(NamedTuple):
    """A scenario's ground (arrays; :func:`make` builds them)."""
    floor: jax.Array      # z of the floor plane [m]
    centre_x: jax.Array   # x of the block's centre [m]
    top: jax.Array        # z of the block's top face [m]


def make(step_height: float, step_x: float) -> Terrain:
    """:class:`Terrain` (numpy) of a step of ``step_height`` [m] at world x = ``step_x`` [m]."""
    f = np.float64
    if step_height > 0:
        return Terrain(floor=f(0.0), centre_x=f(step_x + HALF[0]), top=f(step_height))
    if step_height < 0:
        return Terrain(floor=f(step_height), centre_x=f(step_x - HALF[0]), top=f(0.0))
    return Terrain(floor=f(0.0), centre_x=f(step_x + HALF[0]), top=f(BURIED))


def height(t: Terrain, xy) -> jax.Array:
    """Ground height [m] under the points ``xy`` (..., 2): the block's top where it is above
    the floor and the point lies over it, the floor elsewhere."""
    over = jnp.abs(xy[..., 0] - t.centre_x) <= HALF[0]
    return jnp.where(over, jnp.maximum(t.top, t.floor), t.floor)


@functools.lru_cache(maxsize=1)
def scene() -> tuple[mujoco.MjModel, mjx.Model]:
    """(C MuJoCo model, MJX-JAX model) of the walking scene with the terrain block (buried).
    The block collides like the floor (same contact type, affinity, friction and condim)."""
    spec = mujoco.MjSpec.from_file(str(model.SCENE_XML))
    floor = spec.geom("floor")
    body = spec.worldbody.add_body(name=NAME)     # at the origin: geom_pos is in the world
    body.add_geom(name=NAME, type=mujoco.mjtGeom.mjGEOM_BOX, size=list(HALF),
                  pos=[HALF[0], 0.0, BURIED - HALF[2]],
                  contype=floor.contype, conaffinity=floor.conaffinity, condim=floor.condim,
                  friction=list(floor.friction), rgba=[0.45, 0.42, 0.38, 1.0])
    m = spec.compile()
    with jax.ensure_compile_time_eval():      # first called while tracing: keep it concrete
        return m, mjx.put_model(m)


def geoms() -> tuple[int, int]:
    """(floor geom id, block geom id) in :func:`scene`."""
    m = scene()[0]
    return (mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "floor"),
            mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, NAME))


def place(mx: mjx.Model, t: Terrain) -> mjx.Model:
    """``mx`` (built on :func:`scene`'s model) with the floor and the block where ``t`` puts
    them; the block takes the floor's friction (which the scenario's realism may have set)."""
    fl, blk = geoms()
    dt = mx.geom_pos.dtype
    pos = mx.geom_pos.at[fl, 2].set(jnp.asarray(t.floor, dt))
    pos = pos.at[blk].set(jnp.stack([jnp.asarray(t.centre_x, dt), jnp.zeros((), dt),
                                     jnp.asarray(t.top, dt) - HALF[2]]))
    return mx.replace(geom_pos=pos, geom_friction=mx.geom_friction.at[blk].set(mx.geom_friction[fl]))
