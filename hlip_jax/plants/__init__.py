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

A plant validates the scenario configs it is given in its own ``check(cfg)``, found through
:data:`CHECKS` (:func:`check`).
"""

from __future__ import annotations

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

#: each registered plant's validation of a scenario config: name -> module that defines
#: ``check(cfg)`` (None, or a one-line message naming a field the plant cannot take), imported
#: on first :func:`check`; a light module (the Cassie plant's is not its MJX plant module)
CHECKS = {"hlip": "hlip_jax.plants.hlip_plant", "cassie": "hlip_jax.plants.cassie.checks"}


#: the scenario tables a plant owns: table -> (module, its config class); the scenario config
#: (:class:`hlip_jax.simulation.config.ScenarioConfig`) holds one of each, found here
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


#: a plant's parts for the layers above the closed loop (the per-tick log's clock and phases,
#: the scene and ground a renderer draws, the physics-only benchmark, the default gait, the
#: physics check): name -> module, imported on first :func:`tools`.  A plant without one has
#: no per-tick log and nothing to draw (the exact H-LIP plant).
TOOLS = {"cassie": "hlip_jax.plants.cassie.tools"}


def tools(name: str):
    """The tools module of plant ``name`` (:data:`TOOLS`); ValueError naming the plants that
    have one for any other."""
    if name not in TOOLS:
        raise ValueError(f"plant {name!r} has no per-tick log, scene or physics benchmark; "
                         f"plants with them: {', '.join(repr(n) for n in TOOLS)}")
    return importlib.import_module(TOOLS[name])


def load(name: str) -> Plant:
    """The registered plant ``name``; ValueError listing the names for any other."""
    if name not in REGISTRY:
        raise ValueError(f"plant: {name!r} is not a registered plant; registered: "
                         f"{', '.join(repr(n) for n in NAMES)}")
    return importlib.import_module(REGISTRY[name]).PLANT


def check(cfg) -> Optional[str]:
    """The plant's own validation of a scenario config, the ``check(cfg)`` of its
    :data:`CHECKS` module: None, or a one-line message naming a field the plant cannot take.
    Light: the plant's MJX modules are not imported."""
    module = CHECKS.get(cfg.plant)
    return None if module is None else importlib.import_module(module).check(cfg)


def warp_installed() -> bool:
    """Whether the warp-lang package is installed (found, not imported: validation stays light)."""
    return importlib.util.find_spec("warp") is not None

