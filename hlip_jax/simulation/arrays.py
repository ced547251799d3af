"""Configs to arrays: every scenario of a batch as per-scenario data (:class:`Scenario`, leading
axis = scenarios) and the settings one compiled program shares (:class:`Static`).

Each :class:`hlip_jax.simulation.config.ScenarioConfig` becomes its H-LIP S2S model and stepping gain, its
MPC's parameters (obstacles padded to the batch's count, the tube's tightening), its path
sampled in time, its initial state and PRNG key, and its plant's parameters; :func:`build`
stacks them, and :func:`shapes_of` fixes the array sizes a whole sweep shares, so its chunks
reuse one compile.  Pure numpy on the host; the closed loop (:mod:`hlip_jax.simulation.rollout`) and its
execution over devices (:mod:`hlip_jax.simulation.execution`) take it from here.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import NamedTuple, Optional, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from hlip_jax.core import hlip, mpc, paths, qp, robust, s2s_model
from hlip_jax.simulation.config import (GROUND_KINDS, STATIC_FIELDS, RealismConfig, ScenarioConfig,
                             field_value)
from hlip_jax import plants

#: mpc.mode -> which of the nominal's [c, p, v] restart from the robot's state before every plan
#: (the log's ``anchor``; the error system it gives: :func:`hlip_jax.core.invariant.closed_loop`)
ANCHOR = {"tube": np.zeros(3, np.float32), "measured": np.ones(3, np.float32),
          "position": np.array([1.0, 0.0, 0.0], np.float32)}


class Scenario(NamedTuple):
    """Batched per-scenario data (leading axis = scenarios)."""
    mpc: mpc.MPCParams
    path: paths.Path
    gain: jax.Array       # (2, 3)
    z0: jax.Array
    t_ssp: jax.Array
    t_dsp: jax.Array
    x0: jax.Array         # (2, 3) initial state (robot and H-LIP)
    n_steps: jax.Array    # steps to simulate (≤ the static K)
    anchor: jax.Array     # (3,) 1 where the nominal [c, p, v] restarts from the robot's each step
    plant: object         # the plant's params pytree
    key: jax.Array


class Static(NamedTuple):
    """Shapes and solver settings: one compile per distinct value."""
    n_steps: int
    horizon: int
    settings: qp.Settings
    plant: str
    viability: bool = False                        # the MPC's viability rows (mpc.viability)
    plant_settings: Optional[object] = None   # the plant's static settings (Cassie: tick.Settings)
    keep_ticks: bool = False                       # also return the plant's per-tick log
    progress: bool = False                         # report each finished step (progress.py)


# ----------------------------------------------------------------------------------------------
# configs → arrays

def stepping_gain(cfg: ScenarioConfig) -> np.ndarray:
    """K (2, 3) per plane on [c, p, v]; the c entry is zero for a 2-state gain.  Designed on
    the scenario's S2S map (:func:`s2s_of`)."""
    return _cached_gain(cfg.hlip, cfg.gain, cfg.s2s).copy()


def s2s_of(cfg: ScenarioConfig) -> tuple[np.ndarray, np.ndarray]:
    """(A (3, 3), B (3,)) on [c, p, v] of the scenario's S2S map: the H-LIP's, or the
    identified model of ``s2s.file`` lifted (:func:`hlip_jax.core.s2s_model.lifted`)."""
    if cfg.s2s.model == "identified":
        return _cached_identified(cfg.s2s.file)
    return _cached_s2s(cfg.hlip)


@functools.lru_cache(maxsize=64)
def _cached_identified(path: str) -> tuple[np.ndarray, np.ndarray]:
    return s2s_model.lifted(s2s_model.read(path))


def _stepping_gain(h, g, s) -> np.ndarray:
    plane_gain = (_plane_gain if s.model == "hlip" else
                  functools.partial(_model_gain, *_cached_identified(s.file)))
    K = plane_gain(h, g)
    if g.lateral == "deadbeat" and g.type != "deadbeat":
        K[1] = plane_gain(h, dataclasses.replace(g, type="deadbeat"))[1]
    return K


def _model_gain(A3, B3, h, g) -> np.ndarray:
    """The gain of design ``g`` on an identified map (A3, B3): deadbeat by Ackermann's
    placement (every eigenvalue of A + BK at zero), LQR by the Riccati equation; on [p, v]
    alone without ``g.with_position``."""
    A, B = (A3, B3) if g.with_position else (A3[1:, 1:], B3[1:])
    if g.type == "deadbeat":
        k = hlip.place_gain_ackermann(jnp.asarray(A), jnp.asarray(B))
    else:
        q = [g.q_c, g.q_p, g.q_v] if g.with_position else [g.q_p, g.q_v]
        k = hlip.lqr_gain(A, B, jnp.diag(jnp.array(q)), jnp.array(g.r))
    k = np.asarray(k, np.float64)
    return np.tile(k if g.with_position else np.concatenate([[0.0], k]), (2, 1))


def _plane_gain(h, g) -> np.ndarray:
    if g.with_position:
        if g.type == "deadbeat":
            k = hlip.deadbeat_gain(h.z0, h.t_ssp, h.t_dsp, h.g, with_position=True)
        else:
            A, B = hlip.s2s_matrices(h.z0, h.t_ssp, h.t_dsp, h.g, with_position=True)
            k = hlip.lqr_gain(A, B, jnp.diag(jnp.array([g.q_c, g.q_p, g.q_v])), jnp.array(g.r))
        k = np.asarray(k, np.float64)
    else:
        if g.type == "deadbeat":
            k = hlip.deadbeat_gain(h.z0, h.t_ssp, h.t_dsp, h.g)
        else:
            A, B = hlip.s2s_matrices(h.z0, h.t_ssp, h.t_dsp, h.g, with_position=False)
            k = hlip.lqr_gain(A, B, jnp.diag(jnp.array([g.q_p, g.q_v])), jnp.array(g.r))
        k = np.concatenate([[0.0], np.asarray(k, np.float64)])
    return np.tile(k, (2, 1))


def tube_of(cfg: ScenarioConfig, A, B) -> robust.Tightening:
    """The MPC's tube tightening (:mod:`hlip_jax.core.robust`): none unless ``mpc.robust``."""
    m = cfg.mpc
    if not m.robust:
        return robust.NONE
    w = np.array([[m.w_c_1, m.w_p_1, m.w_v_1], [m.w_c_2, m.w_p_2, m.w_v_2]])
    hull = robust.read_hull(m.w_hull_file) if m.w_shape == "hull" else None
    return robust.tightening(A, B, stepping_gain(cfg), w, m.w_frame, hull)


def n_steps_of(cfg: ScenarioConfig) -> int:
    return int(math.ceil(cfg.duration / (cfg.hlip.t_ssp + cfg.hlip.t_dsp) - 1e-9))


def _freeze(v):
    if isinstance(v, dict):
        return tuple(sorted((k, _freeze(x)) for k, x in v.items()))
    if isinstance(v, (list, tuple)):
        return tuple(_freeze(x) for x in v)
    return v


@functools.lru_cache(maxsize=4096)
def _cached_path(shape: str, frozen: tuple) -> paths.Path:
    params = {k: (list(map(list, v)) if isinstance(v, tuple) else v) for k, v in frozen}
    return jax.tree.map(np.asarray, paths.make_path(shape, **params))


def _path_of(cfg: ScenarioConfig, t_final: float, n_samples: int) -> paths.Path:
    """The path table of a scenario (memoised: a sweep repeats the same paths many times).
    The table length and time span are set by the batch so every path has the same shape."""
    params = dict(cfg.path.params)
    params["t_final"] = t_final
    params["n_samples"] = n_samples
    return _cached_path(cfg.path.shape, _freeze(params))


@functools.lru_cache(maxsize=4096)
def _cached_s2s(h) -> tuple[np.ndarray, np.ndarray]:
    A, B = hlip.s2s_matrices(h.z0, h.t_ssp, h.t_dsp, h.g)
    return np.asarray(A, np.float64), np.asarray(B, np.float64)


@functools.lru_cache(maxsize=4096)
def _cached_gain(hlip_cfg, gain_cfg, s2s_cfg) -> np.ndarray:
    return _stepping_gain(hlip_cfg, gain_cfg, s2s_cfg)


def default_dtype():
    """float64 where JAX has x64 enabled (CPU runs, tests), else float32 (GPU)."""
    return jnp.float64 if jax.config.jax_enable_x64 else jnp.float32


class Shapes(NamedTuple):
    """Array sizes of a batch.  Chunks of one sweep built with the sweep-wide ``shapes_of``
    share one compile."""
    n_steps: int
    n_obstacles: int
    n_pushes: int
    t_final: float
    t_step: float = 0.0      # longest step span [s] (Plant.step_span; the Cassie tick budget)
    non_ideal: bool = False  # a scenario departs from the ideal robot (``realism``): every
                             # robot of the batch carries the realism data (compiled in)
    terrain: str = "flat"    # the batch's ground: "rough" if a scenario has rough ground
                             # (``realism.rough_height``), else "step" if one has a step
                             # (``realism.step_height``), else "flat"; every robot of the batch
                             # walks on that scene (:mod:`hlip_jax.plants.cassie.terrain`)


def shapes_of(configs: Sequence[ScenarioConfig]) -> Shapes:
    """The smallest shapes that fit every scenario of ``configs``."""
    K = max(n_steps_of(c) for c in configs)
    horizon = max(c.mpc.horizon for c in configs)
    return Shapes(
        n_steps=K,
        n_obstacles=max((len(c.obstacles) for c in configs), default=0),
        n_pushes=max(1, max(len(c.disturbance.pushes) for c in configs)),
        t_final=max((K + horizon + 2) * (c.hlip.t_ssp + c.hlip.t_dsp) for c in configs),
        t_step=max(_step_span(c) for c in configs),
        non_ideal=any(c.realism != RealismConfig() for c in configs),
        terrain=max((c.realism.ground_kind() for c in configs), key=GROUND_KINDS.index,
                    default="flat"))


def _step_span(c: ScenarioConfig) -> float:
    """Longest step of one scenario [s], as its plant counts it (:attr:`plants.Plant.step_span`)."""
    return plants.load(c.plant).step_span(c)


def build(configs: Sequence[ScenarioConfig], *, n_samples: int = 2048, dtype=None,
          shapes: Shapes | None = None):
    """Validated configs → (Scenario batch, Static).  The horizon, the QP settings and the
    plant must agree across the batch (they are shapes / static settings).  ``shapes``
    (default: :func:`shapes_of` the batch) must fit every scenario."""
    if not configs:
        raise ValueError("build: no scenarios")
    first = configs[0]
    for c in configs:
        for name in STATIC_FIELDS:
            a, b = field_value(c, name), field_value(first, name)
            if a != b:
                raise ValueError(f"{name} must be the same for every scenario of a batch "
                                 f"(it fixes shapes/compiled settings): got {a!r} and {b!r}")
    need = shapes_of(configs)
    shapes = shapes or need
    for f in Shapes._fields:
        if getattr(shapes, f) < getattr(need, f):
            raise ValueError(f"shapes.{f} = {getattr(shapes, f)} is smaller than the batch needs "
                             f"({getattr(need, f)})")
    K, t_final = shapes.n_steps, shapes.t_final
    n_obs, n_push = shapes.n_obstacles, shapes.n_pushes
    horizon = first.mpc.horizon

    rows = []
    for c in configs:
        A, B = s2s_of(c)
        obs = np.zeros((n_obs, 4))
        act = np.zeros(n_obs, bool)
        for i, o in enumerate(c.obstacles):
            obs[i] = (o.x, o.y, o.radius + o.margin, o.radius)
            act[i] = True
        m = c.mpc
        mp = mpc.MPCParams(A=np.asarray(A), B=np.asarray(B), w_pos=m.w_pos, w_vel=m.w_vel,
                           alpha=m.alpha, length_min=m.step_length_min,
                           length_max=m.step_length_max, width_min=m.step_width_min,
                           width_max=m.step_width_max, obstacle_weight=m.obstacle_weight,
                           obstacles=obs, obstacle_active=act, **tube_of(c, A, B)._asdict())
        path = _path_of(c, t_final, n_samples)
        start = np.array([float(path.x[0]), float(path.y[0])])
        x0 = np.stack([np.array([start[0], 0.0, 0.0]), np.array([start[1], 0.0, 0.0])])
        plant = plants.load(c.plant).make_params(c, n_push, shapes.t_step, shapes.non_ideal,
                                                 shapes.terrain)
        rows.append(Scenario(mpc=mp, path=path, gain=stepping_gain(c), z0=c.hlip.z0,
                             t_ssp=c.hlip.t_ssp, t_dsp=c.hlip.t_dsp, x0=x0,
                             n_steps=np.int32(n_steps_of(c)), anchor=ANCHOR[m.mode],
                             plant=plant, key=None))
    batch = jax.tree.map(lambda *a: np.stack([np.asarray(x) for x in a]), *rows)
    batch = batch._replace(key=_keys([c.seed for c in configs]))

    dtype = dtype or default_dtype()

    def cast(x):
        x = np.asarray(x)
        return x.astype(dtype) if np.issubdtype(x.dtype, np.floating) else x

    batch = jax.tree.map(cast, batch)
    settings = qp.Settings(eps_abs=first.mpc.qp_eps, eps_rel=first.mpc.qp_eps,
                           max_iter=first.mpc.qp_max_iter, check_interval=25,
                           adaptive_rho_interval=50)
    plant_settings = plants.load(first.plant).settings(first, len(configs))
    return batch, Static(n_steps=K, horizon=horizon, settings=settings, plant=first.plant,
                         viability=first.mpc.viability,
                         plant_settings=plant_settings)


def _keys(seeds: Sequence[int]) -> np.ndarray:
    """Every scenario's PRNG key data, ``jax.random.PRNGKey(seed)`` of each seed, in one call
    (one call per scenario took a quarter of building 2048 Cassie scenarios)."""
    return np.asarray(jax.random.key_data(jax.vmap(jax.random.PRNGKey)(np.asarray(seeds, np.int64))))
