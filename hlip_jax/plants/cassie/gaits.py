"""Named gait presets of the Cassie plant (pure Python: the sweep validator imports it).

A gait is everything that shapes how the simulated Cassie walks, wherever the setting lives in
a :class:`hlip_jax.simulation.config.ScenarioConfig`: the H-LIP timing and COM height the planner and the
stepping law share (``hlip.*``), the stepping gain (``gain.*``), the MPC's step-width bounds
(``mpc.step_width_*``) and the controller's own parameters (``cassie.*``).  A scenario with
``plant = "cassie"`` names its gait with ``cassie.gait``; every dotted field of that preset that
the sweep file does not set takes the preset's value, and whatever the file sets wins
(:func:`fill`).  The presets, with how each was chosen, are documented in docs/cassie_gait.md.
"""

from __future__ import annotations

#: gait name -> {dotted field: value}.  "paper": the underactuated controller of Xiong, Reher
#: & Ames (passive stance foot, no horizontal COM output), tuned on the training set of
#: docs/cassie_protocol only.
PRESETS: dict[str, dict[str, object]] = {
    "paper": {
        "hlip.z0": 0.864,
        "hlip.t_ssp": 0.175,
        "hlip.t_dsp": 0.03,
        "mpc.step_width_min": 0.1296,
        "gain.type": "lqr",
        "gain.with_position": True,
        "gain.q_c": 0.1,
        "gain.q_p": 1.0,
        "gain.q_v": 0.1766,
        "gain.r": 4.6765,
        "cassie.clearance": 0.0647,
        "cassie.strike": 0.0174,
        "cassie.reach": 0.9333,
        "cassie.early_contact": 0.8914,
        "cassie.step_width_min": 0.1,
        "cassie.step_width_max": 0.645,
        "cassie.omega_pelvis": 6.2518,
        "cassie.omega_height": 2.5235,
        "cassie.omega_swing": 17.0053,
        "cassie.omega_yaw": 7.5996,
        "cassie.weight_pelvis": 6.3141,
        "cassie.height_reference": "stance_foot",
        "cassie.qp_rho_start": "previous",
    },
}

DEFAULT = "paper"


class UnknownGait(KeyError):
    """A gait name that is not in :data:`PRESETS` (the message lists the known names)."""

    def __str__(self):
        return self.args[0]


def preset(name: str) -> dict[str, object]:
    """The preset ``name`` as {dotted field: value}; raises :class:`UnknownGait` naming the
    known presets."""
    if name not in PRESETS:
        raise UnknownGait(f"cassie.gait: unknown gait {name!r}; allowed: "
                          f"{', '.join(map(repr, PRESETS))}")
    return PRESETS[name]


def fill(raw: dict) -> dict:
    """``raw`` (a scenario's nested settings table) with every field of its gait preset that it
    does not set filled in.  The preset is the one ``cassie.gait`` names, on any plant (so a
    Cassie sweep run with ``--plant hlip`` keeps the gait's H-LIP timing, COM height, gain and
    step limits: a like-for-like comparison), or :data:`DEFAULT` for ``plant = "cassie"``;
    other tables are returned unchanged."""
    cassie = raw.get("cassie", {})
    named = isinstance(cassie, dict) and "gait" in cassie
    if raw.get("plant") != "cassie" and not named:
        return raw
    name = cassie["gait"] if named else DEFAULT
    out = {k: dict(v) if isinstance(v, dict) else v for k, v in raw.items()}
    for dotted, value in preset(name).items():
        table, key = dotted.split(".")
        sub = out.setdefault(table, {})
        if isinstance(sub, dict):
            sub.setdefault(key, value)
    return out
