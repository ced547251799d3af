"""CPU reference of the standing CLF-QP controller: C MuJoCo + numpy + OSQP, one robot per tick.

The same controller as :func:`hlip_jax.plants.cassie.control.control` and
:func:`~hlip_jax.plants.cassie.control.stand_rollout`, written the way a conventional
single-robot controller runs on a CPU core — the baseline the batched MJX throughput is compared
against ("C MuJoCo + OSQP per tick, one process per core").  One control tick (1 kHz):

1. **Model terms** (:func:`robot_terms`) with C MuJoCo on the current ``qpos``, ``qvel``:
   ``mj_kinematics``, ``mj_comPos``, ``mj_crb`` (M, armature included), ``mj_factorM`` (its
   sparse L'DL factor), ``mj_comVel`` (``cdof_dot``, ``cvel``), ``mj_passive`` (f_p) and
   ``mj_rne`` with q̈ = 0 (h) — the stages of :func:`model.smooth`, no collision and no
   constraint solve.  Dense M by ``mj_fullM``; Jacobians by ``mj_jacSite`` (contact sites),
   ``mj_jac`` (the two anchor points of every connect loop, as :func:`model.loop_jacobian`) and
   ``mj_jacSubtreeCom`` (the COM of the pelvis subtree = the whole robot).
2. **J̇q̇** of a point p on body b at q̈ = 0, model.py's analytic form (module doc of
   :mod:`~hlip_jax.plants.cassie.model`) evaluated from C MuJoCo's ``cdof``, ``cdof_dot`` and
   ``cvel``::

       J̇q̇(p) = Σ_{i ∈ anc(b)} q̇_i (ċdof_lin,i + ċdof_ang,i × o) + ω_b × ȯ,
       o = p − c₀,   ȯ = v_b(c₀) − o × ω_b,   (ω_b, v_b(c₀)) = cvel[b]

   (``Σ_{i ∈ anc(b)} q̇_i cdof_ang,i = ω_b``), with ċdof of the quaternion dofs (ball joints
   and the free joint's rotation) replaced by ``cvel_body ×ₘ cdof`` as in
   :func:`model._cdof_dot` (this is also ``mj_jacDot``'s convention; the test checks the result
   against ``mj_jacDot @ qvel``).  ``mj_comVel`` itself gives those dofs the parent's velocity
   instead; the q̇-weighted sums differ by v_J ×ₘ v_J = 0 over each joint's own dofs, so J̇q̇
   would not change, but the override is kept to mirror model.py term by term.  All 37 points — 4 contact sites, 8 loop anchors and the 25
   body COMs of the COM term — are evaluated in one vectorised pass; the COM term is their
   mass-weighted mean (:func:`model.com_jdot_qdot`).
3. **Outputs** (:func:`measure`, :func:`errors`) and **condensed dynamics** (:func:`condense`):
   numpy transcriptions of :func:`outputs.measure` and :func:`dynamics.condense`; M⁻¹ by
   ``mj_solveM`` on MuJoCo's factor instead of a dense Cholesky (same solve, round-off apart);
   the pseudo-inverse of G by ``numpy.linalg.eigh`` with the same relative cut-off.
4. **CLF-QP** (:func:`build`): P, q, A, l, u exactly as :func:`clfqp.build`, solved by OSQP
   (:class:`QPSolver`): one ``osqp.OSQP`` object per robot, set up once on a fixed sparsity
   pattern and updated every tick (``update(Px, q, Ax, l, u)``), warm-started from the previous
   tick's (x, y), with the solver settings of :data:`clfqp.DEFAULT_SETTINGS` (ε = 1e-4, at most
   150 ADMM iterations, 5 Ruiz passes, ρ₀ = 0.1 adapted every 25 iterations, no polishing, no
   duality-gap test).  τ = clip(x[:nu], τ_min, τ_max) as :func:`clfqp.solve` (``fallback=False``).
5. **Physics**: ``SUBSTEPS`` = 2 ``mj_step`` of 0.5 ms with ``ctrl = τ`` and the push force on
   the pelvis (``xfrc_applied``), on the model with 10 N m s/rad on the leaf springs
   (:func:`load_model`, the C twin of :func:`control.load`).

Units: SI throughout (m, s, rad, kg, N, N m); τ is motor-side torque (``ctrl`` units).

No JAX computation happens here: this module imports the project's constants (MJCF path, index
map, gains, solver settings, dimensions) from the JAX modules, which creates no JAX array and
initialises no JAX backend.  float64 only.
"""

from __future__ import annotations

import functools
import math
import time
from typing import NamedTuple, Optional

import mujoco
import numpy as np
import osqp
import scipy.sparse as sp

from hlip_jax.plants.cassie import clfqp, control, dynamics, model, outputs, tree_terms

SUBSTEPS = control.SUBSTEPS
CONTROL_DT = control.CONTROL_DT       # [s]
N_POINT_SITES = 4                     # contact sites in the J̇q̇ batch (rows 0..3)
N_POINT_LOOPS = 8                     # loop anchors (rows 4..7: body1, 8..11: body2)
#: stages of one tick timed by :class:`Robot` (``prof`` slots, seconds accumulated)
STAGES = ("model terms", "outputs", "condensation", "QP build", "OSQP", "physics")
_OSQP_INFTY = 1e30                    # OSQP's infinity (|bound| ≥ this is unbounded)


# ----------------------------------------------------------------------------- model


def load_model(spring_damping: float = control.SPRING_DAMPING) -> mujoco.MjModel:
    """C MuJoCo model of ``scene.xml`` with ``spring_damping`` [N m s/rad] on the four leaf-spring
    dofs (left shin, left heel, right shin, right heel), as :func:`control.load`."""
    if not spring_damping >= 0:
        raise ValueError(f"spring_damping must be ≥ 0 N m s/rad, got {spring_damping}")
    m = mujoco.MjModel.from_xml_path(str(model.SCENE_XML))
    for j in spring_dofs(model.index_map(m)):
        m.dof_damping[j] = spring_damping
    return m


def spring_dofs(idx: model.CassieIndex) -> tuple:
    """dof addresses of the leaf springs, :func:`dynamics.spring_dofs` order."""
    return tuple(int(getattr(idx.dof[s], n)) for s in (0, 1) for n in ("shin", "heel_spring"))


_I1, _I2 = np.array([1, 2, 0]), np.array([2, 0, 1])


def _cross(a, b):
    """Row-wise cross product of (k, 3) arrays (cheaper than ``np.cross`` at this size)."""
    return a[:, _I1] * b[:, _I2] - a[:, _I2] * b[:, _I1]


class Static(NamedTuple):
    """Per-model constants of the reference (numpy; built once by :func:`static`)."""

    m: mujoco.MjModel
    idx: model.CassieIndex
    B: np.ndarray             # (nv, nu) actuation matrix
    tau_min: np.ndarray       # (nu,) [N m]
    tau_max: np.ndarray       # (nu,) [N m]
    springs: tuple            # 4 spring dof addresses
    sites: tuple              # 4 contact site ids (model.CONTACT_SITES order)
    loop_b1: np.ndarray       # (4,) rod body of each loop
    loop_b2: np.ndarray       # (4,) partner body
    loop_a1: np.ndarray       # (4, 3) anchor in body1's frame [m]
    loop_a2: np.ndarray       # (4, 3) anchor in body2's frame [m]
    com_bodies: np.ndarray    # (nbody − 1,) bodies 1.. of the COM term
    com_w: np.ndarray         # (nbody − 1,) body mass / total mass
    pt_bodies: np.ndarray     # (37,) body of every J̇q̇ point: sites, loop b1, loop b2, COMs
    pt_mask: np.ndarray       # (37, nv) ancestor mask of those bodies
    quat_dofs: np.ndarray     # dof ids whose axis is body-fixed (ball / free rotation)
    quat_body: np.ndarray     # their bodies


def static(m: mujoco.MjModel) -> Static:
    """Index maps, masks and weights of :func:`robot_terms` for the model ``m``."""
    idx = model.index_map(m)
    loops = np.array(idx.loops)
    sites = tuple(idx.contact_sites)
    b1, b2 = m.eq_obj1id[loops].copy(), m.eq_obj2id[loops].copy()
    com_bodies = np.arange(1, m.nbody)
    pt_bodies = np.concatenate([m.site_bodyid[list(sites)], b1, b2, com_bodies]).astype(int)
    mask = tree_terms.tree_of(m).moves
    jt = m.jnt_type[m.dof_jntid]
    first = m.jnt_dofadr[m.dof_jntid]
    is_quat = (jt == mujoco.mjtJoint.mjJNT_BALL) | (
        (jt == mujoco.mjtJoint.mjJNT_FREE) & (np.arange(m.nv) >= first + 3))
    quat_dofs = np.flatnonzero(is_quat)
    return Static(
        m=m, idx=idx, B=model.actuation_matrix(m),
        tau_min=m.actuator_ctrlrange[:, 0].copy(), tau_max=m.actuator_ctrlrange[:, 1].copy(),
        springs=spring_dofs(idx), sites=sites,
        loop_b1=b1, loop_b2=b2,
        loop_a1=m.eq_data[loops, 0:3].copy(), loop_a2=m.eq_data[loops, 3:6].copy(),
        com_bodies=com_bodies,
        com_w=m.body_mass[com_bodies] / float(m.body_subtreemass[idx.pelvis_body]),
        pt_bodies=pt_bodies, pt_mask=np.ascontiguousarray(mask[pt_bodies]),
        quat_dofs=quat_dofs, quat_body=m.dof_bodyid[quat_dofs].copy(),
    )


class Terms(NamedTuple):
    """The :class:`model.RobotTerms` fields the standing tick uses (same names, shapes, units)."""

    M: np.ndarray           # (nv, nv)
    bias: np.ndarray        # (nv,) h
    passive: np.ndarray     # (nv,) f_p
    com: np.ndarray         # (3,) [m]
    com_vel: np.ndarray     # (3,) [m/s]
    com_J: np.ndarray       # (3, nv)
    com_jdqd: np.ndarray    # (3,) [m/s²]
    site_pos: np.ndarray    # (4, 3) [m]
    site_J: np.ndarray      # (4, 3, nv)
    site_jdqd: np.ndarray   # (4, 3) [m/s²]
    loop_res: np.ndarray    # (12,) [m]
    loop_J: np.ndarray      # (12, nv)
    loop_jdqd: np.ndarray   # (12,) [m/s²]
    pelvis_R: np.ndarray    # (3, 3) pelvis → world (from the qpos quaternion)


def smooth(m: mujoco.MjModel, d: mujoco.MjData) -> None:
    """C MuJoCo stages of :func:`model.smooth` on ``d.qpos``, ``d.qvel`` (in place), plus the
    factorisation of M used by ``mj_solveM``; leaves ``qfrc_bias`` = h(q, q̇) (q̈ = 0)."""
    mujoco.mj_kinematics(m, d)
    mujoco.mj_comPos(m, d)
    mujoco.mj_crb(m, d)
    mujoco.mj_factorM(m, d)
    mujoco.mj_comVel(m, d)
    mujoco.mj_passive(m, d)
    mujoco.mj_rne(m, d, 0, d.qfrc_bias)


def point_jdot_qdot(s: Static, d: mujoco.MjData, points: np.ndarray) -> np.ndarray:
    """``J̇q̇`` (k, 3) [m/s²] of the world points ``points`` (k, 3) fixed to ``s.pt_bodies``
    (module doc, step 2); needs :func:`smooth` on ``d``.

    Evaluated as S_lin + S_ang × o + ω × v − o‖ω‖² + ω (ω·o) with S = Σ_{anc} q̇ ċdof and
    ω × ȯ = ω × v − ω × (o × ω) expanded, so that all cross products of a call are one
    vectorised product (the same terms as :func:`model.point_jdot_qdot`, round-off apart)."""
    cdd = d.cdof_dot.copy()
    qd = s.quat_dofs
    n = len(qd)
    cv = d.cvel[s.quat_body]
    cd = d.cdof[qd]
    # quaternion dofs: body-fixed axes, ċdof = v_body ×ₘ cdof = [ω × s_ang, ω × s_lin + v × s_ang]
    c = _cross(np.concatenate([cv[:, :3], cv[:, :3], cv[:, 3:]]),
               np.concatenate([cd[:, :3], cd[:, 3:], cd[:, :3]]))
    cdd[qd, :3] = c[:n]
    cdd[qd, 3:] = c[n:2 * n] + c[2 * n:]
    S = s.pt_mask @ (d.qvel[:, None] * cdd)                    # (k, 6) Σ q̇ ċdof over ancestors
    o = points - d.subtree_com[s.idx.pelvis_body]
    cvel = d.cvel[s.pt_bodies]
    w, v = cvel[:, :3], cvel[:, 3:]
    k = len(o)
    c = _cross(np.concatenate([S[:, :3], w]), np.concatenate([o, v]))
    ww = np.einsum("ki,ki->k", w, w)
    wo = np.einsum("ki,ki->k", w, o)
    return S[:, 3:] + c[:k] + c[k:] - o * ww[:, None] + w * wo[:, None]


def robot_terms(s: Static, d: mujoco.MjData) -> Terms:
    """Runs :func:`smooth` on ``d`` and gathers :class:`Terms` (the C twin of
    :func:`model.robot_terms`, standing subset)."""
    m = s.m
    nv = m.nv
    smooth(m, d)
    M = np.empty((nv, nv))
    mujoco.mj_fullM(m, d, M)
    site_pos = d.site_xpos[list(s.sites)].copy()
    site_J = np.empty((4, 3, nv))
    for k, site in enumerate(s.sites):
        mujoco.mj_jacSite(m, d, site_J[k], None, site)
    # loop anchors: p = x_b + R_b a (model._loop_points)
    p1 = d.xpos[s.loop_b1] + (d.xmat[s.loop_b1].reshape(4, 3, 3) @ s.loop_a1[:, :, None])[..., 0]
    p2 = d.xpos[s.loop_b2] + (d.xmat[s.loop_b2].reshape(4, 3, 3) @ s.loop_a2[:, :, None])[..., 0]
    J1 = np.empty((4, 3, nv))
    J2 = np.empty((4, 3, nv))
    for k in range(4):
        mujoco.mj_jac(m, d, J1[k], None, p1[k], int(s.loop_b1[k]))
        mujoco.mj_jac(m, d, J2[k], None, p2[k], int(s.loop_b2[k]))
    com_J = np.empty((3, nv))
    mujoco.mj_jacSubtreeCom(m, d, com_J, s.idx.pelvis_body)
    pts = np.concatenate([site_pos, p1, p2, d.xipos[s.com_bodies]])
    acc = point_jdot_qdot(s, d, pts)
    nl = N_POINT_SITES + N_POINT_LOOPS // 2
    q = d.qpos[s.idx.root_qpos + 3: s.idx.root_qpos + 7]
    R = np.empty(9)
    mujoco.mju_quat2Mat(R, q / np.linalg.norm(q))
    return Terms(
        M=M, bias=d.qfrc_bias.copy(), passive=d.qfrc_passive.copy(),
        com=d.subtree_com[s.idx.pelvis_body].copy(), com_vel=com_J @ d.qvel, com_J=com_J,
        com_jdqd=s.com_w @ acc[N_POINT_SITES + N_POINT_LOOPS:],
        site_pos=site_pos, site_J=site_J, site_jdqd=acc[:N_POINT_SITES],
        loop_res=(p1 - p2).reshape(-1), loop_J=(J1 - J2).reshape(12, nv),
        loop_jdqd=(acc[N_POINT_SITES:nl] - acc[nl:N_POINT_SITES + N_POINT_LOOPS]).reshape(-1),
        pelvis_R=R.reshape(3, 3),
    )


def rpy_from_mat(R: np.ndarray) -> np.ndarray:
    """(roll, pitch, yaw) [rad], :func:`model.rpy_from_mat`."""
    return np.array([np.arctan2(R[2, 1], R[2, 2]), np.arcsin(np.clip(-R[2, 0], -1.0, 1.0)),
                     np.arctan2(R[1, 0], R[0, 0])])


# ----------------------------------------------------------------------------- outputs


def measure(terms: Terms, qvel: np.ndarray, root_dof: int = 0) -> outputs.Measured:
    """The 16 outputs of :func:`outputs.measure` (y, ẏ = J q̇, J, J̇q̇, R) as numpy arrays."""
    nv = terms.M.shape[0]
    R = terms.pelvis_R
    J_rot = np.zeros((3, nv))
    J_rot[:, root_dof + 3: root_dof + 6] = R
    Jsite = terms.site_J.reshape(2, 2, 3, nv)
    Asite = terms.site_jdqd.reshape(2, 2, 3)
    J_foot = 0.5 * (Jsite[:, 0] + Jsite[:, 1])
    a_foot = 0.5 * (Asite[:, 0] + Asite[:, 1])
    sp3 = terms.site_pos.reshape(2, 2, 3)
    dv = sp3[:, 0] - sp3[:, 1]                              # heel → toe (2, 3)
    Jd = Jsite[:, 0] - Jsite[:, 1]
    ad = Asite[:, 0] - Asite[:, 1]
    dd = Jd @ qvel
    r2 = dv[:, 0] ** 2 + dv[:, 1] ** 2
    yaw = np.arctan2(dv[:, 1], dv[:, 0])
    J_yaw = (dv[:, 0, None] * Jd[:, 1] - dv[:, 1, None] * Jd[:, 0]) / r2[:, None]
    yaw_dot = (dv[:, 0] * dd[:, 1] - dv[:, 1] * dd[:, 0]) / r2
    a_yaw = ((dv[:, 0] * ad[:, 1] - dv[:, 1] * ad[:, 0]) / r2
             - 2.0 * yaw_dot * (dv[:, 0] * dd[:, 0] + dv[:, 1] * dd[:, 1]) / r2)
    feet = 0.5 * (sp3[:, 0] + sp3[:, 1])
    feet[:, 2] -= model.FOOT_SPHERE_RADIUS
    y = np.concatenate([np.zeros(3), terms.com[2:3], terms.com[:2], feet[0], feet[1],
                        dv[:, 2], yaw])
    J = np.concatenate([J_rot, terms.com_J[2:3], terms.com_J[:2], J_foot[0], J_foot[1],
                        Jd[:, 2], J_yaw], axis=0)
    jdqd = np.concatenate([np.zeros(3), terms.com_jdqd[2:3], terms.com_jdqd[:2], a_foot[0],
                           a_foot[1], ad[:, 2], a_yaw])
    return outputs.Measured(y=y, ydot=J @ qvel, J=J, jdqd=jdqd, R=R)


def rotation_error(R: np.ndarray, R_d: np.ndarray) -> np.ndarray:
    """World rotation vector e [rad] with R = exp([e]×) R_d (:func:`outputs.rotation_error`)."""
    E = R @ R_d.T
    sx, sy, sz = 0.5 * (E[2, 1] - E[1, 2]), 0.5 * (E[0, 2] - E[2, 0]), 0.5 * (E[1, 0] - E[0, 1])
    c = 0.5 * (E[0, 0] + E[1, 1] + E[2, 2] - 1.0)
    n = math.sqrt(sx * sx + sy * sy + sz * sz)
    f = math.atan2(n, c) / n if n > 1e-9 else 1.0
    return np.array([sx * f, sy * f, sz * f])


def errors(meas: outputs.Measured, des: outputs.Desired):
    """(e, ė) (16,) each, :func:`outputs.errors`: output minus desired, masked."""
    e = meas.y - des.y
    e[outputs.ROT] = rotation_error(meas.R, des.R)
    fy = list(outputs.FOOT_YAW)
    e[fy] = np.arctan2(np.sin(e[fy]), np.cos(e[fy]))
    return e * des.mask, (meas.ydot - des.ydot) * des.mask


def stand_desired(com_height, com_xy, yaw) -> outputs.Desired:
    """Standing desired outputs (:func:`outputs.stand_desired`): pelvis level with heading
    ``yaw`` [rad], COM at (``com_xy``, ``com_height``) [m]; numpy float64."""
    y = np.zeros(outputs.N_OUT)
    y[outputs.COM_Z] = com_height
    y[outputs.COM_XY] = com_xy
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    z = np.zeros(outputs.N_OUT)
    return outputs.Desired(y=y, ydot=z, yddot=z.copy(), R=R, mask=outputs.STAND_MASK.astype(float))


# ----------------------------------------------------------------------------- dynamics


_EYE3 = np.eye(3)


def contact_frames(terms: Terms, contact: np.ndarray):
    """Row frames H (4, 3, 3) and row flags (12,), :func:`dynamics.contact_frames`: with both
    sites of a foot in contact the heel keeps only the rows n₁ = (ẑ − (ẑ·d̂)d̂)/‖·‖, n₂ = d̂ × n₁
    normal to the heel→toe axis d̂."""
    contact = np.asarray(contact, float)
    sp3 = terms.site_pos.reshape(2, 2, 3)
    dv = sp3[:, 0] - sp3[:, 1]
    dv /= np.sqrt(np.einsum("fi,fi->f", dv, dv))[:, None]
    n1 = -dv[:, 2:3] * dv
    n1[:, 2] += 1.0
    n1 /= np.sqrt(np.einsum("fi,fi->f", n1, n1))[:, None]
    both = (contact[0::2] > 0.5) & (contact[1::2] > 0.5)
    H = np.empty((4, 3, 3))
    H[0::2] = _EYE3
    pair = np.stack([n1, _cross(dv, n1), np.zeros((2, 3))], axis=1)
    H[1::2] = np.where(both[:, None, None], pair, _EYE3)
    flags = np.repeat(contact, 3).reshape(4, 3)
    flags[1::2, 2] *= np.where(both, 0.0, 1.0)
    return H, flags.reshape(-1)


def constraint_stack(terms: Terms, contact, springs=None):
    """(J (28, nv), J̇q̇ (28,), active (28,), H (4, 3, 3)), :func:`dynamics.constraint_stack`:
    loops (rows 0..11), contact sites in the frames H (12..23), locked springs (24..27)."""
    nv = terms.M.shape[0]
    H, ac = contact_frames(terms, contact)
    nl, nc = dynamics.N_LOOP_ROWS, dynamics.N_LOOP_ROWS + dynamics.N_CONTACT_ROWS
    J = np.zeros((dynamics.N_CONSTRAINT_ROWS, nv))
    J[:nl] = terms.loop_J
    J[nl:nc] = (H @ terms.site_J).reshape(dynamics.N_CONTACT_ROWS, nv) * ac[:, None]
    jd = np.zeros(dynamics.N_CONSTRAINT_ROWS)
    jd[:nl] = terms.loop_jdqd
    jd[nl:nc] = (H @ terms.site_jdqd[:, :, None]).reshape(dynamics.N_CONTACT_ROWS) * ac
    active = np.ones(dynamics.N_CONSTRAINT_ROWS)
    active[nl:nc] = ac
    if springs is None:
        active[nc:] = 0.0
    else:
        J[np.arange(nc, dynamics.N_CONSTRAINT_ROWS), list(springs)] = 1.0
    return J, jd, active, H


def condense(terms: Terms, actuation, contact, springs, solve_M, reg: float = 1e-9):
    """Affine maps τ ↦ (q̈, λ) of the constrained dynamics, :func:`dynamics.condense`::

        G = J M⁻¹ Jᵀ + diag(1 − active),   λ = G⁺ (−J̇q̇ − J M⁻¹ (B τ − h + f_p)),
        q̈ = M⁻¹ (B τ − h + f_p) + M⁻¹ Jᵀ λ,

    G⁺ the eigen pseudo-inverse (eigenvalues ≤ ``reg`` · max eig dropped); contact rows of λ
    returned as world forces Hᵢᵀλᵢ [N].  ``solve_M(Yᵀ)`` returns (M⁻¹ Y)ᵀ for Yᵀ (k, nv) (here
    ``mj_solveM`` on MuJoCo's factor).  Returns :class:`dynamics.Condensed` (numpy)."""
    J, jd, active, H = constraint_stack(terms, contact, springs)
    nu = actuation.shape[1]
    # M⁻¹ [B, f_p − h, Jᵀ], solved as rows: Yᵀ = [Bᵀ; (f_p − h)ᵀ; J]
    X = solve_M(np.concatenate([actuation.T, (terms.passive - terms.bias)[None], J]))
    Minv_rhs, Minv_Jt = X[:nu + 1].T, X[nu + 1:].T
    G = J @ Minv_Jt
    G[np.diag_indices_from(G)] += 1.0 - active
    rhs_l = -(J @ Minv_rhs)
    rhs_l[:, -1] -= jd
    s, U = np.linalg.eigh(0.5 * (G + G.T))
    keep = s > reg * s.max()
    s_inv = np.where(keep, 1.0 / np.where(keep, s, 1.0), 0.0)
    lam = U @ (s_inv[:, None] * (U.T @ rhs_l))
    qdd = Minv_rhs + Minv_Jt @ lam
    c0, c1 = dynamics.N_LOOP_ROWS, dynamics.N_LOOP_ROWS + dynamics.N_CONTACT_ROWS
    lam[c0:c1] = (H.transpose(0, 2, 1) @ lam[c0:c1].reshape(4, 3, -1)).reshape(
        dynamics.N_CONTACT_ROWS, -1)
    return dynamics.Condensed(qdd_tau=qdd[:, :-1], qdd0=qdd[:, -1], lam_tau=lam[:, :-1],
                              lam0=lam[:, -1])


# ----------------------------------------------------------------------------- CLF-QP


@functools.lru_cache(maxsize=8)
def _friction_rows(mu_f: float) -> np.ndarray:
    """(5, 3) rows of the friction pyramid on a site force (f_z, μf_z ∓ f_x, μf_z ∓ f_y ≥ 0)."""
    sel = np.array([[0, 0, 1], [-1, 0, mu_f], [1, 0, mu_f], [0, -1, mu_f], [0, 1, mu_f]], float)
    sel.flags.writeable = False
    return sel


def build(meas, des, cond, contact, tau_min, tau_max, gains: clfqp.Gains) -> clfqp.Problem:
    """The CLF-QP of :func:`clfqp.build` over x = [τ, δ] as dense numpy (P, q, A, l, u):

        P = [[A_μᵀ W A_μ + w_τ I, 0], [0, w_δ]],   q = [A_μᵀ W (b_μ − μ_PD), 0],
        rows: CLF  L_gV A_μ τ − δ ≤ −γV − L_fV − L_gV b_μ;  friction pyramid λ_z ≥ 0,
        |λ_x|, |λ_y| ≤ μ_f λ_z per active site (5 rows each);  τ_min ≤ τ ≤ τ_max;  δ ≥ 0,

    with A_μ = J_y Q_τ, b_μ = J_y q̈₀ + J̇_y q̇ − ÿ_d, μ_PD = −k_p e − k_d ė, W = mask ∘ weight;
    infinite bounds are ±inf."""
    e, edot = errors(meas, des)
    msk = des.mask
    kp, kd = np.asarray(gains.kp), np.asarray(gains.kd)
    A_mu = meas.J @ cond.qdd_tau
    b_mu = meas.J @ cond.qdd0 + meas.jdqd - des.yddot
    mu_pd = -kp * e - kd * edot
    W = msk * np.asarray(gains.weight)
    nu = A_mu.shape[1]
    G = clfqp.N_GROUPS
    P = np.zeros((nu + G, nu + G))
    P[:nu, :nu] = A_mu.T @ (W[:, None] * A_mu) + float(gains.w_tau) * np.eye(nu)
    P[nu:, nu:] = float(gains.w_delta) * np.eye(G)
    q = np.concatenate([A_mu.T @ (W * (b_mu - mu_pd)), np.zeros(G)])
    # one CLF per output group, summed over its rows
    V, LfV, LgV_b = np.zeros(G), np.zeros(G), np.zeros(G)
    LgV_A = np.zeros((G, nu))
    for k, rows in enumerate(outputs.GROUPS):
        ek, dk, mk, pk, vk = e[rows], edot[rows], msk[rows], kp[rows], kd[rows]
        V[k] = np.sum(mk * (pk * vk * ek ** 2 + 2 * pk * ek * dk + vk * dk ** 2))
        LfV[k] = np.sum(2 * mk * (pk * vk * ek + pk * dk) * dk)
        LgV_k = 2 * mk * (pk * ek + vk * dk)
        LgV_A[k] = LgV_k @ A_mu[rows]
        LgV_b[k] = LgV_k @ b_mu[rows]
    clf_ub = -np.asarray(gains.gamma, float) * V - LfV - LgV_b
    c0, c1 = dynamics.N_LOOP_ROWS, dynamics.N_LOOP_ROWS + dynamics.N_CONTACT_ROWS
    Lc = cond.lam_tau[c0:c1].reshape(clfqp.N_SITES, 3, nu)
    lc0 = cond.lam0[c0:c1].reshape(clfqp.N_SITES, 3)
    sel = _friction_rows(float(gains.friction))
    F = (sel @ Lc).reshape(clfqp.N_FRICTION_ROWS, nu)
    f0 = (lc0 @ sel.T).reshape(clfqp.N_FRICTION_ROWS)
    on = np.repeat(np.asarray(contact, float) > 0.5, 5)
    A = np.zeros((clfqp.n_rows(nu), nu + G))
    A[:G, :nu] = LgV_A
    A[:G, nu:] = -np.eye(G)
    A[G:G + clfqp.N_FRICTION_ROWS, :nu] = F
    A[G + clfqp.N_FRICTION_ROWS:] = np.eye(nu + G)
    l = np.concatenate([np.full(G, -np.inf), np.where(on, -f0, -np.inf), tau_min, np.zeros(G)])
    u = np.concatenate([clf_ub, np.full(clfqp.N_FRICTION_ROWS, np.inf), tau_max, np.full(G, np.inf)])
    return clfqp.Problem(P=P, q=q, A=A, l=l, u=u, V=V, Vdot_free=LfV + LgV_b, LgV_A=LgV_A)


def _pattern(mask: np.ndarray):
    """CSC structure of the boolean (r, c) ``mask``: (indptr, indices, rows, cols) with
    ``rows, cols`` the entries in CSC order (data = dense[rows, cols])."""
    cols, rows = np.nonzero(mask.T)
    indptr = np.concatenate([[0], np.cumsum(mask.sum(axis=0))]).astype(np.int64)
    return indptr, rows.astype(np.int64), rows, cols


class QPSolver:
    """OSQP on the CLF-QP's fixed sparsity pattern, one object per robot.

    Pattern (structural, independent of the values): P's upper triangle of the τ block and the
    (δ, δ) diagonal; A's CLF rows (all n columns), the friction rows' τ columns and the
    identity of the box rows.  :meth:`solve` updates (Px, q, Ax, l, u), warm-starts from the previous tick's (x, y)
    and resets ρ to ρ₀ when the last solve adapted it, so every tick starts like
    :func:`hlip_jax.core.qp.solve` (fresh ρ₀, Ruiz scaling of the new data, warm x, y)."""

    def __init__(self, nu: int, settings=clfqp.DEFAULT_SETTINGS):
        G = clfqp.N_GROUPS
        n, mrows = clfqp.n_vars(nu), clfqp.n_rows(nu)
        nf = clfqp.N_FRICTION_ROWS
        pmask = np.zeros((n, n), bool)
        pmask[np.triu_indices(nu)] = True
        pmask[np.arange(nu, n), np.arange(nu, n)] = True
        amask = np.zeros((mrows, n), bool)
        amask[:G] = True
        amask[G:G + nf, :nu] = True
        amask[G + nf:] = np.eye(n, dtype=bool)
        pi, pj, self._pr, self._pc = _pattern(pmask)
        ai, aj, self._ar, self._ac = _pattern(amask)
        P0 = sp.csc_matrix((np.where(self._pr == self._pc, 1.0, 0.0), pj, pi), shape=(n, n))
        A0 = sp.csc_matrix((np.ones(len(self._ar)), aj, ai), shape=(mrows, n))
        self.rho = float(settings.rho)
        self.osqp = osqp.OSQP()
        self.osqp.setup(
            P0, np.zeros(n), A0, np.full(mrows, -_OSQP_INFTY), np.full(mrows, _OSQP_INFTY),
            verbose=False, eps_abs=settings.eps_abs, eps_rel=settings.eps_rel,
            eps_prim_inf=settings.eps_prim_inf, eps_dual_inf=settings.eps_dual_inf,
            max_iter=settings.max_iter, rho=settings.rho, sigma=settings.sigma,
            alpha=settings.alpha, scaling=settings.scaling,
            adaptive_rho=1 if settings.adaptive_rho else 0,
            adaptive_rho_interval=settings.adaptive_rho_interval,
            adaptive_rho_tolerance=settings.adaptive_rho_tolerance,
            check_termination=settings.check_interval, check_dualgap=False,
            polishing=False, warm_starting=True, scaled_termination=False)
        self._rho_changed = False

    def solve(self, P, q, A, l, u, warm):
        """Solve at the dense problem (P, q, A, l, u) from ``warm`` = (x, y).
        Returns (x, y, status, iterations) (x, y NaN where OSQP reports infeasibility)."""
        o = self.osqp
        if self._rho_changed:
            o.update_settings(rho=self.rho)
        o.update(Px=P[self._pr, self._pc], q=q, Ax=A[self._ar, self._ac],
                 l=np.maximum(l, -_OSQP_INFTY), u=np.minimum(u, _OSQP_INFTY))
        o.warm_start(x=warm[0], y=warm[1])
        r = o.solve(raise_error=False)
        self._rho_changed = r.info.rho_updates > 0
        return r.x, r.y, int(r.info.status_val), int(r.info.iter)


# ----------------------------------------------------------------------------- robot


class TickResult(NamedTuple):
    tau: np.ndarray       # (nu,) [N m], clipped to the limits
    delta: np.ndarray     # (N_GROUPS,) CLF relaxations
    V: np.ndarray         # (N_GROUPS,) CLF values
    Vdot: np.ndarray      # (N_GROUPS,) predicted V̇_g at τ
    status: int           # OSQP status code (hlip_jax.core.qp codes)
    iterations: int


class Robot:
    """One simulated Cassie with its C MuJoCo data, OSQP object and warm start.

    ``Robot(static_)`` starts at the "stand" keyframe after ``mj_forward`` (the C analogue of
    :func:`control.canonical`); ``qpos`` / ``qvel`` override it."""

    def __init__(self, s: Static, qpos=None, qvel=None, gains: clfqp.Gains = control.STAND_GAINS,
                 settings=clfqp.DEFAULT_SETTINGS):
        self.s, self.gains = s, gains
        m = s.m
        self.d = mujoco.MjData(m)
        mujoco.mj_resetDataKeyframe(m, self.d, s.idx.stand_key)
        if qpos is not None:
            self.d.qpos[:] = qpos
        if qvel is not None:
            self.d.qvel[:] = qvel
        mujoco.mj_forward(m, self.d)
        nu = m.nu
        self.qp = QPSolver(nu, settings)
        self.warm = (np.zeros(clfqp.n_vars(nu)), np.zeros(clfqp.n_rows(nu)))
        self.contact = np.ones(4)

    def solve_M(self, Yt: np.ndarray) -> np.ndarray:
        """(M⁻¹ Y)ᵀ for Yᵀ (k, nv) C-contiguous, by ``mj_solveM`` on MuJoCo's L'DL factor (needs
        :func:`smooth` on the current state)."""
        X = np.empty_like(Yt)
        mujoco.mj_solveM(self.s.m, self.d, X, Yt)
        return X

    def control(self, des: outputs.Desired, prof: Optional[np.ndarray] = None):
        """CLF-QP torque at the current state; updates the warm start.
        Returns (TickResult, Terms, Problem).  ``prof`` (len(STAGES),) accumulates the time
        [s] of the first five stages."""
        s = self.s
        t0 = time.perf_counter()
        terms = robot_terms(s, self.d)
        t1 = time.perf_counter()
        meas = measure(terms, self.d.qvel, s.idx.root_dof)
        t2 = time.perf_counter()
        cond = condense(terms, s.B, self.contact, s.springs, self.solve_M)
        t3 = time.perf_counter()
        prob = build(meas, des, cond, self.contact, s.tau_min, s.tau_max, self.gains)
        t4 = time.perf_counter()
        x, y, status, it = self.qp.solve(prob.P, prob.q, prob.A, prob.l, prob.u, self.warm)
        # clfqp.solve (fallback=False): a non-finite result keeps the previous (x, y)
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
            x, y = self.warm
        self.warm = (np.array(x), np.array(y))
        nu = s.m.nu
        tau = np.clip(x[:nu], s.tau_min, s.tau_max)
        res = TickResult(tau=tau, delta=np.array(x[nu:]), V=np.array(prob.V),
                         Vdot=prob.Vdot_free + prob.LgV_A @ tau, status=status,
                         iterations=it)
        if prof is not None:
            t5 = time.perf_counter()
            prof[:5] += (t1 - t0, t2 - t1, t3 - t2, t4 - t3, t5 - t4)
        return res, terms, prob

    def physics(self, tau: np.ndarray, force) -> None:
        """``SUBSTEPS`` ``mj_step`` with motor torques ``tau`` (nu,) and world force ``force``
        (3,) [N] on the pelvis COM (:func:`control.physics`)."""
        d = self.d
        d.ctrl[:] = tau
        d.xfrc_applied[self.s.idx.pelvis_body, :3] = force
        for _ in range(SUBSTEPS):
            mujoco.mj_step(self.s.m, d)


class StandLog(NamedTuple):
    """Per-tick log of :func:`stand` (:class:`control.StandLog` plus the QP iterations)."""
    com: np.ndarray          # (T, 3) [m], before the tick's physics
    pelvis_z: np.ndarray     # (T,) [m], after it
    rpy: np.ndarray          # (T, 3) [rad]
    tau: np.ndarray          # (T, nu) [N m]
    V: np.ndarray            # (T,)
    status: np.ndarray       # (T,) OSQP status
    iterations: np.ndarray   # (T,) ADMM iterations


def default_target(robot: Robot) -> np.ndarray:
    """(4,) target of the standing tests: the current COM x, y, 2 cm lower, heading 0."""
    robot_terms(robot.s, robot.d)
    c = robot.d.subtree_com[robot.s.idx.pelvis_body]
    return np.array([c[0], c[1], c[2] - 0.02, 0.0])


def stand(seconds: float, target, push=None, *, robot: Optional[Robot] = None,
          prof: Optional[np.ndarray] = None) -> StandLog:
    """Simulate one standing robot for ``seconds`` (``round(seconds / CONTROL_DT)`` ticks), the
    C twin of :func:`control.stand_rollout`.

    Args:
      target: (4,) desired COM x, y, z [m] and heading [rad].
      push: optional (5,) [start s, end s, Fx, Fy, Fz N] pelvis force, on while
        start ≤ t < end with t the time at the start of the tick.
      robot: the robot to advance (default: a new one at the "stand" keyframe); its state and
        warm start carry over, so calls chain.
      prof: optional (len(STAGES),) accumulator of the time per stage [s].
    """
    robot = Robot(static(load_model())) if robot is None else robot
    target = np.asarray(target, float)
    push = np.zeros(5) if push is None else np.asarray(push, float)
    des = stand_desired(target[2], target[:2], target[3])
    n = int(round(seconds / CONTROL_DT))
    nu = robot.s.m.nu
    log = StandLog(com=np.empty((n, 3)), pelvis_z=np.empty(n), rpy=np.empty((n, 3)),
                   tau=np.empty((n, nu)), V=np.empty(n), status=np.empty(n, int),
                   iterations=np.empty(n, int))
    zero = np.zeros(3)
    for k in range(n):
        res, terms, _ = robot.control(des, prof)
        t = k * CONTROL_DT
        t0 = time.perf_counter()
        robot.physics(res.tau, push[2:] if push[0] <= t < push[1] else zero)
        if prof is not None:
            prof[5] += time.perf_counter() - t0
        log.com[k] = terms.com
        log.pelvis_z[k] = robot.d.qpos[2]
        log.rpy[k] = rpy_from_mat(terms.pelvis_R)
        log.tau[k] = res.tau
        log.V[k] = float(np.sum(res.V))
        log.status[k] = res.status
        log.iterations[k] = res.iterations
    return log


def throughput(n_ticks: int, prof: Optional[np.ndarray] = None) -> float:
    """Robot control ticks per second [1/s] of this process: one robot standing from the
    keyframe for ``n_ticks`` ticks (each = one CLF-QP + ``SUBSTEPS`` physics steps), timed
    after model loading and setup."""
    if int(n_ticks) < 1:
        raise ValueError(f"n_ticks must be ≥ 1, got {n_ticks}")
    robot = Robot(static(load_model()))
    target = default_target(robot)
    t0 = time.perf_counter()
    stand(int(n_ticks) * CONTROL_DT, target, robot=robot, prof=prof)
    return int(n_ticks) / (time.perf_counter() - t0)
