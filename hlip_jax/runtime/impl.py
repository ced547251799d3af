"""Implementation profiles: how a sweep is computed, chosen for the backend, never what it
computes.

A sweep's ``[impl]`` table holds the implementation settings
(:class:`hlip_jax.simulation.config.ImplConfig`: physics, qp_loop, qp_linsys, qp_kernel, condense, terms)
and names a profile (``profile = "auto"`` when absent) that fills the ones it leaves unset:

``auto``
    ``gpu`` on a GPU backend, ``cpu`` on any other.
``cpu``
    the sweep's own settings (the ImplConfig defaults where it sets none): the Cholesky
    solve, the eigen condensation, MJX's whole-body terms, MJX-JAX physics.
``gpu``
    fills the implementation fields the sweep file does not set with the settings
    measured fastest on an H200 at thousands of robots (docs/benchmarks/cassie_gpu.md): ``qp_linsys =
    "inverse"``, ``qp_kernel = "fused"`` (where the solve is the inverse), ``condense =
    "deflated"``, ``terms = "dense"``, and ``physics = "warp"`` where ``warp-lang`` imports.  On the validation set
    these walk as the CPU settings do (138 of 148 runs with each; docs/cassie_validation).
    Refused on a backend without a GPU.
``sweep``
    the sweep's own settings on any backend.

Fields the sweep file sets itself (in ``[impl]``, or ``--physics``) always win.  The settings a profile fills are applied to the expanded configs
before the run, so the manifest's configs, the run's identity (its config hash) and every
replay hold what was computed; the manifest's ``impl`` entry records the profile, the backend
and the fields it filled.  A profile only changes the arithmetic's route: the same scenario
within the solvers' tolerances.
"""

from __future__ import annotations

import dataclasses
import importlib.util
from typing import NamedTuple, Sequence

PROFILES = ("auto", "cpu", "gpu", "sweep")

#: the GPU profile's settings
GPU = {"qp_linsys": "inverse", "qp_kernel": "fused", "condense": "deflated", "terms": "dense",
       "physics": "warp"}

#: a filled field that needs another field's value (the fused kernel runs the inverse solve)
REQUIRES = {"qp_kernel": ("qp_linsys", "inverse")}


class Resolved(NamedTuple):
    """A profile resolved for a backend: its name (``cpu``, ``gpu`` or ``sweep``), the backend
    (``jax.default_backend()``) and the fields of ImplConfig it fills {field: value}."""
    profile: str
    backend: str
    settings: dict

    def describe(self) -> str:
        filled = ", ".join(f"{k} {v}" for k, v in self.settings.items())
        return (f"implementation profile {self.profile} on the {self.backend} backend"
                + (f": {filled}" if filled else ": the sweep's own settings"))


def warp_available() -> bool:
    """Whether MJX's Warp physics can run here (``warp-lang`` imports)."""
    return importlib.util.find_spec("warp") is not None


def resolve(profile: str, backend: str, explicit: frozenset, warp: bool) -> Resolved:
    """The settings ``profile`` fills on ``backend`` given the fields the sweep sets itself
    (``explicit``) and whether Warp is installed (``warp``); ValueError naming the field for
    an unknown profile or ``gpu`` without a GPU."""
    if profile not in PROFILES:
        raise ValueError(f"impl.profile: {profile!r} is not allowed; allowed: "
                         f"{', '.join(PROFILES)}")
    gpu = backend in ("gpu", "cuda", "rocm")
    name = ("gpu" if gpu else "cpu") if profile == "auto" else profile
    if name == "gpu" and not gpu:
        raise ValueError(f"impl.profile: 'gpu' needs a GPU backend, this one is {backend!r}; "
                         "allowed here: auto, cpu, sweep")
    settings = {} if name != "gpu" else {
        k: v for k, v in GPU.items()
        if k not in explicit and (k != "physics" or warp)}
    return Resolved(name, backend, settings)


def apply(configs: Sequence, settings: dict) -> list:
    """The configs with ``settings`` ({ImplConfig field: value}) set on every Cassie scenario
    (the H-LIP plant has no implementation to choose); a field of :data:`REQUIRES` only where
    the field it needs has the value it needs (a sweep that sets the Cholesky solve keeps the
    XLA loop)."""
    out = []
    for c in configs:
        if c.plant != "cassie" or not settings:
            out.append(c)
            continue
        im = dataclasses.replace(c.impl, **{k: v for k, v in settings.items() if k not in REQUIRES})
        need = {k: v for k, v in settings.items()
                if k in REQUIRES and getattr(im, REQUIRES[k][0]) == REQUIRES[k][1]}
        out.append(dataclasses.replace(c, impl=dataclasses.replace(im, **need)))
    return out
