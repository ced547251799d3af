"""Constrained (holonomic) dynamics of Cassie, condensed so that q̈ and λ are affine in τ.

The whole-body model (see :mod:`hlip_jax.plants.cassie.model` for conventions)

    M q̈ + h − f_p = B τ + Jᵀ λ,        J q̈ + J̇q̇ = 0,

with τ (nu = 10) the motor torques [N m] (ctrl units), f_p the spring/damping forces,
J (28 × nv) the stacked holonomic constraints

    rows  0..11: the four closed chains (achilles and plantar rods, :data:`model.LOOPS` order),
    rows 12..23: the four contact sites (left toe, left heel, right toe, right heel; xyz each),

    rows 24..27 (``spring_dofs`` given): q̈ = 0 on the four leaf-spring dofs (left shin, left
                heel, right shin, right heel) — the *rigid-spring* controller model,

and λ the matching constraint forces (λ of a contact row is the world-frame force the ground
applies to the robot at that site [N]).  Eliminating λ:

    G λ = −J̇q̇ − J M⁻¹ (B τ − h + f_p),   G = J M⁻¹ Jᵀ,
    q̈  = M⁻¹ (B τ + Jᵀ λ − h + f_p).

A site whose ``contact`` flag is 0 gets a zero Jacobian row and a unit diagonal in G, so its
force is exactly 0 and it does not constrain q̈.  Two sites on one foot constrain only 5 of the
foot's 6 dofs (their distance is fixed): the heel then keeps only its two rows normal to the
foot axis (:func:`contact_frames`).  Each plantar four-bar is planar, so its three connect
rows are also dependent: the combination n·(rows) along the four-bar's plane normal n vanishes
(:func:`plantar_normals`) and G is singular along it.  λ is the minimum-norm least-squares
force G⁺ r, computed one of two ways (``solve``):

* ``"eigen"`` (the default, the validated controller's): G's eigendecomposition, eigenvalues
  below ``reg · max eig`` dropped.  In float32 the two null eigenvalues come out as round-off
  above the cut and are inverted (:func:`condense`).
* ``"deflated"``: with N (28, 2) the two unit null vectors (n on each plantar loop's rows),
  G + s N Nᵀ (s = trace G / 28) is positive definite and acts on range(G) as G does, so

      λ = (G + s N Nᵀ)⁻¹ (I − N Nᵀ) r = G⁺ r

  by one Cholesky factorisation (:func:`min_norm_forces`): float32 stays within 3e-5 of
  float64, and a batched Cholesky is several times cheaper than a batched eigendecomposition
  on a GPU (docs/benchmarks/cassie_gpu.md).

The result is the affine map

    q̈ = Q_τ τ + q̈₀,   λ = L_τ τ + λ₀,

which the CLF-QP uses (:mod:`hlip_jax.plants.cassie.clfqp`).

Why rigid springs: the pelvis is carried by the legs through the shin and heel springs, so a
motor torque reaches the pelvis acceleration only through the spring deflection (relative
degree 4); in the compliant model the map τ ↦ ÿ_pelvis is nearly singular and a CLF-QP on it
demands saturated torques.  The controller therefore treats the springs as locked (their
constraint force absorbs the spring torque); the simulation keeps them compliant.  Pure jax; jit / vmap-able.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax.scipy.linalg import cho_factor, cho_solve

from hlip_jax.plants.cassie import model

N_LOOP_ROWS = 12
N_CONTACT_ROWS = 12
N_SPRING_ROWS = 4
N_CONSTRAINT_ROWS = N_LOOP_ROWS + N_CONTACT_ROWS + N_SPRING_ROWS
#: first rows of the two plantar four-bars' connect constraints (left, right; model.LOOPS order)
PLANTAR_ROWS = tuple(3 * i for i, name in enumerate(model.LOOPS) if "plantar" in name)
#: how :func:`condense` computes the minimum-norm constraint forces (module doc)
SOLVES = ("eigen", "deflated")


def spring_dofs(cassie: model.Cassie) -> tuple:
    """dof addresses of the four leaf springs (left shin, left heel, right shin, right heel)."""
    return tuple(int(getattr(cassie.index.dof[s], n)) for s in (0, 1)
                 for n in ("shin", "heel_spring"))


class Condensed(NamedTuple):
    """q̈ = qdd_tau @ τ + qdd0,  λ = lam_tau @ τ + lam0 (rows as in the module doc; the
    contact rows 12..23 are returned as world-frame forces [N] at the four sites)."""
    qdd_tau: jax.Array   # (nv, nu)
    qdd0: jax.Array      # (nv,)
    lam_tau: jax.Array   # (28, nu)
    lam0: jax.Array      # (28,)


def contact_frames(terms: model.RobotTerms, contact: jax.Array):
    """Row frames H (4, 3, 3) and row flags (12,) of the contact constraints.

    Two points of one rigid foot have a fixed distance, so toe and heel together constrain
    only 5 dofs; a sixth row would be redundant and, with q̇ ≠ 0, inconsistent by |v_rel|²/L
    (which a regularised solve turns into a huge internal force).  When both sites of a foot
    touch, the heel keeps only the two rows normal to the heel→toe axis d̂:
    n₁ = (ẑ − (ẑ·d̂) d̂)/‖·‖, n₂ = d̂ × n₁ (its third row is dropped).  Row r of site i is
    H[i, r] · (site acceleration), and the world force on the robot at site i is H[i]ᵀ λ_i.
    """
    dt = terms.M.dtype
    contact = jnp.asarray(contact, dt)
    sp = terms.site_pos.reshape(2, 2, 3)
    d = sp[:, 0] - sp[:, 1]
    d = d / jnp.linalg.norm(d, axis=-1, keepdims=True)
    ez = jnp.array([0.0, 0.0, 1.0], dt)
    n1 = ez[None] - (d @ ez)[:, None] * d
    n1 = n1 / jnp.linalg.norm(n1, axis=-1, keepdims=True)
    n2 = jnp.cross(d, n1)
    eye = jnp.eye(3, dtype=dt)
    both = (contact[0::2] > 0.5) & (contact[1::2] > 0.5)                  # (2,) per foot
    H_pair = jnp.stack([n1, n2, jnp.zeros_like(n1)], axis=1)             # (2, 3, 3)
    H_heel = jnp.where(both[:, None, None], H_pair, eye[None])
    H = jnp.stack([eye[None].repeat(2, 0), H_heel], axis=1).reshape(4, 3, 3)
    flags = jnp.repeat(contact, 3).reshape(4, 3)
    heel_third = jnp.where(both, 0.0, 1.0)
    flags = flags.at[1, 2].multiply(heel_third[0]).at[3, 2].multiply(heel_third[1])
    return H, flags.reshape(-1)


def constraint_stack(terms: model.RobotTerms, contact: jax.Array, springs=None):
    """(J (28, nv), J̇q̇ (28,), active (28,), H (4, 3, 3)) for the loops, the sites flagged in
    ``contact`` (4,) (1 = in contact, 0 = free; rows in the frames of :func:`contact_frames`)
    and, if ``springs`` (4 dof addresses) is given, the locked springs."""
    dt = terms.M.dtype
    nv = terms.M.shape[0]
    H, ac = contact_frames(terms, contact)
    Jc = jnp.einsum("srk,skn->srn", H, terms.site_J).reshape(N_CONTACT_ROWS, nv)
    ajc = jnp.einsum("srk,sk->sr", H, terms.site_jdqd).reshape(N_CONTACT_ROWS)
    if springs is None:
        Js = jnp.zeros((N_SPRING_ROWS, nv), dt)
        a_s = jnp.zeros(N_SPRING_ROWS, dt)
    else:
        Js = jnp.zeros((N_SPRING_ROWS, nv), dt).at[jnp.arange(N_SPRING_ROWS), jnp.array(springs)].set(1.0)
        a_s = jnp.ones(N_SPRING_ROWS, dt)
    J = jnp.concatenate([terms.loop_J, Jc * ac[:, None], Js], axis=0)
    jd = jnp.concatenate([terms.loop_jdqd, ajc * ac, jnp.zeros(N_SPRING_ROWS, dt)])
    active = jnp.concatenate([jnp.ones(N_LOOP_ROWS, dt), ac, a_s])
    return J, jd, active, H


def plantar_normals(J: jax.Array) -> jax.Array:
    """N (28, 2): the unit null vectors of G from the two planar plantar four-bars.

    A planar four-bar's connect constraint (3 rows, :data:`PLANTAR_ROWS`) has rank 2: every
    column of its block J_p lies in the four-bar's plane, and the plane normal n (nᵀ J_p = 0)
    is the cross product of two of them.  Only the four-bar's own three joints (foot crank,
    plantar rod, toe) give nonzero columns (every other dof moves both anchors alike), so n
    is the largest cross product among the three columns of largest norm.  N holds n on each
    plantar loop's rows; Jᵀ N = 0 and G N = 0 for the whole stack (to the chain's closure: a
    chain held open by δ tilts n by O(δ))."""
    N = jnp.zeros((J.shape[0], 2), J.dtype)
    for i, r in enumerate(PLANTAR_ROWS):
        cols = J[r:r + 3].T                                                      # (nv, 3)
        c = cols[jax.lax.top_k(jnp.sum(cols * cols, axis=1), 3)[1]]
        x = jnp.stack([jnp.cross(c[0], c[1]), jnp.cross(c[0], c[2]), jnp.cross(c[1], c[2])])
        n = x[jnp.argmax(jnp.sum(x * x, axis=1))]
        N = N.at[r:r + 3, i].set(n / jnp.linalg.norm(n))
    return N


def min_norm_forces(G: jax.Array, N: jax.Array, r: jax.Array) -> jax.Array:
    """λ = G⁺ r for symmetric positive semi-definite G whose null space is spanned by the
    orthonormal columns of N (module doc): (G + s N Nᵀ)⁻¹ (I − N Nᵀ) r, s = trace(G) / rows,
    one Cholesky factorisation.  r: (rows, k)."""
    Gs = 0.5 * (G + G.T)
    s = jnp.trace(Gs) / G.shape[0]
    return cho_solve(cho_factor(Gs + s * (N @ N.T)), r - N @ (N.T @ r))


def eigen_forces(G: jax.Array, r: jax.Array, reg: float = 1e-9) -> jax.Array:
    """λ = G⁺ r by G's eigendecomposition, eigenvalues below ``reg`` of the largest dropped
    (with the redundant rows, their inconsistent right sides).  r: (rows, k)."""
    s, U = jnp.linalg.eigh(0.5 * (G + G.T))
    tol = reg * jnp.max(s)
    s_inv = jnp.where(s > tol, 1.0 / jnp.where(s > tol, s, 1.0), 0.0)
    return U @ (s_inv[:, None] * (U.T @ r))


def condense(terms: model.RobotTerms, actuation, contact, springs=None,
             reg: float = 1e-9, solve: str = "eigen") -> Condensed:
    """Affine maps τ ↦ (q̈, λ) of the constrained dynamics (module doc).

    Args:
      terms: :func:`model.robot_terms` at the current state.
      actuation: B (nv, nu).
      contact: (4,) contact flags of the sites (left toe, left heel, right toe, right heel).
      springs: None (compliant springs) or the 4 spring dof addresses (:func:`spring_dofs`)
        to lock them in the model.
      reg: relative eigenvalue cut-off of the pseudo-inverse of G (1e-9 in float64; use ~1e-5
        in float32).  The control tick uses the default in float32 too: G's two null
        eigenvalues then come out as round-off (~1e-7 of the largest), pass the cut and are
        inverted, which leaves q̈ off by up to 11 % of float64's and λ with up to 1.7e5 N of
        spurious plantar-rod force at the standing keyframe.  The validated controller is this
        one; a projection of the null vectors that fixes it walked fewer 200 N pushes on the
        validation set with an earlier preset (docs/cassie_gait.md, round 11), and as many as
        this one with the preset now (docs/cassie_validation, "With the GPU settings").
      solve (static): "eigen" (``reg`` applies) or "deflated", that projection with one
        Cholesky factorisation (module doc; ``impl.condense``).
    """
    if solve not in SOLVES:
        raise ValueError(f"solve: {solve!r}; allowed: {SOLVES}")
    M = terms.M
    B = jnp.asarray(actuation, M.dtype)
    J, jd, active, H = constraint_stack(terms, contact, springs)
    cf = cho_factor(M)
    rhs = jnp.concatenate([B, (terms.passive - terms.bias)[:, None]], axis=1)   # (nv, nu+1)
    Minv_rhs = cho_solve(cf, rhs)
    Minv_Jt = cho_solve(cf, J.T)                                                 # (nv, 28)
    G = J @ Minv_Jt
    G = G + jnp.diag(1.0 - active)                    # inactive rows: λ = 0
    rhs_l = -(J @ Minv_rhs)
    rhs_l = rhs_l.at[:, -1].add(-jd)
    if solve == "eigen":
        lam = eigen_forces(G, rhs_l, reg)                                         # (28, nu+1)
    else:
        lam = min_norm_forces(G, plantar_normals(J), rhs_l)
    qdd = Minv_rhs + Minv_Jt @ lam
    # contact rows → world forces at the sites (H[i]ᵀ λ_i)
    c0, c1 = N_LOOP_ROWS, N_LOOP_ROWS + N_CONTACT_ROWS
    f = jnp.einsum("srk,srn->skn", H, lam[c0:c1].reshape(4, 3, -1)).reshape(N_CONTACT_ROWS, -1)
    lam = lam.at[c0:c1].set(f)
    return Condensed(qdd_tau=qdd[:, :-1], qdd0=qdd[:, -1], lam_tau=lam[:, :-1], lam0=lam[:, -1])
