"""The simulated Cassie stepped by MJX's Warp implementation (``impl.physics = "warp"``).

MJX runs the same model through two implementations: MJX-JAX (``impl="jax"``, the default
here, on every backend) and MJWarp (``impl="warp"``, needs the optional ``warp-lang``
package: ``pip install 'hlip_jax[warp]'``; NVIDIA GPUs, and Warp's CPU device).  Only the
physics step changes.  The closed loop keeps its state as MJX-JAX data, because the
controller's whole-body terms (:func:`model.robot_terms`: kinematics, mass matrix, Jacobians)
are MJX-JAX functions that do not run on Warp-backed data.  A physics stage with Warp

    d_warp = warp_data(m) with d's state fields (qpos, qvel, act, ctrl, applied forces, time,
             the constraint solver's warm start, mocap)
    d_warp = step(m_warp, d_warp)   × SUBSTEPS
    d      = d with every field MJX's Data shares between the implementations from d_warp

so the next tick's controller sees the Warp step's state, kinematics and forces.  Warp
computes in float32: a float64 closed loop (the tests) hands it its state in float32 and takes
float32 results back (the physics is then float32-accurate; the controller still computes in
float64).  The per-scenario edits of the physics' model (leaf-spring damping, the realism
module's mass, COM, stiffness, friction and slope) are applied to the Warp model the same way
as to the MJX-JAX one (:func:`hlip_jax.plants.cassie.tick.scenario_model`,
:func:`hlip_jax.plants.cassie.realism.plant_model` with this module's :func:`base_model`).
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp

from hlip_jax.plants.cassie import model
from hlip_jax.plants.cassie.mjx_import import mjx

#: MJX Data fields that carry the simulation's state from one step to the next (the rest
#: are recomputed by every step)
STATE_FIELDS = ("time", "qpos", "qvel", "act", "qacc_warmstart", "ctrl", "qfrc_applied",
                "xfrc_applied", "mocap_pos", "mocap_quat")


def available() -> bool:
    """Whether MJX's Warp implementation can be used here (``warp-lang`` importable)."""
    try:
        import warp  # noqa: F401
        from mujoco.mjx import warp as _mjx_warp  # noqa: F401
    except ImportError:
        return False
    return True


def require() -> None:
    """Raise ``ValueError`` naming the field when the Warp implementation is missing."""
    if not available():
        raise ValueError("impl.physics = 'warp' needs the warp-lang package "
                         "(pip install 'hlip_jax[warp]'); allowed without it: 'jax'")


@functools.lru_cache(maxsize=None)
def base_model(mj_model):
    """The MJX model of ``mj_model`` on the Warp implementation (built once per model).  Its
    overflow warnings are off: the model caps the constraint solver at a few iterations (the
    closed chains need 4, docs), MJX-JAX runs the same cap silently, and Warp would print
    "solver iterations limit reached" into a sweep's progress output.  Built with concrete
    arrays even when first asked for inside a trace, so the cached model holds no tracer of a
    finished compile.  On this process's first device (:func:`model.put`): on process 0's
    device, every other process of a ``--distributed`` run failed to compile the closed loop."""
    with jax.ensure_compile_time_eval():     # concrete arrays, even when first asked inside a trace
        mx = model.put(mj_model, "warp")
    return mx.replace(opt=mx.opt.replace(_impl=mx.opt._impl.replace(warn_overflow=0)))


def shared_fields() -> tuple[str, ...]:
    """The fields of MJX's Data common to both implementations (everything but ``_impl``)."""
    return tuple(f.name for f in dataclasses.fields(mjx.Data) if not f.name.startswith("_"))


@functools.lru_cache(maxsize=None)
def contacts_per_robot(mj_model) -> int:
    """Warp's contact capacity for one robot (its default for a single world)."""
    return int(mjx.make_data(mj_model, impl="warp")._impl.naconmax)


def step(mj_model, mx_warp, d, n: int, robots: int = 1):
    """``n`` Warp physics steps of the MJX-JAX data ``d`` on the Warp model ``mx_warp``;
    returns ``d`` with every shared field from the Warp result (in ``d``'s dtypes).

    ``robots`` (static) is the size of the vmapped batch this call runs in: Warp keeps one
    contact buffer for all worlds of a batch (``naconmax``), so it is sized
    :func:`contacts_per_robot` × ``robots``; a buffer for one robot would silently drop the
    contacts of the others (their feet would sink through the floor)."""
    dw = mjx.make_data(mj_model, impl="warp", naconmax=contacts_per_robot(mj_model) * int(robots))
    dw = dw.replace(**{f: jnp.asarray(getattr(d, f), getattr(dw, f).dtype) for f in STATE_FIELDS})
    for _ in range(n):
        dw = mjx.step(mx_warp, dw)
    return d.replace(**{f: jnp.asarray(getattr(dw, f), getattr(d, f).dtype) for f in shared_fields()})
