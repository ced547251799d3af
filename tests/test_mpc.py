"""Condensed MPC against an independently built non-condensed QP (states as variables) solved by OSQP."""


import jax.numpy as jnp
import numpy as np
import osqp
import pytest
import scipy.sparse as sp

from hlip_jax.core import hlip, mpc, qp


def _params(obstacles=np.zeros((0, 3)), active=None, **kw):
    A, B = hlip.s2s_matrices(0.8, 0.3, 0.1)
    d = dict(w_pos=1.0, w_vel=0.2, alpha=0.05, length_min=-0.3, length_max=0.5,
             width_min=0.1, width_max=0.4, obstacle_weight=1e3)
    d.update(kw)
    obstacles = jnp.asarray(obstacles, jnp.float64).reshape(-1, 3)
    if active is None:
        active = np.ones(obstacles.shape[0], bool)
    return mpc.MPCParams(A=A, B=B, obstacles=obstacles, obstacle_active=jnp.asarray(active),
                         **{k: jnp.asarray(v, jnp.float64) for k, v in d.items()})


def _osqp(P, q, A, l, u):
    P = sp.csc_matrix(np.triu(np.asarray(P)))
    A = sp.csc_matrix(np.asarray(A))
    l = np.clip(np.asarray(l), -1e30, 1e30)
    u = np.clip(np.asarray(u), -1e30, 1e30)
    prob = osqp.OSQP()
    prob.setup(P=P, q=np.asarray(q), A=A, l=l, u=u, eps_abs=1e-8, eps_rel=1e-8,
               max_iter=200000, polishing=True, verbose=False)
    res = prob.solve()
    assert res.info.status_val in (1, 2), res.info.status  # refined exactly below
    # The condensed MPC Hessian is ill-conditioned (cond ~1e6: the unstable H-LIP makes later
    # steps weigh far more), so OSQP's iterate alone is only good to ~1e-4 in u.  Re-solve the
    # KKT system exactly on the active set OSQP identified (what polishing does, without its
    # regularisation) to get a reference accurate to round-off.
    P, A = P.toarray(), A.toarray()
    P = np.triu(P) + np.triu(P, 1).T
    ax = A @ res.x
    at_u, at_l = np.abs(ax - u) < 1e-6, np.abs(ax - l) < 1e-6
    act = at_u | at_l
    bound = np.where(at_u, u, l)[act]
    Aa = A[act]
    n, k = P.shape[0], int(act.sum())
    K = np.block([[P, Aa.T], [Aa, np.zeros((k, k))]])
    sol = np.linalg.lstsq(K, np.concatenate([-np.asarray(q), bound]), rcond=None)[0]
    x = sol[:n]
    viol = max(np.max(A @ x - u), np.max(l - A @ x))
    assert viol < 1e-7, viol
    return x


def _noncondensed(params, x0, prev, stance0, prev_c):
    """Variables: [x_1..x_N (plane x, 3 each), x_1..x_N (plane y), u^x (N), u^y (N), s (O)]."""
    A, B = np.asarray(params.A), np.asarray(params.B)
    N = prev.pos.shape[0]
    O = params.obstacles.shape[0]
    nx = 2 * 3 * N
    n = nx + 2 * N + O
    iX = lambda p, j: p * 3 * N + 3 * j             # noqa: E731  state block of plane p, step j+1
    iU = lambda p, j: nx + p * N + j                 # noqa: E731
    iS = lambda o: nx + 2 * N + o                    # noqa: E731
    P = np.zeros((n, n))
    q = np.zeros(n)
    for p in range(2):
        for j in range(N):
            P[iX(p, j), iX(p, j)] += 2 * params.w_pos
            q[iX(p, j)] += -2 * params.w_pos * prev.pos[j, p]
            P[iX(p, j) + 2, iX(p, j) + 2] += 2 * params.w_vel
            q[iX(p, j) + 2] += -2 * params.w_vel * prev.vel[j, p]
            P[iU(p, j), iU(p, j)] += 2 * params.alpha
    for o in range(O):
        P[iS(o), iS(o)] = 1e-6
        q[iS(o)] = params.obstacle_weight
    rows, lo, hi = [], [], []
    for p in range(2):                 # dynamics x_{j+1} − A x_j − B u_j = 0
        for j in range(N):
            for a in range(3):
                r = np.zeros(n)
                r[iX(p, j) + a] = 1.0
                if j > 0:
                    r[iX(p, j - 1):iX(p, j - 1) + 3] -= A[a]
                    rhs = 0.0
                else:
                    rhs = A[a] @ np.asarray(x0[p])
                r[iU(p, j)] -= B[a]
                rows.append(r); lo.append(rhs); hi.append(rhs)
    for j in range(N):
        th = float(prev.heading[j])
        r = np.zeros(n); r[iU(0, j)] = np.cos(th); r[iU(1, j)] = np.sin(th)
        rows.append(r); lo.append(params.length_min); hi.append(params.length_max)
        left = (stance0 + j) % 2 == 1
        r = np.zeros(n); r[iU(0, j)] = -np.sin(th); r[iU(1, j)] = np.cos(th)
        rows.append(r)
        lo.append(params.width_min if left else -params.width_max)
        hi.append(params.width_max if left else -params.width_min)
    obs = np.asarray(params.obstacles)
    pc = np.asarray(prev_c)
    for o in range(O):
        # side of the plan point nearest the disc, across that point's heading
        jn = int(np.argmin([np.hypot(*(pc[j] - obs[o, :2])) for j in range(N)]))
        thn = float(prev.heading[jn])
        side = 1.0 if np.dot(pc[jn] - obs[o, :2], [-np.sin(thn), np.cos(thn)]) >= 0 else -1.0
        for j in range(N):
            th = float(prev.heading[j])
            d = pc[j] - obs[o, :2] + 2 * side * obs[o, 2] * np.array([-np.sin(th), np.cos(th)])
            nrm = d / np.linalg.norm(d)
            r = np.zeros(n); r[iX(0, j)] = nrm[0]; r[iX(1, j)] = nrm[1]; r[iS(o)] = 1.0
            rows.append(r); lo.append(obs[o, 2] + nrm @ obs[o, :2]); hi.append(np.inf)
    for o in range(O):
        r = np.zeros(n); r[iS(o)] = 1.0
        rows.append(r); lo.append(0.0); hi.append(np.inf)
    z = _osqp(P, q, np.array(rows), np.array(lo), np.array(hi))
    u = np.stack([z[nx:nx + N], z[nx + N:nx + 2 * N]], -1)
    X = np.stack([z[:3 * N].reshape(N, 3), z[3 * N:nx].reshape(N, 3)], 1)
    return u, X, z[nx + 2 * N:]


def _random_case(rng, N, heading=None):
    x0 = jnp.asarray(rng.normal(size=(2, 3)) * [0.3, 0.05, 0.2])
    t = np.arange(1, N + 1) * 0.4
    th0 = rng.uniform(-np.pi, np.pi) if heading is None else heading
    pos = np.stack([np.cos(th0) * 0.5 * t, np.sin(th0) * 0.5 * t], -1) + np.asarray(x0[:, 0])
    vel = np.tile([np.cos(th0) * 0.5, np.sin(th0) * 0.5], (N, 1))
    head = th0 + rng.normal(size=N) * 0.1 if heading is None else np.full(N, heading)
    return x0, mpc.Preview(jnp.asarray(pos), jnp.asarray(vel), jnp.asarray(head))


# OSQP at eps 1e-8 with polishing returns the active-set solution to ~1e-9; the two problems are
# algebraically equal, so agreement to 1e-5 (the acceptance figure) has ample margin.
TOL = 1e-5


@pytest.mark.parametrize("seed", range(6))
def test_condensed_equals_noncondensed(seed):
    rng = np.random.default_rng(seed)
    N = 5
    params = _params()
    x0, prev = _random_case(rng, N)
    stance0 = seed % 2
    prev_c = prev.pos
    P, q, A, l, u = mpc.build_qp(params, x0, prev, stance0, prev_c)
    z = _osqp(P, q, A, l, u)
    u_c = np.asarray(mpc.decode(params, x0, jnp.asarray(z), N))
    u_ref, X_ref, _ = _noncondensed(params, x0, prev, stance0, prev_c)
    np.testing.assert_allclose(u_c, u_ref, atol=TOL)
    np.testing.assert_allclose(np.asarray(mpc.predict(params, x0, jnp.asarray(u_c))), X_ref, atol=TOL)


@pytest.mark.parametrize("seed", range(3))
def test_condensed_with_obstacles(seed):
    rng = np.random.default_rng(10 + seed)
    N = 6
    x0, prev = _random_case(rng, N, heading=0.0)
    # obstacle on the straight path ahead, linearised at a plan offset sideways
    obstacles = np.array([[float(prev.pos[3, 0]), float(prev.pos[3, 1]) - 0.05, 0.3],
                          [50.0, 50.0, 0.1]])
    params = _params(obstacles)
    prev_c = np.asarray(prev.pos) + np.array([0.0, 0.4])
    P, q, A, l, u = mpc.build_qp(params, x0, prev, seed % 2, jnp.asarray(prev_c))
    z = _osqp(P, q, A, l, u)
    u_ref, X_ref, s_ref = _noncondensed(params, x0, prev, seed % 2, prev_c)
    np.testing.assert_allclose(np.asarray(mpc.decode(params, x0, jnp.asarray(z), N)), u_ref, atol=TOL)
    np.testing.assert_allclose(z[2 * N:], s_ref, atol=TOL)
    # the linearised half-plane keeps every planned COM outside the disc (slack is zero here)
    X = np.asarray(mpc.predict(params, x0, jnp.asarray(u_ref)))
    dist = np.linalg.norm(X[:, :, 0] - obstacles[0, :2], axis=1)
    assert np.all(dist >= obstacles[0, 2] - 1e-6)


def test_obstacle_normals_tilt_towards_the_passing_side():
    """Closed forms: a plan straight along +x at the disc's centre line (a tie: side +1) gets
    n ∝ (c − o) + 2r (0, 1); a plan passing 0.1 m below the centre tilts down, n ∝ (c − o) −
    2r (0, 1); along heading 90° (across = −x) a plan right of o tilts to +x.  Every normal is a unit vector and
    its half-plane lies outside the disc (sampled: 1e-12 m)."""
    r = 0.4
    obstacles = jnp.array([[2.0, 0.0, r]])
    xs = jnp.linspace(0.5, 3.5, 7)
    heading = jnp.zeros(7)
    for dy, side in ((0.0, 1.0), (-0.1, -1.0)):
        prev_c = jnp.stack([xs, jnp.full(7, dy)], axis=1)
        n = np.asarray(mpc.obstacle_normals(prev_c, heading, obstacles))[:, 0]
        ref = np.stack([np.asarray(xs) - 2.0, np.full(7, dy + 2 * side * r)], axis=1)
        np.testing.assert_allclose(n, ref / np.linalg.norm(ref, axis=1, keepdims=True), atol=1e-12)
    prev_c = jnp.stack([jnp.full(7, 2.05), xs - 2.0], axis=1)     # walking +y just right of o
    n = np.asarray(mpc.obstacle_normals(prev_c, jnp.full(7, np.pi / 2), obstacles))[:, 0]
    ref = np.stack([np.full(7, 0.05 + 2 * r), np.asarray(xs) - 2.0], axis=1)  # tilted to +x
    np.testing.assert_allclose(n, ref / np.linalg.norm(ref, axis=1, keepdims=True), atol=1e-12)
    # half-planes n·(c − o) ≥ r keep out of the disc
    rng = np.random.default_rng(0)
    pts = rng.uniform(-1.0, 5.0, size=(4000, 2))
    for nj in n:
        inside = pts[(pts - [2.0, 0.0]) @ nj >= r]
        assert np.all(np.linalg.norm(inside - [2.0, 0.0], axis=1) >= r - 1e-12)


def test_predicted_states_roll_the_s2s_map():
    rng = np.random.default_rng(3)
    params = _params()
    x0 = jnp.asarray(rng.normal(size=(2, 3)))
    u = jnp.asarray(rng.normal(size=(7, 2)))
    X = np.asarray(mpc.predict(params, x0, u))
    A, B = np.asarray(params.A), np.asarray(params.B)
    x = np.asarray(x0)
    for j in range(7):
        x = x @ A.T + np.asarray(u[j])[:, None] * B
        np.testing.assert_allclose(X[j], x, rtol=1e-12, atol=1e-12)


def test_heading_90_swaps_length_and_width():
    """At θ = 90° the length row acts on u^y and the width row on −u^x."""
    params = _params()
    N = 3
    prev = mpc.Preview(jnp.zeros((N, 2)), jnp.zeros((N, 2)), jnp.full((N,), np.pi / 2))
    _, _, A, l, u = mpc.build_qp(params, jnp.zeros((2, 3)), prev, 1, jnp.zeros((N, 2)))
    # rows act on V; map them back to U (U = free_u + Ω V, and free_u = 0 at x0 = 0)
    om = np.asarray(mpc.condense(params.A, params.B, jnp.zeros((2, 3)), N).omega)
    A = np.asarray(A)[:, :2 * N] @ np.kron(np.eye(2), np.linalg.inv(om))
    np.testing.assert_allclose(A[:N, :N], 0.0, atol=1e-15)              # length ignores u^x
    np.testing.assert_allclose(A[:N, N:2 * N], np.eye(N), atol=1e-15)   # ... and is u^y
    np.testing.assert_allclose(A[N:2 * N, :N], -np.eye(N), atol=1e-15)  # width is −u^x
    np.testing.assert_allclose(A[N:2 * N, N:2 * N], 0.0, atol=1e-15)
    # stance0 = right: step 0 places the left foot, width in [w_min, w_max], then alternates
    np.testing.assert_allclose(np.asarray(l[N:2 * N]), [0.1, -0.4, 0.1])
    np.testing.assert_allclose(np.asarray(u[N:2 * N]), [0.4, -0.1, 0.4])


def test_admm_solution_matches_osqp():
    """The project's ADMM solver on the MPC QP agrees with OSQP (eps 1e-7, float64)."""
    rng = np.random.default_rng(7)
    N = 6
    params = _params(np.array([[1.0, 0.2, 0.3]]))
    x0, prev = _random_case(rng, N, heading=0.2)
    prev_c = prev.pos + jnp.array([0.0, 0.5])
    P, q, A, l, u = mpc.build_qp(params, x0, prev, 0, prev_c)
    ref = _osqp(P, q, A, l, u)
    settings = qp.Settings(eps_abs=1e-9, eps_rel=1e-9, max_iter=20000)
    plan = mpc.solve(params, x0, prev, 0, prev_c, settings)
    assert int(plan.status) == qp.SOLVED
    np.testing.assert_allclose(np.asarray(plan.z), ref, atol=1e-5)
    np.testing.assert_allclose(np.asarray(plan.u), np.asarray(mpc.decode(params, x0, jnp.asarray(ref), N)), atol=1e-5)
