"""What the frames show besides the robot: the path, the footsteps and the keep-out discs.

Every marker is a flat shape a millimetre thick lying on the ground, added to the renderer's
scene (``mjvScene``) with ``mjv_initGeom`` while it is shown:

* the path: small grey squares every :data:`PATH_SPACING` m along the scenario's reference
  path (:func:`hlip_jax.core.paths.make_path` of its shape and parameters, over its duration);
* the H-LIP's planned footsteps (translucent yellow footprints): step j lands at c_H − p_H + u_H
  of the step log's row j (the nominal's COM, its COM relative to the stance foot and its
  step, per plane, :mod:`hlip_jax.core.steplog`), shown from SSP⁻_{j−1}, when the MPC plans it,
  until :data:`PLAN_KEEP` s after the robot's foot landed;
* the robot's placed footsteps (blue left, orange right footprints): step j's swing foot lands
  at c_R − p_R + u_R of row j at SSP⁻_j (step 0, the robot standing up, has none);
* each obstacle's keep-out disc of its ``radius`` (red) and, fainter, the disc of radius +
  ``margin`` that the MPC keeps the H-LIP's COM out of.

Footprints point along the path's heading at the step (the step log's ``ref_heading``); they
are boxes, and the path's dots too: a software rasteriser draws a box several times faster
than MuJoCo's many-sided cylinder, which only the few discs use.  On uneven ground (a step or
rough ground, :mod:`hlip_jax.plants.cassie.terrain`) the markers lie on the ground's surface.
"""

from __future__ import annotations

from typing import NamedTuple

import mujoco
import numpy as np

from hlip_jax import plants

BOX, DISC = int(mujoco.mjtGeom.mjGEOM_BOX), int(mujoco.mjtGeom.mjGEOM_CYLINDER)
#: spacing of the path's dots [m]; their half-width [m]
PATH_SPACING, PATH_DOT = 0.1, 0.012
#: half-length and half-width of the planned and the placed footprints [m]
PLANNED_SIZE, PLACED_SIZE = (0.11, 0.05), (0.085, 0.032)
#: how long a planned footprint stays after the robot's foot landed [s]
PLAN_KEEP = 1.0
#: colours (RGBA)
PATH_RGBA = (0.85, 0.85, 0.85, 1.0)
PLANNED_RGBA = (1.0, 0.85, 0.1, 0.5)
FOOT_RGBA = ((0.2, 0.5, 0.95, 1.0), (0.95, 0.5, 0.1, 1.0))     # left, right
KEEPOUT_RGBA, MARGIN_RGBA = (0.85, 0.1, 0.1, 0.75), (0.85, 0.1, 0.1, 0.2)
#: half-thickness of a marker [m]; each kind of marker lies this much higher than the one below
HALF_THICKNESS, LAYER = 0.0005, 0.0012


class Markers(NamedTuple):
    """Ground markers, one row each."""
    kind: np.ndarray    # (n,) MuJoCo geom type: BOX or DISC (a cylinder)
    pos: np.ndarray     # (n, 3) centre [m]
    size: np.ndarray    # (n, 2) half-length and half-width of a box, radius (twice) of a disc [m]
    yaw: np.ndarray     # (n,) about the vertical [rad]
    rgba: np.ndarray    # (n, 4)
    shown: np.ndarray   # (n,) plant time from which it is drawn [s] (−inf: from the start)
    hidden: np.ndarray  # (n,) plant time from which it is no longer drawn [s] (inf: never)


def _rows(kind: int, xy, size, rgba, layer: int, shown=-np.inf, hidden=np.inf,
          yaw=0.0) -> Markers:
    """Markers of ``kind`` at ``xy`` (n, 2) on flat ground, ``layer`` layers above it."""
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    n = len(xy)
    full = lambda v, shape: np.broadcast_to(np.asarray(v, np.float64), shape).copy()  # noqa: E731
    return Markers(kind=np.full(n, kind), pos=np.hstack([xy, np.full((n, 1), HALF_THICKNESS
                                                                     + layer * LAYER)]),
                   size=full(size, (n, 2)), yaw=full(yaw, (n,)), rgba=full(rgba, (n, 4)),
                   shown=full(shown, (n,)), hidden=full(hidden, (n,)))


def path_points(cfg, spacing: float = PATH_SPACING) -> np.ndarray:
    """(n, 2) points [m] every ``spacing`` m of arc length along the reference path of
    scenario ``cfg`` (:class:`hlip_jax.simulation.config.ScenarioConfig`) over its duration."""
    from hlip_jax.core import paths
    params = dict(cfg.path.params, t_final=float(cfg.duration), n_samples=4096)
    p = paths.make_path(cfg.path.shape, **params)
    xy = np.stack([np.asarray(p.x, np.float64), np.asarray(p.y, np.float64)], axis=1)
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))]
    at = np.arange(0.0, s[-1] + 1e-9, spacing)
    return np.stack([np.interp(at, s, xy[:, 0]), np.interp(at, s, xy[:, 1])], axis=1)


def footsteps(step_log: dict) -> tuple[Markers, Markers]:
    """(the H-LIP's planned footsteps, the robot's placed ones) of a step log (module doc)."""
    valid = np.asarray(step_log["valid"], bool)
    t = np.asarray(step_log["t_plant"], np.float64)
    foot = 1 - np.asarray(step_log["stance"], int)
    heading = np.asarray(step_log["ref_heading"], np.float64)
    xh, xr = np.asarray(step_log["x_hlip"], float), np.asarray(step_log["x_robot"], float)
    planned = xh[:, :, 0] - xh[:, :, 1] + np.asarray(step_log["u_hlip"], float)
    placed = xr[:, :, 0] - xr[:, :, 1] + np.asarray(step_log["u_robot"], float)
    j = np.flatnonzero(valid)
    plan = _rows(BOX, planned[j], PLANNED_SIZE, PLANNED_RGBA, 1, shown=t[np.maximum(j - 1, 0)],
                 hidden=t[j] + PLAN_KEEP, yaw=heading[j])
    j = j[j >= 1]
    put = _rows(BOX, placed[j], PLACED_SIZE, (0, 0, 0, 1), 2, shown=t[j], yaw=heading[j])
    put.rgba[:] = np.asarray(FOOT_RGBA)[foot[j]]
    return plan, put


def keepout_discs(cfg) -> Markers:
    """Each obstacle's keep-out disc and its planning-margin disc (module doc)."""
    rows = [(o.x, o.y, o.radius + o.margin, MARGIN_RGBA, 3) for o in cfg.obstacles]
    rows += [(o.x, o.y, o.radius, KEEPOUT_RGBA, 4) for o in cfg.obstacles]
    return concat(_rows(DISC, [[x, y]], r, rgba, layer) for x, y, r, rgba, layer in rows)


def concat(parts) -> Markers:
    """One :class:`Markers` of several."""
    parts = list(parts) or [_rows(BOX, np.zeros((0, 2)), 0.0, (0, 0, 0, 0), 0)]
    return Markers(*(np.concatenate([getattr(p, f) for p in parts]) for f in Markers._fields))


def on_ground(mk: Markers, cfg) -> Markers:
    """``mk`` lifted onto scenario ``cfg``'s ground (unchanged on flat ground)."""
    if cfg.realism.ground_kind() == "flat" or not len(mk.pos):
        return mk
    z = plants.tools(cfg.plant).ground_height(cfg, mk.pos[:, :2])
    return mk._replace(pos=mk.pos + np.c_[np.zeros((len(z), 2)), z])


def scenario_markers(cfg, step_log: dict) -> Markers:
    """Every marker of one replayed scenario: path, planned and placed footsteps, keep-out
    discs, on its ground."""
    path = _rows(BOX, path_points(cfg), PATH_DOT, PATH_RGBA, 0)
    planned, placed = footsteps(step_log)
    return on_ground(concat([path, planned, placed, keepout_discs(cfg)]), cfg)


def shown_at(mk: Markers, t: float, centre, reach: float) -> np.ndarray:
    """Indices of the markers shown at plant time ``t`` [s] within ``reach`` [m]
    (horizontally, to their edge) of ``centre`` (x, y)."""
    far = np.linalg.norm(mk.pos[:, :2] - np.asarray(centre)[:2], axis=1) - mk.size.max(axis=1)
    return np.flatnonzero((mk.shown <= t) & (t < mk.hidden) & (far <= reach))


def add_to_scene(scene: mujoco.MjvScene, mk: Markers, t: float, centre, reach: float) -> int:
    """Add the markers :func:`shown_at` ``t`` to ``scene``, as many as it has room for;
    returns how many."""
    idx = shown_at(mk, t, centre, reach)[:max(scene.maxgeom - scene.ngeom, 0)]
    c, s = np.cos(mk.yaw), np.sin(mk.yaw)
    for i in idx:
        size = np.r_[mk.size[i], HALF_THICKNESS] if mk.kind[i] == BOX else \
            np.r_[mk.size[i, 0], HALF_THICKNESS, 0.0]
        mat = np.array([c[i], -s[i], 0.0, s[i], c[i], 0.0, 0.0, 0.0, 1.0])
        mujoco.mjv_initGeom(scene.geoms[scene.ngeom], int(mk.kind[i]), size, mk.pos[i], mat,
                            mk.rgba[i].astype(np.float32))
        scene.ngeom += 1
    return len(idx)
