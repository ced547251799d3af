"""MuJoCo's smooth dynamics of one fixed kinematic tree as dense array programs.

The controller needs, at the measured state, what MuJoCo's ``mj_kinematics``, ``mj_comPos``,
``mj_crb``, ``mj_comVel``, ``mj_passive`` and ``mj_rne`` compute: body and site poses, the
dof motion axes ``cdof`` and their derivatives, body velocities, the mass matrix M, the bias
force h and the passive force.  MJX computes them with scans over the body tree whose
reverse accumulations are ``segment_sum`` scatters, and its hinge quaternions are built
with scatters too; under XLA's deterministic GPU operations (the CLI's) every such scatter
is sorted first (docs/benchmarks/cassie_gpu.md, "Both physics backends").  Here the tree is static, so each
accumulation is a product with a constant 0/1 matrix instead:

    subtree sums      Σ_{c ∈ subtree(b)} x_c          = S x,        S[b, c] = 1 if b ≼ c
    body velocities   cvel_b = Σ_{i moves b} cdof_i q̇_i  = A (cdof ∘ q̇),  A[b, i] = 1 if dof i moves b
    mass matrix       M_ij = cdof_iᵀ I^c_{b(i)} cdof_j  for j on i's dof chain (i ≥ j), mirrored,
                      plus the armature on the diagonal, I^c = S I the composite inertias,

and the forward pass that places the bodies is a Python loop over the (static) bodies, each a
few 3 × 3 products.  Conventions are MuJoCo's (spatial vectors [angular, linear] at the root
subtree's centre of mass, world orientation; ``cdof_dot`` of a free joint's rotational dofs and
of a ball joint's dofs use the body velocity before those dofs, as ``mj_comVel`` does).  The
bias is RNE with the base acceleration −g:

    a_b = [0, −g] + Σ_{i moves b} ċdof_i q̇_i,   f_b = I_b a_b + v_b ×* (I_b v_b),
    h_i = cdof_i · (S f)_{b(i)},

and the passive force −k (q − q_spring) − d q̇ (hinge springs, dof damping).  Every numeric
parameter is read from the MJX model passed in (so edited masses or damping carry over); only
the topology comes from the C model.  Checked against C MuJoCo in ``tests/test_tree_terms.py``.
Pure jax; jit / vmap-able.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

FREE, BALL, SLIDE, HINGE = (int(mujoco.mjtJoint.mjJNT_FREE), int(mujoco.mjtJoint.mjJNT_BALL),
                            int(mujoco.mjtJoint.mjJNT_SLIDE), int(mujoco.mjtJoint.mjJNT_HINGE))


@dataclasses.dataclass(frozen=True, eq=False)
class Tree:
    """Static topology of a model (numpy; hashes by identity).

    parent: parent body of each body (nbody,); body_joints: joint ids of each body (tuples);
    jnt_type, jnt_qposadr, jnt_dofadr: per joint (njnt,); dof_body: body of each dof (nv,);
    moves: A (nbody, nv), 1 where the dof moves the body; subtree: S (nbody, nbody), 1 where
    the column body is in the row body's subtree (itself included); chain: (nv, nv), 1 where
    the column dof is on the row dof's chain to the root (itself included); before: (nv, nv),
    1 where the column dof's motion enters the velocity that ``cdof_dot`` of the row dof
    crosses; root: root body of each body (nbody,); site_body: (nsite,); hinge_jnts,
    hinge_qpos: the hinge and slide joints (springs) and their qpos addresses; hinge_onehot:
    (nv, number of them), 1 at each one's dof."""

    parent: np.ndarray
    body_joints: tuple
    jnt_type: np.ndarray
    jnt_qposadr: np.ndarray
    jnt_dofadr: np.ndarray
    dof_body: np.ndarray
    moves: np.ndarray
    subtree: np.ndarray
    chain: np.ndarray
    before: np.ndarray
    root: np.ndarray
    site_body: np.ndarray
    hinge_jnts: np.ndarray
    hinge_qpos: np.ndarray
    hinge_onehot: np.ndarray


def _chain(m: mujoco.MjModel) -> np.ndarray:
    chain = np.zeros((m.nv, m.nv))
    for i in range(m.nv):
        j = i
        while j >= 0:
            chain[i, j] = 1.0
            j = m.dof_parentid[j]
    return chain


def _before(m: mujoco.MjModel, chain: np.ndarray) -> np.ndarray:
    """Row i: the dofs of the bodies strictly above dof i's body and of the joints before dof
    i's joint in the same body, plus, for a free joint's rotational dofs, its translational
    ones (``mj_comVel``'s order of accumulation: a joint's dofs all see the velocity before
    that joint, except the free joint's rotations, which see its translation)."""
    before = chain * (m.dof_bodyid[None, :] != m.dof_bodyid[:, None])
    width = {FREE: 6, BALL: 3}
    for j in range(m.njnt):
        a = m.jnt_dofadr[j]
        rows = slice(a, a + width.get(int(m.jnt_type[j]), 1))
        before[rows, (m.dof_bodyid == m.dof_bodyid[a]) & (np.arange(m.nv) < a)] = 1.0
        if m.jnt_type[j] == FREE:
            before[a + 3:a + 6, a:a + 3] = 1.0
    return before


def tree_of(m: mujoco.MjModel) -> Tree:
    """The static :class:`Tree` of a C model.  Raises ``ValueError`` for what the dense terms do
    not model: springs on free or ball joints, gravity compensation, fluid forces."""
    stiff = m.jnt_stiffness[np.isin(m.jnt_type, (FREE, BALL))]
    if np.any(stiff != 0):
        raise ValueError("jnt_stiffness: free and ball joints must have none (0); got "
                         f"{stiff[stiff != 0].tolist()}")
    if np.any(m.body_gravcomp != 0) or m.opt.density != 0 or m.opt.viscosity != 0:
        raise ValueError("body_gravcomp, opt.density, opt.viscosity: must be 0 for the dense terms")
    off = mujoco.mjtDisableBit
    if m.opt.disableflags & (off.mjDSBL_GRAVITY | off.mjDSBL_SPRING | off.mjDSBL_DAMPER):
        raise ValueError("opt.disableflags: gravity, springs and dampers must stay enabled for "
                         "the dense terms")
    moves = np.zeros((m.nbody, m.nv))
    subtree = np.zeros((m.nbody, m.nbody))
    for b in range(m.nbody):
        a = b
        while True:
            subtree[a, b] = 1.0
            if a == 0:
                break
            moves[b, m.dof_bodyid == a] = 1.0
            a = m.body_parentid[a]
    chain = _chain(m)
    hinge = np.flatnonzero(np.isin(m.jnt_type, (HINGE, SLIDE)))
    return Tree(
        parent=m.body_parentid.copy(),
        body_joints=tuple(tuple(range(m.body_jntadr[b], m.body_jntadr[b] + m.body_jntnum[b]))
                          for b in range(m.nbody)),
        jnt_type=m.jnt_type.copy(), jnt_qposadr=m.jnt_qposadr.copy(),
        jnt_dofadr=m.jnt_dofadr.copy(), dof_body=m.dof_bodyid.copy(), moves=moves,
        subtree=subtree, chain=chain, before=_before(m, chain), root=m.body_rootid.copy(),
        site_body=m.site_bodyid.copy(), hinge_jnts=hinge, hinge_qpos=m.jnt_qposadr[hinge].copy(),
        hinge_onehot=np.eye(m.nv)[:, m.jnt_dofadr[hinge]])


class Smooth(NamedTuple):
    """The smooth terms at one state (single robot; MuJoCo's field names and frames).

    qpos: (nq,) the state's positions, quaternions normalised
    qvel: (nv,) the state's velocities
    xpos, xmat: (nbody, 3), (nbody, 3, 3) body frames, world [m]
    xipos, ximat: (nbody, 3), (nbody, 3, 3) body inertial frames (centre of mass) [m]
    site_xpos, site_xmat: (nsite, 3), (nsite, 3, 3) site frames [m]
    subtree_com: (nbody, 3) centre of mass of each body's subtree [m]
    cdof: (nv, 6) dof motion axes [angular; linear] at the root subtree's centre of mass
    cdof_dot: (nv, 6) their time derivatives (``mj_comVel``'s convention)
    cvel: (nbody, 6) body velocities [rad/s; m/s] at the root subtree's centre of mass
    qM: (nv, nv) mass matrix, armature included [kg, kg m, kg m²]
    qfrc_bias: (nv,) h = Coriolis + centrifugal + gravity
    qfrc_passive: (nv,) springs and damping
    """

    qpos: jax.Array
    qvel: jax.Array
    xpos: jax.Array
    xmat: jax.Array
    xipos: jax.Array
    ximat: jax.Array
    site_xpos: jax.Array
    site_xmat: jax.Array
    subtree_com: jax.Array
    cdof: jax.Array
    cdof_dot: jax.Array
    cvel: jax.Array
    qM: jax.Array
    qfrc_bias: jax.Array
    qfrc_passive: jax.Array


def quat_mats(q: jax.Array) -> jax.Array:
    """Quaternions (..., 4) (w, x, y, z; normalised here) → rotation matrices (..., 3, 3)."""
    q = q / jnp.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    rows = [[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]]
    return jnp.stack([jnp.stack(r, axis=-1) for r in rows], axis=-2)


def axis_rotation(axis: jax.Array, angle: jax.Array) -> jax.Array:
    """Rotation (3, 3) by ``angle`` [rad] about the unit ``axis`` (3,): I + sin θ K + (1 − cos θ) K²,
    K the cross-product matrix of the axis (Rodrigues)."""
    K = cross_matrix(axis)
    return jnp.eye(3, dtype=K.dtype) + jnp.sin(angle) * K + (1.0 - jnp.cos(angle)) * (K @ K)


def cross_matrix(a: jax.Array) -> jax.Array:
    """[a]× (..., 3, 3) with [a]× b = a × b."""
    z = jnp.zeros_like(a[..., 0])
    x, y, w = a[..., 0], a[..., 1], a[..., 2]
    return jnp.stack([jnp.stack([z, -w, y], -1), jnp.stack([w, z, -x], -1),
                      jnp.stack([-y, x, z], -1)], -2)


def motion_cross(u: jax.Array, v: jax.Array) -> jax.Array:
    """Spatial motion cross product u ×ₘ v = [u_a × v_a; u_l × v_a + u_a × v_l] (..., 6)."""
    ua, ul, va, vl = u[..., :3], u[..., 3:], v[..., :3], v[..., 3:]
    return jnp.concatenate([jnp.cross(ua, va), jnp.cross(ul, va) + jnp.cross(ua, vl)], -1)


def motion_cross_force(v: jax.Array, f: jax.Array) -> jax.Array:
    """Spatial motion–force cross product v ×* f = [v_a × f_a + v_l × f_l; v_a × f_l] (..., 6)."""
    va, vl, fa, fl = v[..., :3], v[..., 3:], f[..., :3], f[..., 3:]
    return jnp.concatenate([jnp.cross(va, fa) + jnp.cross(vl, fl), jnp.cross(va, fl)], -1)


def _joint(t: int, jpos, jaxis, q, q0, x, r):
    """One joint (type ``t``, anchor ``jpos`` and axis ``jaxis`` in its body's frame, its qpos
    entries ``q`` and reference ``q0``) of a body whose frame before it is (x, r): (anchor and
    axis in the world, the frame after it), ``mj_kinematics``'s rules (a hinge turns by
    q − qpos0 about its anchor, a slide moves along its axis)."""
    if t == FREE:
        return q[:3], jnp.array([0.0, 0.0, 1.0], x.dtype), q[:3], quat_mats(q[3:7])
    anchor, axis = r @ jpos + x, r @ jaxis
    if t == BALL:
        r = r @ quat_mats(q)
        return anchor, axis, anchor - r @ jpos, r
    if t == HINGE:
        r = r @ axis_rotation(jaxis, q[0] - q0)
        return anchor, axis, anchor - r @ jpos, r
    return anchor, axis, x + axis * (q[0] - q0), r


def place(tree: Tree, mx, qpos: jax.Array):
    """Forward kinematics: body frames xpos (nbody, 3), xmat (nbody, 3, 3) and every joint's
    world anchor and axis (njnt, 3) each, bodies in index order (parents first)."""
    dt = qpos.dtype
    f = lambda a: jnp.asarray(a, dt)
    body_pos, body_R = f(mx.body_pos), quat_mats(f(mx.body_quat))
    jnt_pos, jnt_axis, qpos0 = f(mx.jnt_pos), f(mx.jnt_axis), f(mx.qpos0)
    xs, rs = [jnp.zeros(3, dt)], [jnp.eye(3, dtype=dt)]
    anchors, axes = [], []
    for b in range(1, len(tree.parent)):
        p = tree.parent[b]
        x, r = xs[p] + rs[p] @ body_pos[b], rs[p] @ body_R[b]
        for j in tree.body_joints[b]:
            t, a = int(tree.jnt_type[j]), int(tree.jnt_qposadr[j])
            width = {FREE: 7, BALL: 4}.get(t, 1)
            anchor, axis, x, r = _joint(t, jnt_pos[j], jnt_axis[j], qpos[a:a + width],
                                        qpos0[a], x, r)
            anchors.append(anchor)
            axes.append(axis)
        xs.append(x)
        rs.append(r)
    return jnp.stack(xs), jnp.stack(rs), jnp.stack(anchors), jnp.stack(axes)


def motion_axes(tree: Tree, xmat, anchors, axes, root_com) -> jax.Array:
    """cdof (nv, 6): [axis; axis × (root COM − anchor)] per rotational dof (a free or ball
    joint's three axes are its body's frame axes), [0; axis] per translational dof."""
    dt = xmat.dtype
    rows = []
    for j, t in enumerate(tree.jnt_type):
        b = int(tree.dof_body[tree.jnt_dofadr[j]])
        off = root_com[b] - anchors[j]
        if t in (FREE, BALL):
            if t == FREE:
                rows.append(jnp.eye(3, 6, 3, dtype=dt))
            ang = xmat[b].T                                              # (3, 3): its axes
            rows.append(jnp.concatenate([ang, jnp.cross(ang, off)], -1))
        elif t == HINGE:
            rows.append(jnp.concatenate([axes[j], jnp.cross(axes[j], off)])[None])
        else:
            rows.append(jnp.concatenate([jnp.zeros(3, dt), axes[j]])[None])
    return jnp.concatenate(rows)


def spatial_inertias(mx, xipos, ximat, root_com) -> jax.Array:
    """Body inertias (nbody, 6, 6) at the root subtree's COM, world orientation:
    [[I + m [c]×[c]×ᵀ, m [c]×], [m [c]×ᵀ, m 1]], c = body COM − root COM, I = R diag(i) Rᵀ."""
    dt = xipos.dtype
    mass, inertia = jnp.asarray(mx.body_mass, dt), jnp.asarray(mx.body_inertia, dt)
    C = cross_matrix(xipos - root_com)
    Ct = jnp.swapaxes(C, -1, -2)
    rot = jnp.einsum("bij,bj,bkj->bik", ximat, inertia, ximat)
    m = mass[:, None, None]
    top = jnp.concatenate([rot + m * (C @ Ct), m * C], -1)
    bottom = jnp.concatenate([m * Ct, m * jnp.eye(3, dtype=dt)[None].repeat(len(mass), 0)], -1)
    return jnp.concatenate([top, bottom], -2)


def mass_matrix(tree: Tree, mx, inert, cdof) -> jax.Array:
    """M (nv, nv) by composite inertias I^c = S I: M_ij = (I^c_{b(i)} cdof_i) · cdof_j on the
    dof chain (j ≤ i), mirrored, plus the armature on the diagonal (``mj_crb``)."""
    dt = cdof.dtype
    composite = jnp.einsum("bc,cij->bij", jnp.asarray(tree.subtree, dt), inert)
    F = jnp.einsum("vij,vj->vi", composite[tree.dof_body], cdof)
    lower = (F @ cdof.T) * jnp.asarray(tree.chain, dt)
    return lower + jnp.tril(lower, -1).T + jnp.diag(jnp.asarray(mx.dof_armature, dt))


def bias_force(tree: Tree, mx, inert, cdof, cdof_dot, cvel, qvel) -> jax.Array:
    """h (nv,) by RNE at q̈ = 0 with the base acceleration −g (module doc)."""
    dt = cdof.dtype
    g = jnp.concatenate([jnp.zeros(3, dt), -jnp.asarray(mx.opt.gravity, dt)])
    cacc = g + jnp.asarray(tree.moves, dt) @ (cdof_dot * qvel[:, None])
    f = (jnp.einsum("bij,bj->bi", inert, cacc)
         + motion_cross_force(cvel, jnp.einsum("bij,bj->bi", inert, cvel)))
    cfrc = jnp.asarray(tree.subtree, dt) @ f
    return jnp.sum(cdof * cfrc[tree.dof_body], axis=-1)


def passive_force(tree: Tree, mx, qpos, qvel) -> jax.Array:
    """−k (q − q_spring) on the hinge and slide joints − d q̇ on every dof (``mj_passive``)."""
    dt = qvel.dtype
    a = tree.hinge_qpos
    spring = -jnp.asarray(mx.jnt_stiffness, dt)[tree.hinge_jnts] * (
        qpos[a] - jnp.asarray(mx.qpos_spring, dt)[a])
    return jnp.asarray(tree.hinge_onehot, dt) @ spring - jnp.asarray(mx.dof_damping, dt) * qvel


def normalised(tree: Tree, qpos: jax.Array) -> jax.Array:
    """qpos with every free and ball joint's quaternion normalised (as ``mj_kinematics``)."""
    parts, start = [], 0
    for j, t in enumerate(tree.jnt_type):
        if t in (FREE, BALL):
            a = int(tree.jnt_qposadr[j]) + (3 if t == FREE else 0)
            q = qpos[a:a + 4]
            parts += [qpos[start:a], q / jnp.linalg.norm(q)]
            start = a + 4
    return jnp.concatenate(parts + [qpos[start:]])


def smooth(tree: Tree, mx, qpos: jax.Array, qvel: jax.Array) -> Smooth:
    """Every :class:`Smooth` term at (qpos, qvel) with the parameters of ``mx``."""
    dt = qvel.dtype
    qpos = normalised(tree, jnp.asarray(qpos, dt))
    xpos, xmat, anchors, axes = place(tree, mx, qpos)
    xipos = xpos + jnp.einsum("bij,bj->bi", xmat, jnp.asarray(mx.body_ipos, dt))
    ximat = xmat @ quat_mats(jnp.asarray(mx.body_iquat, dt))
    site_xpos = (xpos[tree.site_body]
                 + jnp.einsum("sij,sj->si", xmat[tree.site_body], jnp.asarray(mx.site_pos, dt)))
    site_xmat = xmat[tree.site_body] @ quat_mats(jnp.asarray(mx.site_quat, dt))
    S, mass = jnp.asarray(tree.subtree, dt), jnp.asarray(mx.body_mass, dt)
    sub_mass = S @ mass
    heavy = sub_mass >= mujoco.mjMINVAL
    subtree_com = jnp.where(heavy[:, None], (S @ (mass[:, None] * xipos))
                            / jnp.maximum(sub_mass, mujoco.mjMINVAL)[:, None], xipos)
    root_com = subtree_com[tree.root]
    cdof = motion_axes(tree, xmat, anchors, axes, root_com)
    inert = spatial_inertias(mx, xipos, ximat, root_com)
    motion = cdof * qvel[:, None]
    cvel = jnp.asarray(tree.moves, dt) @ motion
    cdof_dot = motion_cross(jnp.asarray(tree.before, dt) @ motion, cdof)
    return Smooth(
        qpos=qpos, qvel=qvel, xpos=xpos, xmat=xmat, xipos=xipos, ximat=ximat,
        site_xpos=site_xpos, site_xmat=site_xmat, subtree_com=subtree_com, cdof=cdof,
        cdof_dot=cdof_dot, cvel=cvel, qM=mass_matrix(tree, mx, inert, cdof),
        qfrc_bias=bias_force(tree, mx, inert, cdof, cdof_dot, cvel, qvel),
        qfrc_passive=passive_force(tree, mx, qpos, qvel))
