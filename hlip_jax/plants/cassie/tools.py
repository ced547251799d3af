"""The Cassie plant's parts that the layers above the closed loop use, found through
:func:`hlip_jax.plants.tools` (``plants.tools("cassie")``): the per-tick log's clock and phase
codes (the replay and the videos), the scene and ground a renderer draws, the zero-torque
physics-only run that the benchmark divides by, the default gait preset and the check that a
physics implementation can run.  One name each for what the generic modules would otherwise
take from this plant's modules directly.
"""

from __future__ import annotations

import copy

import numpy as np

from hlip_jax.plants.cassie import gaits, terrain, warp_physics
#: the controller's tick [s] (1 kHz) and MJX steps per tick (2 kHz physics)
from hlip_jax.plants.cassie.control import CONTROL_DT, SUBSTEPS  # noqa: F401 (re-exported)
#: the tick log's ``phase`` codes: double support, single support, after the scenario ended
from hlip_jax.plants.cassie.tick import DONE as PHASE_DONE, DSP as PHASE_DSP, SSP as PHASE_SSP  # noqa: F401


def default_gait() -> dict:
    """The default gait preset's values (``"hlip.t_ssp"``, ``"gain.q_v"``, ...)."""
    return gaits.preset(gaits.DEFAULT)


def require_physics(physics: str) -> None:
    """ValueError naming ``impl.physics`` when implementation ``physics`` cannot run here
    (``"warp"`` without the warp-lang package); ``"jax"`` always runs."""
    if physics == "warp":
        warp_physics.require()


def scene(cfg):
    """The C MuJoCo model (``mujoco.MjModel``) of the scene scenario ``cfg`` walked on: the
    robot on the flat floor, or with the terrain block and the height field placed as its
    ground puts them (:mod:`hlip_jax.plants.cassie.terrain`).  A model of its own: the
    simulation's is not touched."""
    import mujoco

    from hlip_jax.plants.cassie import model
    r = cfg.realism
    if r.ground_kind() == "flat":
        return mujoco.MjModel.from_xml_path(str(model.SCENE_XML))
    rough = r.ground_kind() == "rough"
    m = copy.deepcopy(terrain.scene(field=rough)[0])
    g = terrain.make(r.step_height, r.step_x, r.rough_height, cfg.seed, field=rough)
    floor, block, field = terrain.geoms()
    m.geom_pos[floor, 2] = float(g.floor)
    m.geom_pos[block] = [float(g.centre_x), 0.0, float(g.top) - terrain.HALF[2]]
    if rough:
        m.geom_pos[field, 2] = float(g.rough_z)
        m.hfield_data[:] = np.asarray(g.bumps, np.float32)
    return m


def ground_height(cfg, xy: np.ndarray) -> np.ndarray:
    """Height of scenario ``cfg``'s ground at the points ``xy`` (n, 2) [m] (zeros on flat
    ground)."""
    xy = np.asarray(xy, np.float64)
    r = cfg.realism
    if r.ground_kind() == "flat" or not len(xy):
        return np.zeros(len(xy))
    ground = terrain.make(r.step_height, r.step_x, r.rough_height, cfg.seed,
                          field=r.ground_kind() == "rough")
    return np.asarray(terrain.height(ground, xy), np.float64)


def physics_only(robots: int, ticks: int, physics: str = "jax"):
    """(run, state): ``run(state)`` steps ``robots`` zero-torque Cassies over ``ticks`` control
    ticks (``ticks`` × :data:`SUBSTEPS` physics steps) with implementation ``physics``
    (``"jax"``: MJX-JAX, ``"warp"``: MJX's Warp), jitted and vmapped; ``state`` their batch of
    standing robots.  The benchmark's denominator: physics alone, no controller."""
    import jax

    from hlip_jax.plants.cassie import control, model, plant
    cassie = plant.cassie()
    mx = warp_physics.base_model(cassie.mj_model) if physics == "warp" else None
    state = model.make_batch(cassie, robots, jax.random.PRNGKey(0))
    run = jax.jit(jax.vmap(
        lambda d: control.zero_torque_rollout(cassie, d, ticks, mx, physics, robots)))
    return run, state
