"""Typed configuration of one closed-loop scenario.

A sweep file (see :mod:`hlip_jax.sweep`) is validated into these frozen dataclasses; the
closed loop (:mod:`hlip_jax.rollout`) turns a list of them into batched scenario arrays.
Every numeric field carries its unit, its allowed range and a one-line description in the
field metadata (``spec``), which the sweep validator uses for its error messages.

Conventions: world frame x forward, y left, z up; angles in degrees in configuration files
(converted to radians in arrays); the two H-LIP planes are the world x and y axes.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from hlip_jax import plants
from hlip_jax.plants.cassie import gaits

INF = float("inf")


def spec(default, lo=-INF, hi=INF, doc="", unit="", choices=None):
    """A dataclass field with validation metadata (allowed closed range or choices)."""
    meta = {"lo": lo, "hi": hi, "doc": doc, "unit": unit, "choices": choices}
    if isinstance(default, (list, dict)):
        return field(default_factory=lambda: default, metadata=meta)
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class HLIPConfig:
    """The planner's H-LIP (and the stepping law's reference model)."""
    z0: float = spec(0.8, 0.3, 1.5, "nominal COM height", "m")
    t_ssp: float = spec(0.3, 0.1, 1.0, "single-support duration", "s")
    t_dsp: float = spec(0.1, 0.0, 0.5, "double-support duration", "s")
    g: float = spec(9.81, 1.0, 30.0, "gravity", "m/s^2")


@dataclass(frozen=True)
class MPCConfig:
    """Condensed MPC over the next ``horizon`` step sizes (both planes)."""
    horizon: int = spec(6, 1, 30, "number of future steps planned (static: shapes)")
    w_pos: float = spec(1.0, 0.0, 1e6, "weight on |c_k - r(t_k)|^2")
    w_vel: float = spec(0.1, 0.0, 1e6, "weight on |v_k - rdot(t_k)|^2")
    alpha: float = spec(0.01, 0.0, 1e6, "weight on step sizes |u_k|^2")
    step_length_min: float = spec(-0.4, -2.0, 0.0, "minimum step length along the heading", "m")
    step_length_max: float = spec(0.6, 0.0, 2.0, "maximum step length along the heading", "m")
    step_width_min: float = spec(0.1, 0.0, 1.0, "minimum |step width| (leg clearance)", "m")
    step_width_max: float = spec(0.5, 0.0, 2.0, "maximum |step width|", "m")
    obstacle_weight: float = spec(1e3, 0.0, 1e9, "exact-penalty weight on obstacle slack", "1/m")
    mode: str = spec("tube", doc="what each step's plan starts from: the H-LIP's own state (tube); "
                     "the robot's COM position c with the H-LIP's p and v (position); the robot's "
                     "whole state (measured: on Cassie it feeds the S2S residual back into the "
                     "plan and every robot falls within a few steps, docs/cassie_gait.md round 9)",
                     choices=("tube", "measured", "position"))
    robust: bool = spec(False, doc="tube MPC: tighten step limits by K E and keep-out discs by E, "
                        "E = mRPI(A + B K, W) of the W below (hlip_jax.robust)",
                        choices=(True, False))
    w_frame: str = spec("heading", doc="frame of W (box or hull): plane 1/2 = sagittal/lateral "
                        "('heading') or world x/y ('world')", choices=("heading", "world"))
    w_c_1: float = spec(0.0, 0.0, 1.0, "W half-width on c, plane 1 (robust only)", "m")
    w_p_1: float = spec(0.0, 0.0, 1.0, "W half-width on p, plane 1 (robust only)", "m")
    w_v_1: float = spec(0.0, 0.0, 5.0, "W half-width on v, plane 1 (robust only)", "m/s")
    w_c_2: float = spec(0.0, 0.0, 1.0, "W half-width on c, plane 2 (robust only)", "m")
    w_p_2: float = spec(0.0, 0.0, 1.0, "W half-width on p, plane 2 (robust only)", "m")
    w_v_2: float = spec(0.0, 0.0, 5.0, "W half-width on v, plane 2 (robust only)", "m/s")
    w_shape: str = spec("box", doc="shape of W (robust only): the box of the half-widths above "
                        "('box') or the symmetric convex hull of the points in mpc.w_hull_file "
                        "('hull', as hlip-sweep whull writes them; the half-widths stay 0)",
                        choices=("box", "hull"))
    w_hull_file: str = spec("", doc="CSV file of a hull W's points, columns plane (1 or 2), c, p, "
                            "v, in the frame mpc.w_frame; read with w_shape = 'hull' only (a "
                            "relative path in a sweep file is read from that file's directory)")
    viability: bool = spec(False, doc="keep every planned H-LIP state where step lengths "
                           "within the (tightened) limits can still stop it diverging along the "
                           "path: its sagittal divergent component between the fixed points of "
                           "the length band's edges (hlip_jax.mpc; static: adds QP rows)",
                           choices=(True, False))
    qp_max_iter: int = spec(400, 10, 100000, "ADMM iteration cap per MPC solve")
    qp_eps: float = spec(1e-4, 1e-10, 1e-1, "ADMM absolute/relative tolerance")


@dataclass(frozen=True)
class S2SConfig:
    """The step-to-step map that the MPC plans with, the stepping gain is designed on and the
    error analysis uses (:mod:`hlip_jax.s2s_model`)."""
    model: str = spec("hlip", doc="'hlip': the H-LIP's map from hlip.z0, t_ssp, t_dsp; "
                      "'identified': the map fitted from a robot's step log, read from s2s.file",
                      choices=("hlip", "identified"))
    file: str = spec("", doc="the identified model (.npz of hlip-sweep identify), fitted at this "
                     "sweep's hlip.z0, t_ssp, t_dsp; read with s2s.model = 'identified' only")


@dataclass(frozen=True)
class GainConfig:
    """Stepping-law gain K in u = u_HLIP + K (x_robot - x_HLIP), per plane.

    With ``with_position`` the gain acts on [c, p, v] (3-state: the global position error is
    removed too, deadbeat in 3 steps); without it on [p, v] only (the global position error
    then persists and is left to the planner).  ``type = "deadbeat"`` is therefore the paper's
    classic H-LIP gain K = [1, T_DSP + coth(λ T_SSP)/λ] only with ``with_position = false``;
    with it, it is the 3-state deadbeat gain, whose weight on c grows as 1/T_SSP² (2.4 at the
    Cassie preset's cadence, where it falls: docs/cassie_validation, "Why the classic deadbeat
    gain falls")."""
    type: str = spec("deadbeat", doc="gain design", choices=("deadbeat", "lqr"))
    with_position: bool = spec(True, doc="feed back the global COM position error c too",
                               choices=(True, False))
    q_c: float = spec(1.0, 0.0, 1e6, "LQR weight on c (with_position only)")
    q_p: float = spec(1.0, 0.0, 1e6, "LQR weight on p")
    q_v: float = spec(1.0, 0.0, 1e6, "LQR weight on v")
    r: float = spec(1.0, 1e-9, 1e6, "LQR weight on the step size")
    lateral: str = spec("same", doc="lateral (y) plane gain: the same design as the sagittal "
                        "plane, or deadbeat on the same state", choices=("same", "deadbeat"))


@dataclass(frozen=True)
class PushConfig:
    """A horizontal force on the robot's COM (pelvis for Cassie)."""
    time: float = spec(10.0, 0.0, 1e4, "start time", "s")
    duration: float = spec(0.1, 0.0, 10.0, "duration", "s")
    force: float = spec(200.0, 0.0, 5000.0, "magnitude", "N")
    direction: float = spec(90.0, -360.0, 360.0, "direction in the world frame (0 = +x, 90 = +y)", "deg")


@dataclass(frozen=True)
class DisturbanceConfig:
    """Disturbances of the plant.  Cassie takes ``noise_v`` (a random pelvis force per step that
    changes the COM velocity by up to ±noise_v), ``step_error`` (an offset of the landing
    target) and ``pushes``; the other fields model the H-LIP plant only (rejected for Cassie)."""
    noise_p: float = spec(0.0, 0.0, 1.0, "half-width of the uniform S2S noise on p (both planes)", "m")
    noise_v: float = spec(0.0, 0.0, 5.0, "half-width of the uniform S2S noise on v (both planes)", "m/s")
    step_error: float = spec(0.0, 0.0, 0.5, "half-width of the uniform step-placement error", "m")
    z0: float = spec(0.0, 0.0, 1.5, "plant COM height, 0 = same as the planner's", "m")
    t_ssp: float = spec(0.0, 0.0, 1.0, "plant SSP duration, 0 = same as the planner's", "s")
    t_dsp: float = spec(0.0, 0.0, 0.5, "plant DSP duration, 0 = same as the planner's", "s")
    mass: float = spec(33.0, 1.0, 500.0, "robot mass the pushes act on", "kg")
    step_limits: bool = spec(False, doc="clip the H-LIP plant's steps to a legged robot's reach: the "
                             "Cassie controller's swing-target limits cassie.step_length_max (along "
                             "the heading) and cassie.step_width_min..step_width_max (across it, on "
                             "the swing side), as the Cassie plant clips its own steps")
    pushes: tuple = ()


@dataclass(frozen=True)
class ObstacleConfig:
    """Keep-out disc for the COM."""
    x: float = spec(0.0, -1e4, 1e4, "centre x", "m")
    y: float = spec(0.0, -1e4, 1e4, "centre y", "m")
    radius: float = spec(0.3, 0.0, 100.0, "keep-out radius", "m")
    margin: float = spec(0.0, 0.0, 10.0, "planning margin: the MPC keeps the H-LIP's COM radius + margin "
                         "away (tightening by the robot's tracking error); clearance is reported "
                         "against radius", "m")


@dataclass(frozen=True)
class PathConfig:
    """A reference path: a shape from :data:`hlip_jax.paths.SHAPES` and its parameters."""
    shape: str = "circle"
    params: dict = field(default_factory=dict)


@dataclass(frozen=True)
class CassieConfig:
    """Gait and controller parameters of the Cassie plant (ignored by the H-LIP plant).

    ``gait`` names a preset of :mod:`hlip_jax.plants.cassie.gaits` that fills every gait field
    the sweep file leaves unset (here and in ``hlip``, ``gain``, ``mpc``); the defaults below are
    the "paper" preset's.  All numeric fields are per-scenario data: a sweep over them shares one
    compiled program.  Output frequencies ω set the PD/CLF gains k_p = ω², k_d = 2ω of
    :mod:`hlip_jax.plants.cassie.clfqp`."""
    gait: str = spec("paper", doc="gait preset whose values fill the unset gait fields",
                     choices=tuple(gaits.PRESETS))
    clearance: float = spec(0.0647, 0.0, 0.3, "swing-foot apex height", "m")
    strike: float = spec(0.0174, 0.0, 0.1, "swing target depth below the ground at the end of the swing profile", "m")
    reach: float = spec(0.9333, 0.3, 1.0, "fraction of the swing profile's duration (T_SSP / s*: "
                        "it lands at T_SSP) at which the swing foot reaches its target")
    freeze: float = spec(1.0, 0.3, 1.0, "fraction of SSP after which the step target is held")
    early_contact: float = spec(0.8914, 0.3, 1.0, "fraction of SSP after which a detected swing-foot "
                                "touchdown ends the SSP")
    step_length_max: float = spec(0.6, 0.1, 1.0, "|step length| clip of the swing target, along the heading", "m")
    step_width_min: float = spec(0.1, 0.0, 0.5, "minimum |step width| of the swing target, across the heading", "m")
    step_width_max: float = spec(0.645, 0.1, 1.0, "maximum |step width| of the swing target", "m")
    omega_pelvis: float = spec(6.2518, 0.5, 50.0, "pelvis orientation output frequency", "rad/s")
    omega_height: float = spec(2.5235, 0.5, 50.0, "COM height output frequency", "rad/s")
    omega_swing: float = spec(17.0053, 0.5, 80.0, "swing-foot position and slope output frequency", "rad/s")
    omega_yaw: float = spec(7.5996, 0.5, 50.0, "swing-foot yaw output frequency", "rad/s")
    weight_pelvis: float = spec(6.3141, 0.0, 10.0, "QP tracking weight of the pelvis orientation outputs")
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
    qp_rho_start: str = spec("previous", doc="the ADMM step size rho each tick's CLF-QP starts from: "
                             "the previous tick's final rho ('previous', as OSQP keeps rho between "
                             "warm-started solves; about 40 % fewer iterations per tick, "
                             "docs/cassie_validation) or the solver's default 0.1 ('default', "
                             "the earlier behaviour)", choices=("default", "previous"))
    qp_fallback: str = spec("hold", doc="torques of a tick whose CLF-QP the ADMM budget did not solve: "
                            "the previous tick's ('hold') or the last iterate clipped to the limits ('iterate')",
                            choices=("hold", "iterate"))
    height_reference: str = spec("stance_foot", doc="what the COM-height target z0 and the "
                                 "swing-foot height profile are measured from: the stance foot's "
                                 "sole ('stance_foot', the paper's output: COM height over the "
                                 "stance foot, as Xiong's Cassie controller measures it) or the "
                                 "flat ground z = 0 ('ground', the earlier default; "
                                 "docs/cassie_validation compares the two)",
                                 choices=("stance_foot", "ground"))


@dataclass(frozen=True)
class ImplConfig:
    """How a scenario is computed, never what it computes: the implementation switches of the
    Cassie closed loop (ignored by the H-LIP plant).  A sweep sets them in its ``[impl]``
    table, beside the profile that fills the ones it leaves unset for the backend
    (:mod:`hlip_jax.impl`); every field is static (one value per sweep: one compiled program).
    The same scenario within the solvers' tolerances whichever values are chosen; the
    manifest records them with the scenario."""
    physics: str = spec("jax", doc="implementation that steps the simulated robot (static): MJX-JAX "
                        "('jax', every backend) or MJX's Warp implementation ('warp', needs "
                        "pip install 'hlip_jax[warp]'); the controller is the same code on both",
                        choices=("jax", "warp"))
    qp_loop: str = spec("while", doc="the CLF-QP's ADMM block loop (static): 'while' stops when every "
                        "robot's QP of the batch has converged; 'fixed' always runs the whole budget in a "
                        "loop of static trip count (the same torques; on an H100 2.2x slower at batch 32, "
                        "docs/benchmarks/cassie_gpu.md); 'compact' is the while loop with straggler compaction: the "
                        "robots whose QPs are still unsolved continue in a smaller batch (the same "
                        "torques up to rounding; for large batches on a GPU, docs/benchmarks/cassie_gpu.md)",
                        choices=("while", "fixed", "compact"))
    qp_linsys: str = spec("cholesky", doc="how the CLF-QP's ADMM solves its linear system each iteration "
                          "(static): 'cholesky' (two triangular solves with the factor) or 'inverse' "
                          "(the inverse formed once per factorisation, then a matrix-vector product; "
                          "the same solutions within the solver's tolerance, faster on a GPU, "
                          "docs/benchmarks/cassie_gpu.md)", choices=("cholesky", "inverse"))
    qp_kernel: str = spec("xla", doc="how the CLF-QP's ADMM iterations run (static): 'xla' (each "
                          "iteration as XLA operations) or 'fused' (each block of iterations as one "
                          "Pallas kernel that keeps the problem on chip; needs qp_linsys = 'inverse'; "
                          "compiled on GPUs, interpreted elsewhere, so only for GPUs; the same "
                          "iterations up to float rounding, docs/benchmarks/cassie_gpu.md)", choices=("xla", "fused"))
    condense: str = spec("eigen", doc="how the CLF-QP's model solves for the constraint forces "
                         "(static): 'eigen' (G's eigendecomposition with a relative cut of 1e-9, "
                         "the validated controller's; in float32 it inverts round-off along the "
                         "plantar four-bars' null directions) or 'deflated' (those null directions "
                         "projected out and one Cholesky factorisation: float32 within 3e-5 of "
                         "float64 and cheaper on a GPU; its walking: docs/cassie_validation)",
                         choices=("eigen", "deflated"))
    terms: str = spec("mjx", doc="how the controller computes its whole-body terms (kinematics, "
                      "mass matrix, bias, Jacobians) each tick (static): by MJX's own stages "
                      "('mjx', the validated controller's) or by dense array programs over the "
                      "fixed body tree ('dense': the same terms within float rounding, tested "
                      "against C MuJoCo, without the tree scatters that XLA's deterministic GPU "
                      "operations sort; docs/benchmarks/cassie_gpu.md)", choices=("mjx", "dense"))


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


#: a batch's ground kinds, each one's scene holding what the kinds before it need: "flat" the
#: plain scene, "step" with the terrain block, "rough" with the block and the height field
GROUND_KINDS = ("flat", "step", "rough")


@dataclass(frozen=True)
class ScenarioConfig:
    """Everything one closed-loop run needs.  ``swept`` records the grid values that made it."""
    name: str = "scenario"
    plant: str = spec("hlip", doc="what executes the steps (hlip_jax.plants registry)",
                      choices=plants.NAMES)
    seed: int = spec(0, 0, 2**31 - 1, "PRNG seed")
    duration: float = spec(30.0, 0.5, 3600.0, "simulated time", "s")
    hlip: HLIPConfig = field(default_factory=HLIPConfig)
    s2s: S2SConfig = field(default_factory=S2SConfig)
    mpc: MPCConfig = field(default_factory=MPCConfig)
    gain: GainConfig = field(default_factory=GainConfig)
    path: PathConfig = field(default_factory=PathConfig)
    disturbance: DisturbanceConfig = field(default_factory=DisturbanceConfig)
    obstacles: tuple = ()
    cassie: CassieConfig = field(default_factory=CassieConfig)
    realism: RealismConfig = field(default_factory=RealismConfig)
    impl: ImplConfig = field(default_factory=ImplConfig)
    swept: dict = field(default_factory=dict)


#: settings that are array shapes or compiled solver settings: one value for every scenario of
#: a batch (:func:`hlip_jax.rollout.build`) and of a sweep (:mod:`hlip_jax.sweep`)
STATIC_FIELDS = ("plant", "mpc.horizon", "mpc.viability", "mpc.qp_max_iter", "mpc.qp_eps",
                 "cassie.qp_max_iter", "cassie.qp_eps", "impl.qp_loop", "impl.qp_linsys",
                 "impl.qp_kernel", "impl.condense", "impl.terms", "impl.physics")


def field_value(cfg: "ScenarioConfig", field: str):
    """The value of a dotted field (``"impl.qp_loop"``) of a scenario."""
    obj = cfg
    for k in field.split("."):
        obj = getattr(obj, k)
    return obj


def field_spec(cls, name) -> dict[str, Any]:
    """Validation metadata of ``cls.name`` (empty for structural fields)."""
    for f in dataclasses.fields(cls):
        if f.name == name:
            return dict(f.metadata)
    raise KeyError(name)
