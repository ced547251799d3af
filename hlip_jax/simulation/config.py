"""Typed configuration of one closed-loop scenario.

A sweep file (see :mod:`hlip_jax.sweepio.sweep`) is validated into these frozen dataclasses; the
closed loop (:mod:`hlip_jax.simulation.rollout`) turns a list of them into batched scenario arrays.
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
from hlip_jax.core.fields import INF, field_spec, spec  # noqa: F401  (the config layer's names)
from hlip_jax.plants.base import GROUND_KINDS  # noqa: F401

#: the plants' own settings tables (each plant's config class, found through the registry)
CassieConfig = plants.settings_class("cassie")
RealismConfig = plants.settings_class("realism")

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
                        "E = mRPI(A + B K, W) of the W below (hlip_jax.core.robust)",
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
                           "the length band's edges (hlip_jax.core.mpc; static: adds QP rows)",
                           choices=(True, False))
    qp_max_iter: int = spec(400, 10, 100000, "ADMM iteration cap per MPC solve")
    qp_eps: float = spec(1e-4, 1e-10, 1e-1, "ADMM absolute/relative tolerance")


@dataclass(frozen=True)
class S2SConfig:
    """The step-to-step map that the MPC plans with, the stepping gain is designed on and the
    error analysis uses (:mod:`hlip_jax.core.s2s_model`)."""
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
    """A reference path: a shape from :data:`hlip_jax.core.paths.SHAPES` and its parameters."""
    shape: str = "circle"
    params: dict = field(default_factory=dict)


@dataclass(frozen=True)
class ImplConfig:
    """How a scenario is computed, never what it computes: the implementation switches of the
    Cassie closed loop (the H-LIP plant takes only the defaults).  A sweep sets them in its ``[impl]``
    table, beside the profile that fills the ones it leaves unset for the backend
    (:mod:`hlip_jax.runtime.impl`); every field is static (one value per sweep: one compiled program).
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


#: the implementation fields, set in a sweep's ``[impl]`` table only
IMPL_FIELDS = tuple(f.name for f in dataclasses.fields(ImplConfig))


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
#: a batch (:func:`hlip_jax.simulation.arrays.build`) and of a sweep (:mod:`hlip_jax.sweepio.sweep`)
STATIC_FIELDS = ("plant", "mpc.horizon", "mpc.viability", "mpc.qp_max_iter", "mpc.qp_eps",
                 "cassie.qp_max_iter", "cassie.qp_eps", "impl.qp_loop", "impl.qp_linsys",
                 "impl.qp_kernel", "impl.condense", "impl.terms", "impl.physics")


def field_value(cfg: "ScenarioConfig", field: str):
    """The value of a dotted field (``"impl.qp_loop"``) of a scenario."""
    obj = cfg
    for k in field.split("."):
        obj = getattr(obj, k)
    return obj
