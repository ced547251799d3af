"""Leg–leg and foot–foot proximity of the simulated Cassie, reported as events.

The model's only colliding geoms are the four foot spheres against the floor
(``assets/cassie/cassie.xml``), so the simulated legs pass through each other where a real
Cassie's would hit.  This module measures how close they come, from the capsules the model
draws for the lower legs (its ``look`` geoms of the bodies ``{side}_shin``, ``{side}_tarsus``
and ``{side}_foot``: radius ``size[0]``, half-length ``size[1]`` along the geom's z axis).
The capsule sizes are the MJCF's; nothing here adds geometry of its own.

For two capsules with axis segments [a0, a1], [b0, b1] and radii ra, rb the clearance is

    gap = min_{s,t ∈ [0,1]} |a0 + s (a1 − a0) − b0 − t (b1 − b0)| − ra − rb   [m],

negative where they interpenetrate.  :func:`gaps` gives, per tick, the smallest clearance
between the two feet and between any two lower-leg capsules of opposite legs (feet included);
the plant keeps their minimum over each walking step, and a step whose clearance is below zero
is a collision event in the step log.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import mujoco
import numpy as np

#: bodies whose capsules are checked, per side (the foot is the last)
LEG_BODIES = ("shin", "tarsus", "foot")
_MIN_RADIUS = 0.015   # [m] the drawn rods (achilles, plantar, 8 mm) are not leg links


class Capsules(NamedTuple):
    """Lower-leg capsules of both legs: geom ids (2, n) (left, right), radii (2, n) [m],
    half-lengths (2, n) [m] and whether each is the foot's (n,)."""
    geoms: np.ndarray
    radius: np.ndarray
    half: np.ndarray
    is_foot: np.ndarray


def capsules(mj_model: mujoco.MjModel) -> Capsules:
    """The capsules of :data:`LEG_BODIES` on each side, in the same order on both sides."""
    ids, foot = [], []
    for side in ("left", "right"):
        row, row_foot = [], []
        for name in LEG_BODIES:
            body = mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_BODY, f"{side}_{name}")
            for g in range(mj_model.ngeom):
                if (mj_model.geom_bodyid[g] == body
                        and mj_model.geom_type[g] == mujoco.mjtGeom.mjGEOM_CAPSULE
                        and mj_model.geom_size[g, 0] >= _MIN_RADIUS):
                    row.append(g)
                    row_foot.append(name == "foot")
        ids.append(row)
        foot.append(row_foot)
    if len(ids[0]) != len(ids[1]) or foot[0] != foot[1] or sum(foot[0]) != 1:
        raise ValueError("cassie model: the two legs' capsules do not match")
    g = np.asarray(ids)
    return Capsules(geoms=g, radius=mj_model.geom_size[g, 0], half=mj_model.geom_size[g, 1],
                    is_foot=np.asarray(foot[0]))


def segment_distance(a0, a1, b0, b1):
    """Smallest distance between segments [a0, a1] and [b0, b1] (…, 3) [m]: the closest
    parameters s, t ∈ [0, 1] of the clamped normal equations (the point–segment fallback
    covers parallel and degenerate segments)."""
    da, db, r = a1 - a0, b1 - b0, a0 - b0
    aa = jnp.sum(da * da, -1)
    bb = jnp.sum(db * db, -1)
    ab = jnp.sum(da * db, -1)
    ar = jnp.sum(da * r, -1)
    br = jnp.sum(db * r, -1)
    den = aa * bb - ab * ab
    tiny = 1e-12
    s = jnp.where(den > tiny * jnp.maximum(aa * bb, tiny),
                  jnp.clip((ab * br - bb * ar) / jnp.where(den > 0, den, 1.0), 0.0, 1.0), 0.0)
    t = (ab * s + br) / jnp.where(bb > tiny, bb, 1.0)
    t = jnp.clip(t, 0.0, 1.0)
    s = jnp.clip((ab * t - ar) / jnp.where(aa > tiny, aa, 1.0), 0.0, 1.0)
    t = jnp.clip((ab * s + br) / jnp.where(bb > tiny, bb, 1.0), 0.0, 1.0)
    d = (a0 + s[..., None] * da) - (b0 + t[..., None] * db)
    return jnp.sqrt(jnp.sum(d * d, -1))


def _axes(caps: Capsules, geom_xpos, geom_xmat):
    """Axis end points (2, n, 3) and (2, n, 3) of every capsule, world frame [m]."""
    centre = geom_xpos[caps.geoms]
    axis = geom_xmat[caps.geoms][..., :, 2] * jnp.asarray(caps.half)[..., None]
    return centre - axis, centre + axis


def gaps(caps: Capsules, geom_xpos, geom_xmat):
    """(feet, legs) clearances [m] of one configuration (``mjx.Data.geom_xpos`` (ngeom, 3),
    ``geom_xmat`` (ngeom, 3, 3)): between the two foot capsules, and the smallest between any
    left and any right lower-leg capsule."""
    p0, p1 = _axes(caps, geom_xpos, geom_xmat)
    dist = segment_distance(p0[0][:, None], p1[0][:, None], p0[1][None, :], p1[1][None, :])
    gap = dist - caps.radius[0][:, None] - caps.radius[1][None, :]          # (n, n)
    f = int(np.argmax(caps.is_foot))
    return jnp.stack([gap[f, f], jnp.min(gap)])
