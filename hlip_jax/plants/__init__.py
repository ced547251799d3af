"""What executes the planned steps: the plant registry.

A plant is a :class:`Plant` record of pure functions (the step-level interface of
:mod:`hlip_jax.plants.base`) plus what the closed loop and the sweep validator need to know
about it.  :func:`load` returns a registered plant by name; its error lists the names.  The
records import their modules on first use, so that naming or validating a plant costs nothing
(the Cassie plant pulls in MuJoCo XLA).

    plant = plants.load("cassie")
    params = plant.make_params(cfg, n_push, t_step, non_ideal, terrain)
    state = plant.init(params, x0, u0, stance0, key, heading0)
    x_r0 = plant.measure(params, state, stance0)             # the robot's S2S state at t = 0
    state, result = plant.step(params, state, cmd)           # + plant.settings(cfg) if any
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.util
from typing import Callable, NamedTuple, Optional


class Plant(NamedTuple):
    """A plant's functions (all pure; ``init``/``step`` jit- and vmap-able).

    name: the registry name (``plant = "..."`` in a sweep file).
    make_params: (cfg, n_push, t_step, non_ideal, terrain) -> per-scenario params pytree;
      ``t_step`` is the sweep's longest :attr:`step_span`, ``non_ideal`` whether any scenario
      of the sweep departs from the ideal robot (``cfg.realism``) and ``terrain`` the sweep's
      ground ("flat", "step": a scenario has a step, "rough": one has rough ground), so that
      every chunk has one shape and one program.
    init: (params, x0 (2, 3), u0 (2,), stance0, key, heading0) -> state.
    measure: (params, state, stance) -> the robot's S2S state [c, p, v] per world plane (2, 3)
      as the plant's state holds it (the closed loop's x_R,0 at the start).
    step: (params, state, cmd[, settings]) -> (state, StepResult).
    step_with_log: like ``step`` and also the per-tick log, or None (no ticks to log).
    step_span: cfg -> longest walking step of the scenario [s] (static sizes).
    settings: (cfg, robots) -> the plant's static solver settings for a batch of ``robots``
      scenarios (one compile per value), or None.
    """
    name: str
    make_params: Callable
    init: Callable
    measure: Callable
    step: Callable
    step_with_log: Optional[Callable]
    step_span: Callable
    settings: Callable


#: registered plants: name -> module that defines ``PLANT`` (imported on first :func:`load`)
REGISTRY = {"hlip": "hlip_jax.plants.hlip_plant", "cassie": "hlip_jax.plants.cassie.plant"}

#: names a sweep file may give (the config validator's choices)
NAMES = tuple(REGISTRY)


#: the scenario tables a plant owns: table -> (module, its config class); the scenario config
#: (:class:`hlip_jax.config.ScenarioConfig`) holds one of each, found here
SETTINGS = {"cassie": ("hlip_jax.plants.cassie.config", "CassieConfig"),
            "realism": ("hlip_jax.plants.cassie.config", "RealismConfig")}


def settings_class(table: str) -> type:
    """The config class of a plant-owned scenario table (:data:`SETTINGS`); ValueError listing
    the tables for any other.  Its module is light (dataclasses and the gait presets)."""
    if table not in SETTINGS:
        raise ValueError(f"settings table {table!r} is not a plant's; known: "
                         f"{', '.join(repr(t) for t in SETTINGS)}")
    module, cls = SETTINGS[table]
    return getattr(importlib.import_module(module), cls)


#: modules whose ``fill(raw)`` fills a scenario table's unset fields from the preset it names
#: (the Cassie gaits: :func:`hlip_jax.plants.cassie.gaits.fill`), applied in this order
PRESET_FILLERS = ("hlip_jax.plants.cassie.gaits",)


def with_presets(raw: dict) -> dict:
    """The scenario table ``raw`` (a sweep file's nested settings) with every registered
    preset's fields that it does not set filled in; ValueError with a one-line message naming
    the field for a preset that does not exist."""
    for module in PRESET_FILLERS:
        m = importlib.import_module(module)
        try:
            raw = m.fill(raw)
        except KeyError as err:          # an unknown preset: its message lists the known ones
            raise ValueError(str(err)) from None
    return raw


def load(name: str) -> Plant:
    """The registered plant ``name``; ValueError listing the names for any other."""
    if name not in REGISTRY:
        raise ValueError(f"plant: {name!r} is not a registered plant; registered: "
                         f"{', '.join(repr(n) for n in NAMES)}")
    return importlib.import_module(REGISTRY[name]).PLANT


def _changed(table, names=None) -> Optional[tuple]:
    """(field, value, default) of the first field of the config table ``table`` (of ``names``,
    default all) whose value is not its class's default; None when all are (no import of the
    config layer: the defaults come from the table's own class)."""
    default = type(table)()
    for name in names if names is not None else (f.name for f in dataclasses.fields(table)):
        if getattr(table, name) != getattr(default, name):
            return name, getattr(table, name), getattr(default, name)
    return None


def check(cfg) -> Optional[str]:
    """The plant's own validation of a scenario config: None, or a one-line message naming a
    field the plant cannot take.  Light: no plant module is imported."""
    if cfg.plant == "hlip":
        if (ch := _changed(cfg.realism)) is not None:
            return (f"realism.{ch[0]}: {ch[1]!r} models the Cassie robot; "
                    f"allowed with plant = 'hlip': {ch[2]!r}")
        if (ch := _changed(cfg.impl)) is not None:
            return (f"impl.{ch[0]}: {ch[1]!r} chooses how the Cassie robot is computed; "
                    f"allowed with plant = 'hlip': {ch[2]!r}")
    if cfg.plant == "cassie":
        if (ch := _changed(cfg.disturbance, HLIP_ONLY_DISTURBANCES)) is not None:
            return (f"disturbance.{ch[0]}: {_show(ch[1])} acts on the H-LIP plant only; "
                    f"allowed with plant = 'cassie': {_show(ch[2])} (Cassie takes "
                    "disturbance.noise_v, disturbance.step_error and disturbance.pushes)")
        for f in ("step_height", "rough_height"):
            if cfg.impl.physics == "warp" and getattr(cfg.realism, f) != 0.0:
                return (f"realism.{f}: {getattr(cfg.realism, f):g} needs the MJX-JAX physics "
                        "(the Warp physics has no terrain); allowed with impl.physics = "
                        "'warp': 0")
        if cfg.impl.qp_kernel == "fused" and cfg.impl.qp_linsys != "inverse":
            return (f"impl.qp_kernel: 'fused' with impl.qp_linsys = {cfg.impl.qp_linsys!r}; "
                    "allowed: 'xla', or 'fused' with qp_linsys = 'inverse' (the kernel "
                    "multiplies by the inverse)")
        if cfg.realism.step_height != 0.0 and cfg.realism.rough_height != 0.0:
            return ("realism.rough_height: a scenario has a step (realism.step_height) or rough "
                    "ground, not both; allowed with step_height != 0: 0")
        if cfg.impl.physics == "warp" and not warp_installed():
            return ("impl.physics: 'warp' needs the warp-lang package (pip install "
                    "'hlip_jax[warp]'); allowed without it: 'jax'")
    return None


def warp_installed() -> bool:
    """Whether the warp-lang package is installed (found, not imported: validation stays light)."""
    return importlib.util.find_spec("warp") is not None


#: disturbance fields the Cassie plant has no counterpart for (its model is the model; its legs
#: always limit its steps)
HLIP_ONLY_DISTURBANCES = ("noise_p", "z0", "t_ssp", "t_dsp", "mass", "step_limits")


def _show(v) -> str:
    """A config value as a sweep file writes it (true/false for booleans)."""
    return str(v).lower() if isinstance(v, bool) else f"{v:g}"
