"""The Cassie plant's own settings tables: the controller and gait (:class:`CassieConfig`,
a scenario's ``cassie.*``) and how far the simulated robot is from the ideal plant
(:class:`RealismConfig`, ``realism.*``).  The scenario config (:mod:`hlip_jax.simulation.config`) finds
them through the plant registry (:func:`hlip_jax.plants.settings_class`)."""

from __future__ import annotations

from dataclasses import dataclass

from hlip_jax.core.fields import spec
from hlip_jax.plants.cassie import gaits

#: the default gait's values, the defaults of the fields below
PAPER = {k.split(".", 1)[1]: v for k, v in gaits.preset(gaits.DEFAULT).items()
         if k.startswith("cassie.")}


@dataclass(frozen=True)
class CassieConfig:
    """Gait and controller parameters of the Cassie plant (ignored by the H-LIP plant).

    ``gait`` names a preset of :mod:`hlip_jax.plants.cassie.gaits` that fills every gait field
    the sweep file leaves unset (here and in ``hlip``, ``gain``, ``mpc``); the defaults below are
    the "paper" preset's (read from it: the values are written once, in the preset).  All numeric fields are per-scenario data: a sweep over them shares one
    compiled program.  Output frequencies ω set the PD/CLF gains k_p = ω², k_d = 2ω of
    :mod:`hlip_jax.plants.cassie.clfqp`."""
    gait: str = spec(gaits.DEFAULT, doc="gait preset whose values fill the unset gait fields",
                     choices=tuple(gaits.PRESETS))
    clearance: float = spec(PAPER["clearance"], 0.0, 0.3, "swing-foot apex height", "m")
    strike: float = spec(PAPER["strike"], 0.0, 0.1, "swing target depth below the ground at the end of the swing profile", "m")
    reach: float = spec(PAPER["reach"], 0.3, 1.0, "fraction of the swing profile's duration (T_SSP / s*: "
                        "it lands at T_SSP) at which the swing foot reaches its target")
    freeze: float = spec(1.0, 0.3, 1.0, "fraction of SSP after which the step target is held")
    early_contact: float = spec(PAPER["early_contact"], 0.3, 1.0, "fraction of SSP after which a detected swing-foot "
                                "touchdown ends the SSP")
    step_length_max: float = spec(0.6, 0.1, 1.0, "|step length| clip of the swing target, along the heading", "m")
    step_width_min: float = spec(PAPER["step_width_min"], 0.0, 0.5, "minimum |step width| of the swing target, across the heading", "m")
    step_width_max: float = spec(PAPER["step_width_max"], 0.1, 1.0, "maximum |step width| of the swing target", "m")
    omega_pelvis: float = spec(PAPER["omega_pelvis"], 0.5, 50.0, "pelvis orientation output frequency", "rad/s")
    omega_height: float = spec(PAPER["omega_height"], 0.5, 50.0, "COM height output frequency", "rad/s")
    omega_swing: float = spec(PAPER["omega_swing"], 0.5, 80.0, "swing-foot position and slope output frequency", "rad/s")
    omega_yaw: float = spec(PAPER["omega_yaw"], 0.5, 50.0, "swing-foot yaw output frequency", "rad/s")
    weight_pelvis: float = spec(PAPER["weight_pelvis"], 0.0, 10.0, "QP tracking weight of the pelvis orientation outputs")
    w_chatter: float = spec(0.0, 0.0, 100.0, "CLF-QP weight on the torque change from the previous "
                            "tick, ½ w ‖τ − τ_prev‖² (Xiong's Cassie controller has such a term; 0: none)",
                            "1/(N m)²")
    shin_damping: float = spec(0.1, 0.0, 100.0, "viscous damping of the simulated shin leaf springs "
                               "(Agility's Cassie model: 0.1)", "N m s/rad")
    heel_damping: float = spec(0.0, 0.0, 100.0, "viscous damping of the simulated heel leaf springs "
                               "(Agility's Cassie model: none)", "N m s/rad")
    qp_max_iter: int = spec(150, 25, 5000, "ADMM iteration budget of the CLF-QP per control tick "
                            "(static: one compile per value, equal across a batch)")
    qp_eps: float = spec(1e-4, 1e-8, 1e-1, "ADMM absolute and relative tolerance of the CLF-QP (static)")
    qp_rho_start: str = spec(PAPER["qp_rho_start"], doc="the ADMM step size rho each tick's CLF-QP starts from: "
                             "the previous tick's final rho ('previous', as OSQP keeps rho between "
                             "warm-started solves; about 40 % fewer iterations per tick, "
                             "docs/cassie_validation) or the solver's default 0.1 ('default', "
                             "the earlier behaviour)", choices=("default", "previous"))
    qp_fallback: str = spec("hold", doc="torques of a tick whose CLF-QP the ADMM budget did not solve: "
                            "the previous tick's ('hold') or the last iterate clipped to the limits ('iterate')",
                            choices=("hold", "iterate"))
    height_reference: str = spec(PAPER["height_reference"], doc="what the COM-height target z0 and the "
                                 "swing-foot height profile are measured from: the stance foot's "
                                 "sole ('stance_foot', the paper's output: COM height over the "
                                 "stance foot, as Xiong's Cassie controller measures it) or the "
                                 "flat ground z = 0 ('ground', the earlier default; "
                                 "docs/cassie_validation compares the two)",
                                 choices=("stance_foot", "ground"))


@dataclass(frozen=True)
class RealismConfig:
    """How far the simulated Cassie is from the ideal plant (Cassie only; the defaults are the
    ideal plant).  Every field is per-scenario data: a sweep over them shares one compiled
    program.  Models and sources: :mod:`hlip_jax.plants.cassie.realism`."""
    motor_curve: bool = spec(False, doc="limit motor torques by their torque-speed curve "
                             "(no-load speeds of Agility's Cassie model)", choices=(True, False))
    motor_corner: float = spec(0.5, 0.05, 0.95, "fraction of the no-load speed up to which a motor "
                               "gives full torque")
    motor_lag: float = spec(0.0, 0.0, 0.05, "first-order time constant of the motor torque", "s")
    latency: int = spec(0, 0, 10, "control ticks between measurement and torque", "ms")
    control_period: int = spec(1, 1, 10, "ticks between control updates (torques held between "
                               "them; 1 = 1 kHz)", "ms")
    joint_noise: float = spec(0.0, 0.0, 5.0, "std of the joint-encoder noise", "deg")
    joint_rate_noise: float = spec(0.0, 0.0, 100.0, "std of the joint-rate noise", "deg/s")
    imu_noise: float = spec(0.0, 0.0, 5.0, "std of the pelvis orientation noise per axis", "deg")
    imu_rate_noise: float = spec(0.0, 0.0, 100.0, "std of the gyro noise per axis", "deg/s")
    imu_bias_roll: float = spec(0.0, -10.0, 10.0, "constant bias of the measured pelvis roll", "deg")
    imu_bias_pitch: float = spec(0.0, -10.0, 10.0, "constant bias of the measured pelvis pitch", "deg")
    velocity_filter: float = spec(0.0, 0.0, 0.5, "time constant of the low-pass on the COM velocity "
                                  "the stepping law uses (0: unfiltered)", "s")
    touchdown: str = spec("contact", doc="touchdown detection: exact contact distance ('contact'), "
                          "the measured heel-spring deflection ('spring'), or the measured leg "
                          "kinematics: a sphere within the gap of the lowest one ('kinematic')",
                          choices=("contact", "spring", "kinematic"))
    spring_threshold: float = spec(1.5, 0.05, 20.0, "heel-spring compression that counts as ground "
                                   "contact (touchdown = 'spring')", "deg")
    mass_scale: float = spec(1.0, 0.5, 2.0, "factor on every link's mass and inertia")
    pelvis_com_x: float = spec(0.0, -0.1, 0.1, "pelvis COM offset forward, pelvis frame", "m")
    pelvis_com_y: float = spec(0.0, -0.1, 0.1, "pelvis COM offset to the left, pelvis frame", "m")
    spring_stiffness_scale: float = spec(1.0, 0.25, 4.0, "factor on the leaf springs' stiffness")
    friction: float = spec(1.0, 0.05, 2.0, "friction coefficient of the feet and the floor "
                           "(the model's: 1.0)")
    slope_x: float = spec(0.0, -15.0, 15.0, "ground slope rising along world x", "deg")
    slope_y: float = spec(0.0, -15.0, 15.0, "ground slope rising along world y", "deg")
    step_height: float = spec(0.0, -0.1, 0.1, "height of a step in the ground at world x = step_x "
                              "(+: up, -: down; the controller does not know it)", "m")
    step_x: float = spec(2.0, 0.3, 100.0, "world x at which the ground steps, or the rough "
                         "ground begins", "m")
    rough_height: float = spec(0.0, 0.0, 0.1, "rough ground from world x = step_x on: height "
                               "field nodes every 0.2 m at heights drawn uniformly from [0, "
                               "rough_height] with the scenario's seed (the controller does not "
                               "know them; not with step_height)", "m")

    def ground_kind(self) -> str:
        """The least ground kind (:data:`GROUND_KINDS`) whose scene this scenario walks on:
        "rough" with rough ground, "step" with a step in the ground, else "flat"."""
        if self.rough_height != 0.0:
            return "rough"
        return "step" if self.step_height != 0.0 else "flat"
