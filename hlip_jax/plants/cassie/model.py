"""Cassie model: loading (C MuJoCo and MJX), named indices and whole-body dynamics terms.

Conventions (every quantity here, unless stated otherwise):

* World frame: z up, gravity −9.81 m/s² along z; lengths [m], angles [rad], time [s].
* ``qpos`` (nq = 35): pelvis position (3) and unit quaternion w, x, y, z (4), then the
  joints of the left leg and of the right leg (:data:`LEG_JOINTS` order; the achilles ball
  joint takes 4 quaternion entries).
* ``qvel`` (nv = 32): pelvis linear velocity in the **world** frame (3), pelvis angular
  velocity in the **pelvis (body) frame** (3), then the leg dofs (achilles ball: 3, its
  angular velocity in the rod's frame). This is MuJoCo's convention; every Jacobian here maps
  this ``qvel`` to world-frame velocities.
* Equations of motion (MuJoCo's)::

      M(q) q̈ + h(q, q̇) = qfrc_passive(q, q̇) + B τ_motor + J_eqᵀ λ_eq + J_cᵀ f_contact

  with ``h`` = Coriolis + centrifugal + gravity (:func:`bias_force`), ``qfrc_passive`` the
  shin / heel springs and joint damping (:func:`passive_force`), ``B`` the nv×10 actuation
  matrix (:attr:`Cassie.actuation`; ``τ_motor`` = ``ctrl`` is motor-side torque [N m],
  joint torque = gear · ctrl) and ``J_eq`` the connect (closed-chain) Jacobian.
* Point Jacobians ``J`` are 3×nv with ``ṗ = J q̇`` (world frame, [m/s]); ``J̇q̇`` is the
  point acceleration at ``q̈ = 0`` [m/s²], so ``p̈ = J q̈ + J̇q̇``.

How ``J̇q̇`` is computed: MuJoCo stores the motion subspace of every dof as ``cdof`` (6-vectors
in the frame at the root subtree COM ``c₀``, world orientation) and its time derivative
``cdof_dot`` (computed by ``mjx.com_vel``; for the quaternion dofs of free and ball joints,
whose axes move with the body, ``cdof_dot = cvel_body ×ₘ cdof``). For a point ``p`` on body b
with ``o = p − c₀``, the Jacobian column of dof i is ``cdof_lin,i + cdof_ang,i × o`` and its
time derivative is ``ċdof_lin,i + ċdof_ang,i × o + cdof_ang,i × ȯ`` with ``ȯ`` the velocity of
p relative to c₀ (``ȯ = v_b(c₀) − o × ω_b``). This is the analytic derivative, checked against
central finite differences of ``J(q(t)) q̇`` in the tests. Ancestor masks (which dofs move which
body) are static numpy arrays, so every function is a plain array program (jit / vmap / grad).

Use with batches: every function acts on one robot's ``mjx.Data``; ``jax.vmap`` it over a
batch of data (see :func:`make_batch`). The :class:`Cassie` object is static (close over it);
pass ``mx=`` explicitly where the MJX model is itself batched or traced.
"""

from __future__ import annotations

import dataclasses
import pathlib
from typing import NamedTuple, Optional

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from hlip_jax.plants.cassie.mjx_import import mjx
from hlip_jax.plants.cassie import tree_terms
from hlip_jax.runtime import resources

ASSET_DIR = resources.data_dir("assets", "cassie")
SCENE_XML = ASSET_DIR / "scene.xml"
ROBOT_XML = ASSET_DIR / "cassie.xml"

SIDES = ("left", "right")
#: joints of one leg, root to tip, in qpos / qvel order
LEG_JOINTS = ("hip_roll", "hip_yaw", "hip_pitch", "achilles", "knee", "shin", "tarsus",
              "heel_spring", "foot_crank", "plantar_rod", "foot")
#: motored joints of one leg, in actuator order (left leg actuators 0..4, right leg 5..9)
MOTOR_JOINTS = ("hip_roll", "hip_yaw", "hip_pitch", "knee", "foot")
#: contact sites in the order used by every (4, ...) array here
CONTACT_SITES = ("left_toe", "left_heel", "right_toe", "right_heel")
#: connect constraints in the order used by every (4, ...) / (12, ...) array here
LOOPS = ("left_achilles_loop", "left_plantar_loop", "right_achilles_loop", "right_plantar_loop")
FOOT_SPHERE_RADIUS = 0.02  # [m] contact spheres; the site is the sphere centre
#: how :func:`smooth` computes the smooth terms (``impl.terms``): MJX's own stages ("mjx")
#: or :mod:`tree_terms`' dense array programs ("dense"; the same terms, no tree scatters)
TERMS = ("mjx", "dense")


class LegIndex(NamedTuple):
    """Addresses of one leg's joints (qpos addresses or dof/qvel addresses).

    For the achilles ball joint the address is its first entry (4 in qpos, 3 in qvel).
    """

    hip_roll: int
    hip_yaw: int
    hip_pitch: int
    achilles: int
    knee: int
    shin: int
    tarsus: int
    heel_spring: int
    foot_crank: int
    plantar_rod: int
    foot: int


class SideIds(NamedTuple):
    left: int
    right: int


class CassieIndex(NamedTuple):
    """Named indices into the model, all plain Python ints (hashable, usable as static args).

    ``qpos[s]`` / ``dof[s]`` are the leg addresses of side s (0 = left, 1 = right);
    ``actuators[s]`` the 5 actuator ids of that leg in :data:`MOTOR_JOINTS` order;
    ``actuated_dofs[i]`` the dof driven by actuator i; ``contact_sites`` the site ids in
    :data:`CONTACT_SITES` order; ``loops`` the equality ids in :data:`LOOPS` order.
    """

    nq: int
    nv: int
    nu: int
    root_qpos: int            # pelvis free joint: qpos[root_qpos : root_qpos + 7]
    root_dof: int             # pelvis free joint: qvel[root_dof : root_dof + 6]
    qpos: tuple               # (LegIndex left, LegIndex right)
    dof: tuple                # (LegIndex left, LegIndex right)
    actuators: tuple          # ((5 ids left), (5 ids right))
    actuated_dofs: tuple      # 10 dof addresses, actuator order
    pelvis_body: int
    foot_body: SideIds
    toe_site: SideIds
    heel_site: SideIds
    imu_site: int
    contact_sites: tuple      # 4 site ids, CONTACT_SITES order
    loops: tuple              # 4 equality ids, LOOPS order
    stand_key: int            # keyframe id of "stand"


def index_map(m: mujoco.MjModel) -> CassieIndex:
    """Builds :class:`CassieIndex` from names; raises ``KeyError`` naming what is missing."""

    def _id(kind, name):
        i = mujoco.mj_name2id(m, kind, name)
        if i < 0:
            raise KeyError(f"Cassie model has no {kind.name[5:].lower()} named {name!r}")
        return int(i)

    J = mujoco.mjtObj.mjOBJ_JOINT
    legs_q, legs_v, acts = [], [], []
    for side in SIDES:
        ids = [_id(J, f"{side}_{j}") for j in LEG_JOINTS]
        legs_q.append(LegIndex(*[int(m.jnt_qposadr[i]) for i in ids]))
        legs_v.append(LegIndex(*[int(m.jnt_dofadr[i]) for i in ids]))
        acts.append(tuple(_id(mujoco.mjtObj.mjOBJ_ACTUATOR, f"{side}_{j}") for j in MOTOR_JOINTS))
    actuated = []
    for a in range(m.nu):
        if m.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_JOINT:
            raise ValueError(f"actuator {a} must drive a joint")
        actuated.append(int(m.jnt_dofadr[m.actuator_trnid[a, 0]]))
    root = _id(J, "root")
    S = mujoco.mjtObj.mjOBJ_SITE
    B = mujoco.mjtObj.mjOBJ_BODY
    return CassieIndex(
        nq=int(m.nq), nv=int(m.nv), nu=int(m.nu),
        root_qpos=int(m.jnt_qposadr[root]), root_dof=int(m.jnt_dofadr[root]),
        qpos=tuple(legs_q), dof=tuple(legs_v), actuators=tuple(acts),
        actuated_dofs=tuple(actuated),
        pelvis_body=_id(B, "pelvis"),
        foot_body=SideIds(_id(B, "left_foot"), _id(B, "right_foot")),
        toe_site=SideIds(_id(S, "left_toe"), _id(S, "right_toe")),
        heel_site=SideIds(_id(S, "left_heel"), _id(S, "right_heel")),
        imu_site=_id(S, "imu"),
        contact_sites=tuple(_id(S, n) for n in CONTACT_SITES),
        loops=tuple(_id(mujoco.mjtObj.mjOBJ_EQUALITY, n) for n in LOOPS),
        stand_key=_id(mujoco.mjtObj.mjOBJ_KEY, "stand"),
    )


def actuation_matrix(m: mujoco.MjModel) -> np.ndarray:
    """``B`` (nv, nu): generalized force = ``B @ ctrl``; column i has the gear of actuator i
    at the dof it drives (joint torque [N m] per motor torque [N m])."""
    B = np.zeros((m.nv, m.nu))
    for a in range(m.nu):
        B[m.jnt_dofadr[m.actuator_trnid[a, 0]], a] = m.actuator_gear[a, 0]
    return B


@dataclasses.dataclass(frozen=True, eq=False)
class Cassie:
    """The loaded model: C model, MJX model, indices and static numpy constants.

    Hashes by identity, so it can be closed over or passed as a static jit argument.
    """

    mj_model: mujoco.MjModel
    mjx_model: mjx.Model
    index: CassieIndex
    actuation: np.ndarray        # (nv, nu) actuation matrix B
    ctrl_range: np.ndarray       # (nu, 2) motor torque limits [N m] (ctrl units)
    joint_torque_limit: np.ndarray  # (nu,) |gear * ctrl| limit [N m] at the joint
    stand_qpos: np.ndarray       # (nq,) "stand" keyframe
    total_mass: float            # [kg]
    body_mask: np.ndarray        # (nbody, nv) ancestor mask: 1 where the dof moves the body
    body_mass: np.ndarray        # (nbody,) [kg]
    loop_body1: np.ndarray       # (4,) rod body of each loop
    loop_body2: np.ndarray       # (4,) partner body (heel spring / foot)
    loop_anchor1: np.ndarray     # (4, 3) anchor in body1's frame [m]
    loop_anchor2: np.ndarray     # (4, 3) anchor in body2's frame [m]
    site_body: np.ndarray        # (nsite,) body of each site
    tree: tree_terms.Tree        # static topology of the dense smooth terms


def put(m: mujoco.MjModel, impl: str):
    """``mjx.put_model`` on this process's first device.  MJX's own default is
    ``jax.devices()[0]``, which after ``jax.distributed.initialize`` is process 0's device: in
    every other process the model would then live on a device it cannot address, and the
    closed loop could not be compiled there."""
    return mjx.put_model(m, impl=impl, device=jax.local_devices()[0])


def load(path: Optional[str | pathlib.Path] = None, impl: str = "jax") -> Cassie:
    """Loads ``scene.xml`` (or ``path``) into C MuJoCo and MJX (:func:`put`)."""
    path = pathlib.Path(path) if path is not None else SCENE_XML
    if not path.is_file():
        raise FileNotFoundError(f"path: no MJCF file at {path}")
    m = mujoco.MjModel.from_xml_path(str(path))
    idx = index_map(m)
    mx = put(m, impl)
    gear = m.actuator_gear[:, 0].copy()
    loops = np.array(idx.loops)
    tree = tree_terms.tree_of(m)
    return Cassie(
        mj_model=m, mjx_model=mx, index=idx,
        actuation=actuation_matrix(m),
        ctrl_range=m.actuator_ctrlrange.copy(),
        joint_torque_limit=gear * np.abs(m.actuator_ctrlrange).max(axis=1),
        stand_qpos=m.key_qpos[idx.stand_key].copy(),
        total_mass=float(m.body_subtreemass[idx.pelvis_body]),
        body_mask=tree.moves, body_mass=m.body_mass.copy(),
        loop_body1=m.eq_obj1id[loops].copy(), loop_body2=m.eq_obj2id[loops].copy(),
        loop_anchor1=m.eq_data[loops, 0:3].copy(), loop_anchor2=m.eq_data[loops, 3:6].copy(),
        site_body=m.site_bodyid.copy(), tree=tree,
    )


# ----------------------------------------------------------------------------- data


def stance_projection(cassie: Cassie, qpos: np.ndarray, tol: float = 1e-9,
                      max_iter: int = 30) -> tuple[np.ndarray, np.ndarray]:
    """Close the chains and put both soles flat on the floor, changing ``qpos`` (B, nq) as
    little as possible (C MuJoCo, numpy).

    Constraints c(q) = 0: the 4 connect loops (12 rows, anchor of body 1 minus anchor of body 2,
    world frame) and the height of the 4 contact-sphere centres above the floor minus their
    radius (4 rows).  Gauss–Newton with the minimum-norm step in velocity coordinates,
    Δv = −J⁺ c(q), q ← q ⊕ Δv (``mj_integratePos``, so the pelvis quaternion stays unit), until
    ‖c‖∞ ≤ ``tol`` [m].  Returns (projected qpos, final ‖c‖∞ per robot [m]).

    Random hinge offsets alone leave the loops open and the feet inside or above the floor; the
    simulator then snaps them in the first milliseconds with constraint forces no controller
    sees coming.  The projection makes a randomised *consistent* standing state instead.
    """
    m = cassie.mj_model
    d = mujoco.MjData(m)
    qpos = np.array(qpos, float, copy=True).reshape(-1, m.nq)
    loops = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_EQUALITY, n) for n in LOOPS]
    sites = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, n) for n in CONTACT_SITES]
    jp1, jp2 = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    res = np.zeros(len(qpos))
    for b in range(len(qpos)):
        d.qpos[:] = qpos[b]
        for it in range(max_iter + 1):
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            c, J = [], []
            for e in loops:
                b1, b2 = m.eq_obj1id[e], m.eq_obj2id[e]
                p1 = d.xpos[b1] + d.xmat[b1].reshape(3, 3) @ m.eq_data[e, 0:3]
                p2 = d.xpos[b2] + d.xmat[b2].reshape(3, 3) @ m.eq_data[e, 3:6]
                mujoco.mj_jac(m, d, jp1, None, p1, b1)
                mujoco.mj_jac(m, d, jp2, None, p2, b2)
                c.append(p1 - p2)
                J.append(jp1 - jp2)
            for s in sites:
                mujoco.mj_jacSite(m, d, jp1, None, s)
                c.append([d.site_xpos[s, 2] - FOOT_SPHERE_RADIUS])
                J.append(jp1[2:3].copy())
            c, J = np.concatenate(c), np.concatenate(J)
            res[b] = np.abs(c).max()
            if res[b] <= tol or it == max_iter:
                break
            dv = -np.linalg.lstsq(J, c, rcond=None)[0]
            mujoco.mj_integratePos(m, d.qpos, dv, 1.0)
        qpos[b] = d.qpos
    return qpos, res


def make_batch(cassie: Cassie, batch_size: int, key: jax.Array, qpos_noise: float = 0.0,
               qvel_noise: float = 0.0, forward: bool = False,
               consistent: bool = False) -> mjx.Data:
    """Batched ``mjx.Data`` (leading axis ``batch_size``) at the "stand" keyframe.

    Args:
      batch_size: number of robots, ≥ 1.
      key: jax PRNG key for the offsets.
      qpos_noise: half-width [rad] of uniform offsets added to every hinge joint (pelvis and
        achilles quaternions untouched). Non-zero offsets open the closed chains by about
        this much times the link lengths; the constraint solver pulls them shut in the first
        few milliseconds of simulation.
      qvel_noise: half-width [m/s or rad/s] of uniform offsets added to every dof velocity.
      consistent: pass the offset configurations through :func:`stance_projection` (chains
        closed, both soles flat on the floor; the offsets stay up to the minimum-norm change).
      forward: run ``mjx.forward`` (vmapped, one extra compile) so the derived fields
        (positions, contacts, qacc) belong to the offset state; by default they are those of
        the unperturbed keyframe (``mjx.step`` and :func:`smooth` recompute them anyway).
    """
    if int(batch_size) < 1:
        raise ValueError(f"batch_size must be ≥ 1, got {batch_size}")
    if qpos_noise < 0 or qvel_noise < 0:
        raise ValueError(f"qpos_noise and qvel_noise must be ≥ 0, got {qpos_noise}, {qvel_noise}")
    m = cassie.mj_model
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, cassie.index.stand_key)
    mujoco.mj_forward(m, d)
    dx = mjx.put_data(m, d, impl=cassie.mjx_model.impl)
    hinge = np.array([m.jnt_qposadr[j] for j in range(m.njnt)
                      if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE])
    k1, k2 = jax.random.split(key)
    dtype = dx.qpos.dtype
    qpos = jnp.broadcast_to(dx.qpos, (batch_size, m.nq))
    dq = jax.random.uniform(k1, (batch_size, hinge.size), dtype, -qpos_noise, qpos_noise)
    qpos = qpos.at[:, hinge].add(dq)
    if consistent:
        proj, res = stance_projection(cassie, np.asarray(qpos))
        if np.any(res > 1e-6):
            raise ValueError(f"qpos_noise = {qpos_noise}: {int(np.sum(res > 1e-6))} of {batch_size} "
                             f"offset configurations cannot be projected onto closed chains with "
                             f"both feet on the floor (residual up to {res.max():.3g} m); use a "
                             f"smaller qpos_noise (0.03 rad projects to 1e-9 m)")
        qpos = jnp.asarray(proj, dtype)
    qvel = jax.random.uniform(k2, (batch_size, m.nv), dtype, -qvel_noise, qvel_noise)
    batch = jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (batch_size,) + x.shape), dx)
    batch = batch.replace(qpos=qpos, qvel=qvel)
    if forward:
        mx = cassie.mjx_model
        batch = jax.jit(jax.vmap(mjx.forward, in_axes=(None, 0)))(mx, batch)
    return batch


def smooth(cassie: Cassie, d: mjx.Data, mx: Optional[mjx.Model] = None,
           terms: str = "mjx") -> tree_terms.Smooth:
    """Position- and velocity-dependent smooth quantities for ``d.qpos``, ``d.qvel``.

    Kinematics, COM positions, composite inertia (mass matrix), COM velocities
    (``cdof_dot``), passive forces and RNE bias — no collision, no constraint solve — by
    MJX's stages (``terms = "mjx"``) or by :func:`tree_terms.smooth` (``"dense"``; equal to C
    MuJoCo's within float rounding, ``tests/test_tree_terms.py``).  Call it on a state before
    the functions below (after ``mjx.step`` the stored kinematics belong to the *previous*
    qpos); they read only its fields (the same names on ``mjx.Data``).
    """
    if terms not in TERMS:
        raise ValueError(f"terms: {terms!r}; allowed: {TERMS}")
    mx = cassie.mjx_model if mx is None else mx
    if terms == "dense":
        return tree_terms.smooth(cassie.tree, mx, d.qpos, d.qvel)
    d = mjx.kinematics(mx, d)
    d = mjx.com_pos(mx, d)
    d = mjx.crb(mx, d)
    d = mjx.com_vel(mx, d)
    d = mjx.passive(mx, d)
    d = mjx.rne(mx, d)
    return tree_terms.Smooth(**{f: (mjx.full_m(mx, d) if f == "qM" else getattr(d, f))
                                for f in tree_terms.Smooth._fields})


# ----------------------------------------------------------------------------- dynamics


def bias_force(d: mjx.Data) -> jax.Array:
    """h(q, q̇) (nv,): Coriolis, centrifugal and gravity generalized force (needs :func:`smooth`)."""
    return d.qfrc_bias


def passive_force(d: mjx.Data) -> jax.Array:
    """Spring (shin 1500, heel 1250 N m/rad) and damping generalized force (nv,)."""
    return d.qfrc_passive


# ----------------------------------------------------------------------------- points


def _root_com(cassie, d):
    return d.subtree_com[cassie.index.pelvis_body]


def _cdof_dot(cassie, d):
    """Time derivative of the dof motion axes, quaternion dofs handled as body-fixed axes."""
    m = cassie.mj_model
    jt = m.jnt_type[m.dof_jntid]
    first = m.jnt_dofadr[m.dof_jntid]
    is_quat = (jt == mujoco.mjtJoint.mjJNT_BALL) | (
        (jt == mujoco.mjtJoint.mjJNT_FREE) & (np.arange(m.nv) >= first + 3))
    cvel = d.cvel[m.dof_bodyid]                      # (nv, 6) [ang, lin]
    ang, lin = cvel[:, :3], cvel[:, 3:]
    c_ang, c_lin = d.cdof[:, :3], d.cdof[:, 3:]
    # spatial motion cross product  v ×ₘ s = [ω × s_ang, ω × s_lin + v × s_ang]
    quat_dot = jnp.concatenate([jnp.cross(ang, c_ang), jnp.cross(ang, c_lin) + jnp.cross(lin, c_ang)], -1)
    return jnp.where(is_quat[:, None], quat_dot, d.cdof_dot)


def point_jacobians(cassie: Cassie, d: mjx.Data, points: jax.Array, bodies) -> jax.Array:
    """Translational Jacobians (k, 3, nv) of world points ``points`` (k, 3) fixed to static
    body ids ``bodies`` (length k, Python ints). Needs :func:`smooth`."""
    bodies = np.asarray(bodies, dtype=int)
    mask = jnp.asarray(cassie.body_mask[bodies])                   # (k, nv)
    o = points - _root_com(cassie, d)                              # (k, 3)
    cang, clin = d.cdof[:, :3], d.cdof[:, 3:]                      # (nv, 3)
    cols = clin[None] + jnp.cross(cang[None], o[:, None, :])       # (k, nv, 3)
    return jnp.swapaxes(cols * mask[..., None], 1, 2)


def point_jdot_qdot(cassie: Cassie, d: mjx.Data, points: jax.Array, bodies) -> jax.Array:
    """``J̇ q̇`` (k, 3) [m/s²] of world points fixed to static bodies (see module docstring)."""
    bodies = np.asarray(bodies, dtype=int)
    mask = jnp.asarray(cassie.body_mask[bodies])
    o = points - _root_com(cassie, d)
    cvel = d.cvel[bodies]
    odot = cvel[:, 3:] - jnp.cross(o, cvel[:, :3])                 # velocity of p rel. c₀ frame
    cdd = _cdof_dot(cassie, d)
    cang, cdang, cdlin = d.cdof[:, :3], cdd[:, :3], cdd[:, 3:]
    cols = (cdlin[None] + jnp.cross(cdang[None], o[:, None, :])
            + jnp.cross(cang[None], odot[:, None, :]))              # (k, nv, 3)
    return jnp.einsum("knj,kn,n->kj", cols, mask, d.qvel)


def angular_jacobians(cassie: Cassie, d: mjx.Data, bodies) -> jax.Array:
    """Rotational Jacobians (k, 3, nv) of static bodies: ω_world = J_ω q̇ [rad/s]."""
    mask = jnp.asarray(cassie.body_mask[np.asarray(bodies, dtype=int)])
    return jnp.swapaxes(d.cdof[None, :, :3] * mask[..., None], 1, 2)


def angular_jdot_qdot(cassie: Cassie, d: mjx.Data, bodies) -> jax.Array:
    """``J̇_ω q̇`` (k, 3) [rad/s²]: world angular acceleration of static bodies at q̈ = 0."""
    mask = jnp.asarray(cassie.body_mask[np.asarray(bodies, dtype=int)])
    return jnp.einsum("nj,kn,n->kj", _cdof_dot(cassie, d)[:, :3], mask, d.qvel)


def site_positions(cassie: Cassie, d: mjx.Data, sites=None) -> jax.Array:
    """World positions (k, 3) of sites (default: the 4 contact sites, toe/heel L/R)."""
    sites = cassie.index.contact_sites if sites is None else sites
    return d.site_xpos[np.asarray(sites)]


def site_jacobians(cassie: Cassie, d: mjx.Data, sites=None) -> jax.Array:
    """Jacobians (k, 3, nv) of site origins (default: the 4 contact sites)."""
    sites = np.asarray(cassie.index.contact_sites if sites is None else sites)
    return point_jacobians(cassie, d, d.site_xpos[sites], cassie.site_body[sites])


def site_jdot_qdot(cassie: Cassie, d: mjx.Data, sites=None) -> jax.Array:
    """``J̇ q̇`` (k, 3) [m/s²] of site origins (default: the 4 contact sites)."""
    sites = np.asarray(cassie.index.contact_sites if sites is None else sites)
    return point_jdot_qdot(cassie, d, d.site_xpos[sites], cassie.site_body[sites])


# ----------------------------------------------------------------------------- COM


def com_position(cassie: Cassie, d: mjx.Data) -> jax.Array:
    """Whole-robot centre of mass (3,) [m], world frame (needs :func:`smooth`)."""
    return _root_com(cassie, d)


def com_jacobian(cassie: Cassie, d: mjx.Data) -> jax.Array:
    """COM Jacobian (3, nv): ċ = J_c q̇, the mass-weighted mean of body-COM Jacobians."""
    bodies = np.arange(1, cassie.mj_model.nbody)
    w = jnp.asarray(cassie.body_mass[bodies] / cassie.total_mass)
    J = point_jacobians(cassie, d, d.xipos[bodies], bodies)
    return jnp.einsum("b,bjn->jn", w, J)


def com_velocity(cassie: Cassie, d: mjx.Data) -> jax.Array:
    """COM velocity (3,) [m/s], world frame."""
    return com_jacobian(cassie, d) @ d.qvel


def com_jdot_qdot(cassie: Cassie, d: mjx.Data) -> jax.Array:
    """``J̇_c q̇`` (3,) [m/s²]: COM acceleration at q̈ = 0."""
    bodies = np.arange(1, cassie.mj_model.nbody)
    w = jnp.asarray(cassie.body_mass[bodies] / cassie.total_mass)
    return w @ point_jdot_qdot(cassie, d, d.xipos[bodies], bodies)


# ----------------------------------------------------------------------------- closed chains


def _loop_points(cassie, d):
    b1, b2 = cassie.loop_body1, cassie.loop_body2
    p1 = d.xpos[b1] + jnp.einsum("kij,kj->ki", d.xmat[b1], jnp.asarray(cassie.loop_anchor1))
    p2 = d.xpos[b2] + jnp.einsum("kij,kj->ki", d.xmat[b2], jnp.asarray(cassie.loop_anchor2))
    return p1, p2


def loop_residual(cassie: Cassie, d: mjx.Data) -> jax.Array:
    """Connect-constraint violation (12,) [m]: rod tip − partner point, 4 loops × xyz
    (:data:`LOOPS` order); zero when every closed chain is closed."""
    p1, p2 = _loop_points(cassie, d)
    return (p1 - p2).reshape(-1)


def loop_jacobian(cassie: Cassie, d: mjx.Data) -> jax.Array:
    """Jacobian (12, nv) of :func:`loop_residual` (same rows as MuJoCo's connect rows)."""
    p1, p2 = _loop_points(cassie, d)
    J = (point_jacobians(cassie, d, p1, cassie.loop_body1)
         - point_jacobians(cassie, d, p2, cassie.loop_body2))
    return J.reshape(-1, J.shape[-1])


def loop_jdot_qdot(cassie: Cassie, d: mjx.Data) -> jax.Array:
    """``J̇_eq q̇`` (12,) [m/s²]; holding the chains closed means J_eq q̈ + J̇_eq q̇ = 0."""
    p1, p2 = _loop_points(cassie, d)
    a = (point_jdot_qdot(cassie, d, p1, cassie.loop_body1)
         - point_jdot_qdot(cassie, d, p2, cassie.loop_body2))
    return a.reshape(-1)


# ----------------------------------------------------------------------------- orientation


def pelvis_rotation(cassie: Cassie, d: mjx.Data) -> jax.Array:
    """Pelvis rotation matrix (3, 3), body → world (from ``qpos``, no kinematics needed)."""
    q = d.qpos[cassie.index.root_qpos + 3: cassie.index.root_qpos + 7]
    return quat_to_mat(q / jnp.linalg.norm(q))


def foot_rotations(cassie: Cassie, d: mjx.Data) -> jax.Array:
    """Sole frames (2, 3, 3) of the left and right foot, sole → world: x heel→toe,
    z normal to the sole (identity for a flat foot facing +x). Needs :func:`smooth`."""
    return d.site_xmat[np.asarray(cassie.index.toe_site)]


def foot_yaw(cassie: Cassie, d: mjx.Data) -> jax.Array:
    """Heading (2,) [rad] of each foot's heel→toe direction in the ground plane."""
    R = foot_rotations(cassie, d)
    return jnp.arctan2(R[:, 1, 0], R[:, 0, 0])


def quat_to_mat(q: jax.Array) -> jax.Array:
    """Unit quaternion (w, x, y, z) → rotation matrix (3, 3)."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    return jnp.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def rpy_from_mat(R: jax.Array) -> jax.Array:
    """(roll, pitch, yaw) [rad] with R = Rz(yaw) Ry(pitch) Rx(roll); pitch in [−π/2, π/2]."""
    roll = jnp.arctan2(R[2, 1], R[2, 2])
    pitch = jnp.arcsin(jnp.clip(-R[2, 0], -1.0, 1.0))
    yaw = jnp.arctan2(R[1, 0], R[0, 0])
    return jnp.stack([roll, pitch, yaw])


# ----------------------------------------------------------------------------- all at once


class RobotTerms(NamedTuple):
    """Everything a whole-body controller needs at one state (single robot; world frame).

    Arrays with a leading 4 follow :data:`CONTACT_SITES` (left toe, left heel, right toe,
    right heel); with a leading 2, (left, right).
    """

    M: jax.Array            # (nv, nv) mass matrix [kg, kg m, kg m²]
    bias: jax.Array         # (nv,) h = Coriolis + centrifugal + gravity
    passive: jax.Array      # (nv,) springs + damping
    com: jax.Array          # (3,) [m]
    com_vel: jax.Array      # (3,) [m/s]
    com_J: jax.Array        # (3, nv)
    com_jdqd: jax.Array     # (3,) [m/s²]
    site_pos: jax.Array     # (4, 3) contact-sphere centres [m]
    site_J: jax.Array       # (4, 3, nv)
    site_jdqd: jax.Array    # (4, 3) [m/s²]
    loop_res: jax.Array     # (12,) [m]
    loop_J: jax.Array       # (12, nv)
    loop_jdqd: jax.Array    # (12,) [m/s²]
    pelvis_R: jax.Array     # (3, 3) pelvis → world
    pelvis_omega: jax.Array  # (3,) pelvis angular velocity, world frame [rad/s]
    pelvis_Jw: jax.Array    # (3, nv) ω_pelvis = pelvis_Jw q̇ (world frame)
    pelvis_Jw_dqd: jax.Array  # (3,) [rad/s²] (zero: the free joint's axes are body-fixed)
    foot_R: jax.Array       # (2, 3, 3) sole → world
    foot_yaw: jax.Array     # (2,) [rad]
    foot_Jw: jax.Array      # (2, 3, nv) foot angular-velocity Jacobians (world frame)
    foot_Jw_dqd: jax.Array  # (2, 3) [rad/s²]
    ankle: jax.Array        # (2, 3) foot-joint (ankle pivot) positions [m]: the foot body origins


class FootContact(NamedTuple):
    """Toe and heel rows of one foot (rows: toe, heel)."""

    pos: jax.Array    # (2, 3) sphere centres [m]
    J: jax.Array      # (2, 3, nv)
    jdqd: jax.Array   # (2, 3) [m/s²]


def foot_contact(terms: RobotTerms, side) -> FootContact:
    """Toe/heel rows of foot ``side`` (0 = left, 1 = right; may be a traced int)."""
    nv = terms.site_J.shape[-1]
    return FootContact(
        pos=terms.site_pos.reshape(2, 2, 3)[side],
        J=terms.site_J.reshape(2, 2, 3, nv)[side],
        jdqd=terms.site_jdqd.reshape(2, 2, 3)[side],
    )


def robot_terms(cassie: Cassie, d: mjx.Data, mx: Optional[mjx.Model] = None,
                terms: str = "mjx") -> RobotTerms:
    """Runs :func:`smooth` on ``d`` (its qpos, qvel; ``terms`` as there, static) and gathers
    :class:`RobotTerms`."""
    d = smooth(cassie, d, mx, terms)
    R = pelvis_rotation(cassie, d)
    w = d.qvel[cassie.index.root_dof + 3: cassie.index.root_dof + 6]
    pelvis, feet = cassie.index.pelvis_body, list(cassie.index.foot_body)
    return RobotTerms(
        M=d.qM, bias=bias_force(d), passive=passive_force(d),
        com=com_position(cassie, d), com_vel=com_velocity(cassie, d),
        com_J=com_jacobian(cassie, d), com_jdqd=com_jdot_qdot(cassie, d),
        site_pos=site_positions(cassie, d), site_J=site_jacobians(cassie, d),
        site_jdqd=site_jdot_qdot(cassie, d),
        loop_res=loop_residual(cassie, d), loop_J=loop_jacobian(cassie, d),
        loop_jdqd=loop_jdot_qdot(cassie, d),
        pelvis_R=R, pelvis_omega=R @ w,
        pelvis_Jw=angular_jacobians(cassie, d, [pelvis])[0],
        pelvis_Jw_dqd=angular_jdot_qdot(cassie, d, [pelvis])[0],
        foot_R=foot_rotations(cassie, d), foot_yaw=foot_yaw(cassie, d),
        foot_Jw=angular_jacobians(cassie, d, feet),
        foot_Jw_dqd=angular_jdot_qdot(cassie, d, feet),
        ankle=d.xpos[jnp.array(feet)],
    )
