"""The Cassie plant's validation of a scenario config (:func:`check`, found by
:func:`hlip_jax.plants.check` through :data:`hlip_jax.plants.CHECKS`).

Light: no MJX, MuJoCo or Warp module is imported (whether Warp is installed is looked up, not
imported: :func:`hlip_jax.plants.warp_installed`).
"""

from __future__ import annotations

from typing import Optional

from hlip_jax import plants
from hlip_jax.plants.base import changed_field, show_setting

#: disturbance fields the Cassie plant has no counterpart for (its model is the model; its legs
#: always limit its steps)
HLIP_ONLY_DISTURBANCES = ("noise_p", "z0", "t_ssp", "t_dsp", "mass", "step_limits")


def check(cfg) -> Optional[str]:
    """None, or a one-line message naming a field of ``cfg`` the Cassie plant cannot take."""
    if (ch := changed_field(cfg.disturbance, HLIP_ONLY_DISTURBANCES)) is not None:
        return (f"disturbance.{ch[0]}: {show_setting(ch[1])} acts on the H-LIP plant only; "
                f"allowed with plant = 'cassie': {show_setting(ch[2])} (Cassie takes "
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
    if cfg.impl.physics == "warp" and not plants.warp_installed():
        return ("impl.physics: 'warp' needs the warp-lang package (pip install "
                "'hlip_jax[warp]'); allowed without it: 'jax'")
    return None
