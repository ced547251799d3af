"""Condensed MPC on the 3D-H-LIP: the next N step sizes from the current state and a path preview.

The 3D-H-LIP is two decoupled planar H-LIPs, one along world x and one along world y, each with
the S2S state x = [c, p, v] (global COM [m], COM relative to the stance foot [m], velocity
[m/s]) sampled at SSP⁻ and the step u [m]:  x_{j+1} = A x_j + B u_j  (:func:`hlip.s2s_matrices`).

Planning from x_0 (time t_0, both planes) over steps j = 0..N-1, the states are eliminated
(*condensed*): X = Φ x_0 + Γ U with Φ = [A; A²; …; A^N] and Γ_{ji} = A^{j-i} B (i ≤ j), so the
decision vector is z = [u^x_0..u^x_{N-1}, u^y_0..u^y_{N-1}, s_1..s_O] (O obstacle slacks [m]) and

    min  Σ_{j=1..N} w_pos |c_j − r(t_j)|² + w_vel |v_j − ṙ(t_j)|² + α Σ_j |u_j|² + ρ_obs Σ_o s_o
    s.t. l_min ≤  u^x_j cos θ_j + u^y_j sin θ_j ≤ l_max                      (step length)
         w_min ≤ σ_j (−u^x_j sin θ_j + u^y_j cos θ_j) ≤ w_max                (step width)
         n_{jo}·(c_{j+1} − o) + s_o ≥ d_o,   s_o ≥ 0                          (obstacles)

with t_j = t_0 + j T, T = T_SSP + T_DSP, θ_j the path heading at t_j, σ_j = +1 when the left
foot is placed by step j (right stance) and −1 otherwise (stance alternates every step), and
n_{jo} a unit normal of keep-out disc o chosen at the previously planned position of c_{j+1},
tilted towards the side the plan passes on (:func:`obstacle_normals`; re-chosen every solve;
the half-plane lies outside the disc, so satisfying it keeps the disc).  The slack enters the
cost linearly (an exact penalty: for ρ_obs larger than the constraint's multiplier the slack
is zero whenever the linearised problem is feasible) so the QP is always feasible; a small
quadratic term keeps P positive definite.  Unused obstacle slots are disabled by infinite bounds.

With ``viability`` (static, ``mpc.viability``) the plan also keeps every planned state where
steps within the length limits can still stop the H-LIP from diverging along the path
(:func:`viability_bounds`): the sagittal divergent component ξ = w·[p, v] (w the left
eigenvector of the S2S map's unstable eigenvalue μ on [p, v], rotated into the heading of the
state's next step) obeys ξ⁺ = μ ξ + β u, so with step lengths u ∈ [lo, hi] the states that
some admissible steps keep bounded are those with ξ between the fixed points of the band's
edges,

    a ≤ ξ_j ≤ c,   a = −M / (μ − 1),   c = −m / (μ − 1),   [m, M] = β [lo, hi]

(:func:`viability_bounds` solves the two-step recursion, for bands that alternate).  The
bands are the step-length rows' own, tightened by the tube's last (mRPI) row, so a tube's
nominal stays inside the speeds its tightened steps can brake.  The rows share one slack
s_ξ ≥ 0 [m/s] with the exact-penalty weight ``obstacle_weight`` (so the QP stays feasible).
Without them a plan whose steps are capped (a tube's U ⊖ K E) may speed the nominal up beyond
what its capped steps can brake, which the finite horizon does not see (docs/robust_mpc.md,
attempt 4).  The lateral plane has no such rows: its width bands alternate in sign with a
minimum width, and for a ratio w_min / w_max above 1 / μ (the interval of a state whose next
step is a left one is |β| [μ w_min − w_max, μ w_max − w_min] / (μ² − 1)) the H-LIP at rest
lies outside their viable set, so the rows would hold no plan that starts walking; a tube's
tightened width band has such a ratio (Cassie's hull tube: [0.25, 0.49] m).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from hlip_jax.core import qp, robust

BIG = 1e20  # OSQP's convention: |bound| ≥ 1e20 is infinite


class MPCParams(NamedTuple):
    """Per-scenario MPC data (all traced; a sweep varies them without recompiling)."""
    A: jax.Array            # (3, 3) S2S matrix
    B: jax.Array            # (3,)
    w_pos: jax.Array        # weight on position error [1/m²]
    w_vel: jax.Array        # weight on velocity error [s²/m²]
    alpha: jax.Array        # weight on step size [1/m²]
    length_min: jax.Array   # step length limits along the heading [m]
    length_max: jax.Array
    width_min: jax.Array    # |step width| limits [m]
    width_max: jax.Array
    obstacle_weight: jax.Array  # exact-penalty weight on slack [1/m]
    obstacles: jax.Array    # (O, 3+) rows (x, y, planning radius, ...) [m]; extra columns unused
    obstacle_active: jax.Array  # (O,) bool
    e_c: jax.Array = robust.NONE.e_c   # (M, 2) tube: COM error bound per step m, plane [m]
    e_u: jax.Array = robust.NONE.e_u   # (M, 2) tube: stepping-law correction bound |K e| [m]
    e_heading: jax.Array = 1.0  # 1: those planes are sagittal/lateral; 0: world x/y


class Preview(NamedTuple):
    """Path preview at the N planned instants t_1..t_N (positions and velocities) and the
    headings at the step instants t_0..t_{N-1}."""
    pos: jax.Array      # (N, 2) [m]
    vel: jax.Array      # (N, 2) [m/s]
    heading: jax.Array  # (N,)   [rad]


class Plan(NamedTuple):
    u: jax.Array          # (N, 2) planned steps, world x / y [m]
    states: jax.Array     # (N, 2, 3) predicted states x_1..x_N per plane
    slack: jax.Array      # max obstacle slack [m]
    z: jax.Array          # raw QP primal (for warm start)
    y: jax.Array          # raw QP dual
    status: jax.Array
    iterations: jax.Array


def prediction_matrices(A, B, N: int):
    """Φ (N, 3, 3) and Γ (N, 3, N) with x_j = Φ_{j-1} x_0 + Γ_{j-1} U for j = 1..N."""
    powers = [jnp.eye(A.shape[0], dtype=A.dtype)]
    for _ in range(N):
        powers.append(A @ powers[-1])
    Phi = jnp.stack(powers[1:])                       # A^1..A^N
    AB = jnp.stack([P @ B for P in powers[:N]])      # A^0 B .. A^{N-1} B, (N, 3)
    j = jnp.arange(N)[:, None]
    i = jnp.arange(N)[None, :]
    lag = jnp.clip(j - i, 0, N - 1)
    Gamma = jnp.where((i <= j)[:, :, None], AB[lag], 0.0)  # (N, N, 3)
    return Phi, jnp.transpose(Gamma, (0, 2, 1))


class Condensed(NamedTuple):
    """Affine maps of the decision vector V (per plane, N entries) to the plan:
    X = free + Γ̄ V (states x_1..x_N) and U = free_u + Ω V (steps u_0..u_{N-1})."""
    free: jax.Array     # (2, N, 3)
    gamma: jax.Array    # (N, 3, N)
    free_u: jax.Array   # (2, N)
    omega: jax.Array    # (N, N)


def condense(A, B, x0, N: int) -> Condensed:
    """Pre-stabilised condensing.  The H-LIP is unstable (eigenvalue ≈ e^{λT_S}), so the plain
    map U ↦ X has entries growing like A^N and a Hessian with condition number ~1e6 even for
    N = 5 — enough to stall ADMM and to make float32 useless.  Writing u_j = K̄ x_j + v_j with
    K̄ the 3-state deadbeat gain (Ā = A + B K̄ nilpotent: Ā³ = 0) gives bounded maps
      x_j = Ā^j x_0 + Σ_{i<j} Ā^{j−1−i} B v_i,
      u_j = K̄ Ā^j x_0 + v_j + Σ_{i<j} K̄ Ā^{j−1−i} B v_i,
    the same problem in better coordinates (V ↦ U is unit lower-triangular, so invertible)."""
    from hlip_jax.core.hlip import place_gain_ackermann
    Kb = place_gain_ackermann(A, B)
    Ab = A + jnp.outer(B, Kb)
    Phi, Gam = prediction_matrices(Ab, B, N)                       # (N,3,3), (N,3,N)
    free = jnp.einsum("jab,pb->pja", Phi, x0)                      # x_1..x_N
    Phi0 = jnp.concatenate([jnp.eye(3, dtype=A.dtype)[None], Phi[:-1]])   # Ā^0..Ā^{N-1}
    free_u = jnp.einsum("a,jab,pb->pj", Kb, Phi0, x0)
    Gam0 = jnp.concatenate([jnp.zeros((1, 3, N), A.dtype), Gam[:-1]])     # x_0..x_{N-1} maps
    omega = jnp.eye(N, dtype=A.dtype) + jnp.einsum("a,jan->jn", Kb, Gam0)
    return Condensed(free=free, gamma=Gam, free_u=free_u, omega=omega)


def obstacle_normals(prev_c, heading, obstacles):
    """(N, O, 2) unit normals n_{jo} of the keep-out half-planes n·(c_{j+1} − o) ≥ r_o.

    The normal points from the disc's centre o to the previously planned c_{j+1} shifted by
    the disc's diameter 2 r_o across the path heading θ_j towards the side the plan passes on,

        n_{jo} ∝ c_{j+1} − o + 2 s_o r_o (−sin θ_j, cos θ_j),
        s_o = sign of the across-heading offset of the plan's point closest to o (+1 on a tie).

    Any unit normal gives a half-plane outside the disc (|c − o| ≥ n·(c − o) ≥ r_o), so the
    choice only decides how the disc is approximated.  The purely radial normal (no shift)
    makes a plan that heads straight at the disc meet a wall across its way: it stops in
    front of it until the reference has run far past, then lurches round (on the paper's
    sinusoid the H-LIP slows to 0.11 m/s, then steps 0.5 m sideways).  Tilted towards the
    passing side, the half-plane is a lane boundary and the plan moves aside while it keeps
    walking (slowest 0.51 m/s); the diameter rather than the radius as the shift turns the
    lane earlier (widest step 0.42 m instead of 0.50 m, lateral speed 0.80 instead of
    0.89 m/s), which is what the Cassie obstacle run needs."""
    dt = prev_c.dtype
    lat = jnp.stack([-jnp.sin(heading), jnp.cos(heading)], axis=-1).astype(dt)   # (N, 2)
    rel = prev_c[:, None, :] - obstacles[None, :, :2]                          # (N, O, 2)
    across = jnp.einsum("jod,jd->jo", rel, lat)                                # (N, O)
    closest = jnp.argmin(jnp.sum(rel ** 2, axis=-1), axis=0)                   # (O,)
    side = jnp.where(jnp.take_along_axis(across, closest[None, :], axis=0)[0] >= 0, 1.0, -1.0)
    diff = rel + (2.0 * side * obstacles[:, 2])[None, :, None] * lat[:, None, :]
    dist = jnp.linalg.norm(diff, axis=-1, keepdims=True)
    return jnp.where(dist > 1e-9, diff / jnp.maximum(dist, 1e-9), jnp.array([1.0, 0.0], dt))


def _support_c(params: MPCParams, dx, dy, heading, bound):
    """Support Σ_i |m_i| bound_i of the tube's per-plane box in the world direction (dx, dy),
    m = its components in the tube's frame (:func:`hlip_jax.core.robust.frame_weights`); ``bound``
    (..., 2) per plane, broadcast against the direction's shape."""
    m1, m2 = robust.frame_weights(dx, dy, heading, params.e_heading)
    return m1 * bound[..., 0] + m2 * bound[..., 1]


def _rows(table, steps):
    """Rows of a tube table (:mod:`hlip_jax.core.robust`) for absolute steps ``steps``; the last row
    (the mRPI bound) serves every later step."""
    return table[jnp.clip(steps, 0, table.shape[0] - 1)]


def _step_tightening(params: MPCParams, heading, c, s, steps):
    """(N,) each: the largest stepping-law correction K e_m along the heading θ_j (direction
    (c, s) = (cos θ_j, sin θ_j)) and across it (support of K F_m, m the absolute step the row
    places); both sides of the row shrink by it."""
    b = _rows(params.e_u, steps)
    return (_support_c(params, c, s, heading, b), _support_c(params, -s, c, heading, b))


def _keepout_tightening(params: MPCParams, normal, heading, steps):
    """(N, O): h_{F_m}(−n) of the COM error along each keep-out normal n_{jo}, m = the absolute
    step of the planned state c_{j+1}."""
    b = _rows(params.e_c, steps)[:, None, :]
    return _support_c(params, -normal[..., 0], -normal[..., 1], heading[:, None], b)


def divergent_direction(A):
    """(μ, w): the unstable eigenvalue μ > 1 of the S2S map on [p, v] (A (3, 3) on [c, p, v];
    the p and v rows do not involve c) and its left eigenvector w = (w_p, 1), scaled so that
    ξ = w·[p, v] is in m/s:  w A_pv = μ w."""
    a, b, c, d = A[1, 1], A[1, 2], A[2, 1], A[2, 2]
    half = 0.5 * (a + d)
    mu = half + jnp.sqrt(half ** 2 - (a * d - b * c))
    return mu, jnp.stack([c / (mu - a), jnp.ones_like(mu)])


def viability_bounds(mu, beta, lo, hi):
    """(a, c) (N,): bounds of ξ_j for states whose next steps are u_j ∈ [lo_j, hi_j] and
    u_{j+1} ∈ [lo_{j+1}, hi_{j+1}]: the fixed points of the two-step map
    ξ ↦ μ(μ ξ + β u_j) + β u_{j+1} at the bands' ends (module docstring).  The bands repeat
    with period one or two, so the last state's second band is the band before its first."""
    ends = jnp.stack([beta * lo, beta * hi])
    m, M = ends.min(axis=0), ends.max(axis=0)
    def following(v):
        return jnp.concatenate([v[1:], v[-2:-1] if v.shape[0] > 1 else v])
    m1, M1 = following(m), following(M)
    den = mu ** 2 - 1.0
    return -(M1 + mu * M) / den, -(m1 + mu * m) / den


def _viability_rows(params: MPCParams, cd: Condensed, preview: Preview, n: int):
    """Rows (2N, n) and bounds (2N,) of a_j ≤ ξ_j + s_ξ and ξ_j − s_ξ ≤ c_j for the planned
    states x_1..x_N, ξ the sagittal divergent component in the heading of step j (the last
    state keeps the last heading), the band the step-length rows' tightened by the tube's
    last (mRPI) row."""
    N, dt = cd.free.shape[1], cd.free.dtype
    mu, w = divergent_direction(params.A)
    beta = w @ params.B[1:]
    heading = jnp.concatenate([preview.heading[1:], preview.heading[-1:]])
    cth, sth = jnp.cos(heading), jnp.sin(heading)
    last = jnp.full((N,), params.e_u.shape[0] - 1)                      # the mRPI row
    tl, _ = _step_tightening(params, heading, cth, sth, last)
    a, c = viability_bounds(mu, beta, params.length_min + tl, params.length_max - tl)
    xi_rows = w[0] * cd.gamma[:, 1, :] + w[1] * cd.gamma[:, 2, :]          # (N, N) per plane
    xi_free = w[0] * cd.free[:, :, 1] + w[1] * cd.free[:, :, 2]            # (2, N)
    r = jnp.concatenate([xi_rows * cth[:, None], xi_rows * sth[:, None],
                         jnp.zeros((N, n - 2 * N - 1), dt)], axis=1)
    f = cth * xi_free[0] + sth * xi_free[1]
    one = jnp.ones((N, 1), dt)
    rows = jnp.concatenate([jnp.concatenate([r, one], axis=1), jnp.concatenate([r, -one], axis=1)])
    big = jnp.full((N,), BIG, dt)
    return rows, jnp.concatenate([a - f, -big]), jnp.concatenate([big, c - f])


def build_qp(params: MPCParams, x0, preview: Preview, stance0, prev_c, step0=0,
             viability: bool = False):
    """The condensed QP (P, q, A, l, u) in z = [V^x, V^y, s] (see :func:`condense`; with
    ``viability`` z = [V^x, V^y, s, s_ξ]).

    Args:
      x0: (2, 3) current state per plane (x plane, y plane).
      stance0: stance foot at t_0 (0 left, 1 right); step 0 is placed by the other foot.
      prev_c: (N, 2) previously planned COM positions c_1..c_N (obstacle linearisation points).
      step0: absolute index m of x0's step (the tube's rows: step j is m + j, state j+1 is
        m + j + 1; :mod:`hlip_jax.core.robust`).
      viability: static; add the viability rows and their slack s_ξ (module docstring):
        z = [V^x, V^y, s, s_ξ], rows [length, width, obstacles, slacks, ξ (2N), s_ξ ≥ 0].
    """
    N = preview.pos.shape[0]
    O = params.obstacles.shape[0]
    dt = x0.dtype
    cd = condense(params.A, params.B, x0, N)
    free, Om = cd.free, cd.omega
    Gc, Gv = cd.gamma[:, 0, :], cd.gamma[:, 2, :]                  # (N, N) position / velocity rows
    n_base = 2 * N + O
    n = n_base + int(viability)

    # cost ½ zᵀ P z + qᵀ z  (factor 2 from the squares)
    Hp = 2.0 * (params.w_pos * Gc.T @ Gc + params.w_vel * Gv.T @ Gv + params.alpha * Om.T @ Om)
    P = jnp.zeros((n, n), dt)
    P = P.at[:N, :N].set(Hp).at[N:2 * N, N:2 * N].set(Hp)
    P = P.at[2 * N:, 2 * N:].set(1e-6 * jnp.eye(n - 2 * N, dtype=dt))
    ref_err_c = free[:, :, 0] - preview.pos.T                      # (2, N)
    ref_err_v = free[:, :, 2] - preview.vel.T
    qx = 2.0 * (params.w_pos * Gc.T @ ref_err_c.T + params.w_vel * Gv.T @ ref_err_v.T
                + params.alpha * Om.T @ cd.free_u.T)                # (N, 2)
    q = jnp.concatenate([qx[:, 0], qx[:, 1], params.obstacle_weight * jnp.ones((n - 2 * N,), dt)])

    # step length / width rows on U = free_u + Ω V, rotated into the heading θ_j
    cth, sth = jnp.cos(preview.heading), jnp.sin(preview.heading)
    zO = jnp.zeros((N, n - 2 * N), dt)
    A_len = jnp.concatenate([Om * cth[:, None], Om * sth[:, None], zO], axis=1)
    A_wid = jnp.concatenate([-Om * sth[:, None], Om * cth[:, None], zO], axis=1)
    len0 = cth * cd.free_u[0] + sth * cd.free_u[1]
    wid0 = -sth * cd.free_u[0] + cth * cd.free_u[1]
    # σ_j = +1 when step j places the left foot, i.e. stance_j = right; stance alternates
    stance = (stance0 + jnp.arange(N)) % 2
    sigma = jnp.where(stance == 1, 1.0, -1.0).astype(dt)
    ones = jnp.ones((N,), dt)
    tl, tw = _step_tightening(params, preview.heading, cth, sth, step0 + jnp.arange(N))  # U ⊖ KF_m
    l_len, u_len = params.length_min * ones - len0 + tl, params.length_max * ones - len0 - tl
    l_wid = jnp.where(sigma > 0, params.width_min, -params.width_max) * ones - wid0 + tw
    u_wid = jnp.where(sigma > 0, params.width_max, -params.width_min) * ones - wid0 - tw

    # obstacles: n_{jo}·(c_{j+1} − o) + s_o ≥ r_o, c_{j+1} = free_c + Gc V (per plane)
    centre = params.obstacles[:, :2]                                # (O, 2)
    normal = obstacle_normals(prev_c, preview.heading, params.obstacles)
    rows_x = normal[:, :, 0:1] * Gc[:, None, :]                     # (N, O, N)
    rows_y = normal[:, :, 1:2] * Gc[:, None, :]
    rows_s = jnp.broadcast_to(jnp.eye(O, n - 2 * N, dtype=dt), (N, O, n - 2 * N))
    A_obs = jnp.concatenate([rows_x, rows_y, rows_s], axis=2).reshape(N * O, n)
    free_c = free[:, :, 0].T                                         # (N, 2)
    lhs0 = jnp.einsum("jod,jod->jo", normal, free_c[:, None, :] - centre[None, :, :])
    l_obs = (params.obstacles[None, :, 2] - lhs0
             + _keepout_tightening(params, normal, preview.heading, step0 + 1 + jnp.arange(N)))
    l_obs = jnp.where(params.obstacle_active[None, :], l_obs, -BIG).reshape(N * O)
    u_obs = jnp.full((N * O,), BIG, dt)
    A_slack = jnp.concatenate([jnp.zeros((O, 2 * N), dt), jnp.eye(O, n - 2 * N, dtype=dt)],
                              axis=1)
    l_slack = jnp.zeros((O,), dt)
    u_slack = jnp.where(params.obstacle_active, BIG, 0.0).astype(dt)

    Aq = [A_len, A_wid, A_obs, A_slack]
    lq = [l_len, l_wid, l_obs, l_slack]
    uq = [u_len, u_wid, u_obs, u_slack]
    if viability:
        A_xi, l_xi, u_xi = _viability_rows(params, cd, preview, n)
        Aq += [A_xi, jnp.zeros((1, n), dt).at[0, n_base].set(1.0)]
        lq += [l_xi, jnp.zeros((1,), dt)]
        uq += [u_xi, jnp.full((1,), BIG, dt)]
    return P, q, jnp.concatenate(Aq, axis=0), jnp.concatenate(lq), jnp.concatenate(uq)


def decode(params: MPCParams, x0, z, N: int):
    """Steps u_0..u_{N-1} (N, 2) from the QP variable z."""
    cd = condense(params.A, params.B, x0, N)
    V = jnp.stack([z[:N], z[N:2 * N]])                              # (2, N)
    return (cd.free_u + V @ cd.omega.T).T


def predict(params: MPCParams, x0, u):
    """Predicted states x_1..x_N (N, 2, 3) from x0 (2, 3) and steps u (N, 2)."""
    Phi, Gam = prediction_matrices(params.A, params.B, u.shape[0])
    return (jnp.einsum("jab,pb->jpa", Phi, x0) + jnp.einsum("jan,np->jpa", Gam, u))


def solve(params: MPCParams, x0, preview: Preview, stance0, prev_c, settings: qp.Settings,
          warm_start=None, step0=0, viability: bool = False) -> Plan:
    """Build and solve the condensed MPC QP with :func:`hlip_jax.core.qp.solve`; ``slack`` is the
    largest obstacle slack (the viability slack is z's last entry)."""
    N, O = preview.pos.shape[0], params.obstacles.shape[0]
    P, q, Aq, lq, uq = build_qp(params, x0, preview, stance0, prev_c, step0, viability)
    sol = qp.solve(P, q, Aq, lq, uq, settings=settings, warm_start=warm_start)
    u = decode(params, x0, sol.x, N)
    slack = jnp.max(sol.x[2 * N:2 * N + O], initial=0.0)
    return Plan(u=u, states=predict(params, x0, u), slack=slack, z=sol.x, y=sol.y,
                status=sol.status, iterations=sol.iterations)


def shift_warm_start(plan: Plan, N: int, O: int):
    """Receding-horizon warm start: drop the executed step, repeat the last one (the
    per-step rows of every block: length, width, obstacles and, when present, the two ξ
    blocks; the slacks' rows stay)."""
    def shift(v):
        return jnp.concatenate([v[1:], v[-1:]])
    z = plan.z
    zx = jnp.concatenate([shift(z[:N]), shift(z[N:2 * N]), z[2 * N:]])
    y = plan.y
    ylen, ywid = y[:N], y[N:2 * N]
    yobs = y[2 * N:2 * N + N * O].reshape(N, O)
    yobs = jnp.concatenate([yobs[1:], yobs[-1:]]).reshape(N * O)
    base = 2 * N + N * O + O
    ys = [shift(ylen), shift(ywid), yobs, y[2 * N + N * O:base]]
    if y.shape[0] > base:                         # the viability rows and their slack's row
        ys += [shift(y[base + k * N:base + (k + 1) * N]) for k in range(2)] + [y[-1:]]
    return zx, jnp.concatenate(ys)
