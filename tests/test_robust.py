"""Tube MPC (hlip_jax.core.robust and its rows in hlip_jax.core.mpc.build_qp).

Independent references: the worst-case disturbance sequence of a box W (each step's d at the
vertex sign((A_cl^l)ᵀ d_dir) · w), which attains the support of the reachable set F_m exactly,
so the table rows are checked against simulated errors (tolerance 1e-12: the same sums in a
different order); the outer mRPI bound against 2000 random vertex sequences (it must hold, not
be tight); the tightened constraint rows against the nominal rows shifted by hand; and the
closed loop on the H-LIP plant, whose S2S noise is a box of known half-width, so the tube's
guarantee is exact: no keep-out violation at any impact with mpc.robust, where the nominal MPC
does violate it on the same seeds.
"""


from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from hlip_jax.simulation import config as C
from hlip_jax.simulation import arrays, execution
from hlip_jax.core import hlip, mpc, robust
from hlip_jax.runtime import resources
from hlip_jax.sweepio import sweep


def _plane(gain_type="lqr"):
    h = C.HLIPConfig(z0=0.8, t_ssp=0.3, t_dsp=0.1)
    A, B = (np.asarray(a, np.float64) for a in hlip.s2s_matrices(0.8, 0.3, 0.1, with_position=True))
    K = arrays._plane_gain(h, C.GainConfig(type=gain_type))[0]
    return A, B, K, A + np.outer(B, K)


@pytest.mark.parametrize("gain_type", ["deadbeat", "lqr"])
def test_table_rows_are_attained_by_the_worst_disturbance_sequence(gain_type):
    A, B, K, A_cl = _plane(gain_type)
    w = np.array([0.01, 0.02, 0.05])
    table = robust.plane_bounds(A_cl, K, w, steps=12)
    assert np.all(table[0] == 0.0), "F_0 = {0}: the first step is not tightened"
    assert np.all(np.diff(table, axis=0) >= -1e-15), "F_m grows with m"
    for m in range(1, 11):
        for col, d_dir in enumerate((np.eye(3)[0], K)):
            e = np.zeros(3)
            for l in range(m):                      # d_l multiplies A_cl^{m-1-l}
                d = np.sign(np.linalg.matrix_power(A_cl, m - 1 - l).T @ d_dir) * w
                e = A_cl @ e + d
            assert d_dir @ e == pytest.approx(table[m, col], abs=1e-12)


def test_last_row_bounds_every_random_error_sequence():
    A, B, K, A_cl = _plane("lqr")
    w = np.array([0.01, 0.01, 0.05])
    table = robust.plane_bounds(A_cl, K, w)
    rng = np.random.default_rng(0)
    e = np.zeros((2000, 3))
    worst = np.zeros(2)
    for _ in range(200):
        e = e @ A_cl.T + rng.choice([-1.0, 1.0], size=e.shape) * w
        worst = np.maximum(worst, np.abs(np.stack([e[:, 0], e @ K], axis=1)).max(axis=0))
    assert np.all(worst <= table[-1] + 1e-12)
    assert np.all(worst >= 0.5 * table[-1]), "the bound is not absurdly loose"


def test_zero_w_gives_no_tightening():
    A, B, K, A_cl = _plane()
    assert np.all(robust.plane_bounds(A_cl, K, np.zeros(3)) == 0.0)


def test_unstable_closed_loop_and_mixed_gains_are_rejected():
    A, B, K, _ = _plane()
    with pytest.raises(ValueError, match="Schur"):
        robust.tightening(A, B, np.zeros((2, 3)), np.full((2, 3), 0.01), "world")
    K2 = np.stack([K, 2 * K])
    with pytest.raises(ValueError, match="same stepping gain"):
        robust.tightening(A, B, K2, np.full((2, 3), 0.01), "heading")


def _params(**kw):
    A, B = hlip.s2s_matrices(0.8, 0.3, 0.1)
    d = dict(w_pos=1.0, w_vel=0.2, alpha=0.05, length_min=-0.3, length_max=0.5,
             width_min=0.1, width_max=0.4, obstacle_weight=1e3)
    obstacles = jnp.array([[1.0, 0.3, 0.25]])
    return mpc.MPCParams(A=A, B=B, obstacles=obstacles, obstacle_active=jnp.array([True]),
                         **{k: jnp.asarray(v, jnp.float64) for k, v in d.items()}, **kw)


@pytest.mark.parametrize("frame", [1.0, 0.0])
def test_rows_shrink_by_the_support_of_the_tube(frame):
    N, steps = 4, 10
    rng = np.random.default_rng(3)
    e_c = np.cumsum(rng.uniform(0, 0.02, (steps, 2)), axis=0)
    e_u = np.cumsum(rng.uniform(0, 0.01, (steps, 2)), axis=0)
    heading = jnp.array([0.0, 0.4, 0.8, 1.2])
    prev = mpc.Preview(pos=jnp.zeros((N, 2)), vel=jnp.zeros((N, 2)), heading=heading)
    x0 = jnp.array([[0.0, 0.05, 0.3], [0.0, -0.05, 0.1]])
    prev_c = jnp.stack([jnp.linspace(0.2, 0.8, N), jnp.zeros(N)], axis=1)
    step0 = 7                                       # rows 7..10; 10 is clipped to the last
    nominal = mpc.build_qp(_params(), x0, prev, 1, prev_c)
    tube = mpc.build_qp(_params(e_c=jnp.asarray(e_c), e_u=jnp.asarray(e_u),
                                e_heading=jnp.asarray(frame)), x0, prev, 1, prev_c, step0)
    rows = np.minimum(step0 + np.arange(N), steps - 1)
    th = np.asarray(heading)
    phi = th * frame
    # length along (cos θ, sin θ), width along (-sin θ, cos θ), both seen in the tube's frame
    def supp(dx, dy, b):
        c, s = np.cos(phi), np.sin(phi)
        return np.abs(c * dx + s * dy) * b[:, 0] + np.abs(-s * dx + c * dy) * b[:, 1]
    tl = supp(np.cos(th), np.sin(th), e_u[rows])
    tw = supp(-np.sin(th), np.cos(th), e_u[rows])
    l0, u0, l1, u1 = (np.asarray(a) for a in (nominal[3], nominal[4], tube[3], tube[4]))
    np.testing.assert_allclose(l1[:N] - l0[:N], tl, atol=1e-12)
    np.testing.assert_allclose(u0[:N] - u1[:N], tl, atol=1e-12)
    np.testing.assert_allclose(l1[N:2 * N] - l0[N:2 * N], tw, atol=1e-12)
    np.testing.assert_allclose(u0[N:2 * N] - u1[N:2 * N], tw, atol=1e-12)
    if frame == 1.0:
        np.testing.assert_allclose(tl, e_u[rows, 0], atol=1e-12)   # sagittal bound only
    # keep-out rows: + h_F(−n) with the obstacle normal of each planned state c_{j+1}
    n = np.asarray(mpc.obstacle_normals(prev_c, heading, _params().obstacles))[:, 0, :]
    rows_c = np.minimum(step0 + 1 + np.arange(N), steps - 1)
    h = supp(-n[:, 0], -n[:, 1], e_c[rows_c])
    np.testing.assert_allclose(l1[2 * N:3 * N] - l0[2 * N:3 * N], h, atol=1e-12)


def test_tube_keeps_the_com_out_of_every_disc_on_the_hlip_plant():
    sw = sweep.load_sweep(resources.data_dir("sweeps") / "robust_mpc.toml")
    cfgs = [c for c in sw.scenarios if c.swept["seed"] in (1, 2, 3) and c.gain.type == "lqr"]
    log = execution.simulate(cfgs)
    valid = np.asarray(log.valid)
    clear = np.where(valid, np.asarray(log.clearance), np.inf).min(axis=1)
    robust_on = np.array([c.mpc.robust for c in cfgs])
    assert np.all(valid[robust_on].sum(axis=1) == arrays.n_steps_of(cfgs[0])), "all walk"
    assert np.all(clear[robust_on] >= 0.0), clear[robust_on]
    assert np.any(clear[~robust_on] < 0.0), "the nominal MPC violates some disc on these seeds"


def _cov_row(group, plane, lo, hi, method="box", state="[c, p, v]"):
    return {"group": group, "plane": plane, "w_method": method, "state": state, "level": "run",
            "w_lo": " ".join(map(str, lo)), "w_hi": " ".join(map(str, hi))}


def test_w_from_coverage_encloses_the_chosen_groups_symmetrically():
    # two groups in the heading frame: per plane and coordinate, max(|w_lo|, |w_hi|) over both
    rows = [_cov_row("a", "sagittal", (-0.01, -0.05, -0.1), (0.02, 0.01, 0.03)),
            _cov_row("a", "lateral", (-0.03, -0.02, -0.2), (0.01, 0.04, 0.05)),
            _cov_row("b", "sagittal", (-0.005, -0.07, -0.01), (0.004, 0.06, 0.12)),
            _cov_row("b", "lateral", (-0.001, -0.001, -0.001), (0.002, 0.003, 0.3)),
            _cov_row("a", "sagittal", (-9, -9, -9), (9, 9, 9), method="conformal_step"),
            _cov_row("a", "lateral", (-9, -9, -9), (9, 9, 9), method="conformal_step")]
    frame, w, groups = robust.w_from_coverage(rows)
    assert frame == "heading" and groups == ["a", "b"]
    np.testing.assert_array_equal(w, [[0.02, 0.07, 0.12], [0.03, 0.04, 0.3]])
    frame, w, _ = robust.w_from_coverage(rows, "box", ["b"])
    np.testing.assert_array_equal(w, [[0.005, 0.07, 0.12], [0.002, 0.003, 0.3]])
    _, w, _ = robust.w_from_coverage(rows, "conformal_step")
    np.testing.assert_array_equal(w, np.full((2, 3), 9.0))
    world = [_cov_row("w", "world x", (-1, -1, -1), (1, 1, 1)), _cov_row("w", "world y", (-2, 0, 0), (0, 0, 3))]
    frame, w, _ = robust.w_from_coverage(world)
    assert frame == "world"
    np.testing.assert_array_equal(w, [[1, 1, 1], [2, 0, 3]])


@pytest.mark.parametrize("rows,kwargs,match", [
    ([_cov_row("a", "sagittal", (0, 0, 0), (1, 1, 1))], {"groups": ["z"]}, "'z' is not in coverage.csv; allowed: a"),
    ([_cov_row("a", "sagittal", (0, 0, 0), (1, 1, 1))], {"method": "conformal_step"}, "no coverage.csv rows"),
    ([_cov_row("a", "sagittal", (0, 0, 0), (1, 1, 1))], {}, "has no rows"),
    ([_cov_row("a", "sagittal", (0, 0, 0), (1, 1, 1)), _cov_row("b", "world x", (0, 0, 0), (1, 1, 1))], {},
     "frames"),
    ([_cov_row("a", "sagittal", (0, 0), (1, 1), state="[p, v]")], {}, "needs"),
    ([_cov_row("a", "sagittal", ("nan",) * 3, ("nan",) * 3)], {}, "no finite W"),
])
def test_w_from_coverage_refuses(rows, kwargs, match):
    with pytest.raises(ValueError, match=match):
        robust.w_from_coverage(rows, **kwargs)


# --- a W that is not a box: the symmetric hull of points ----------------------------------------
def _corners(w):
    return np.array([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)]) * w


def test_hull_of_box_corners_gives_the_box_tables():
    # conv(±corners) is the box: rows F_m equal (the same sums, 1e-15); the last row bounds
    # F_∞ from above, within the box's outer mRPI bound's ε (1e-5) of it
    A, B, K, A_cl = _plane()
    w = np.array([0.01, 0.02, 0.05])
    box = robust.plane_bounds(A_cl, K, w)
    hull = robust.hull_bounds(A_cl, K, _corners(w))
    np.testing.assert_allclose(hull[:-1], box[:-1], atol=1e-15, rtol=0)
    np.testing.assert_allclose(hull[-1], box[-1], atol=1e-5)
    gain = np.stack([K, K])
    t_box = robust.tightening(A, B, gain, np.stack([w, w]), "heading")
    t_hull = robust.tightening(A, B, gain, np.zeros((2, 3)), "heading", [_corners(w)] * 2)
    np.testing.assert_allclose(t_hull.e_u, t_box.e_u, atol=1e-5)
    np.testing.assert_allclose(t_hull.e_c, t_box.e_c, atol=1e-5)


def test_hull_rows_are_attained_and_the_last_row_bounds_them():
    # row m is attained by the disturbance sequence that takes, at each l, the point ±s_j of
    # largest s·(A_cl^{m-1-l})ᵀ g (1e-12); the last row is at least every row and at most
    # 1e-10 above the series summed to 2000 terms (its tail bound, radius·‖g‖·L·M·a/(1−a)
    # with a = ‖A_clᴸ‖₂ ≤ 1e-12, is below that here)
    A, B, K, A_cl = _plane()
    S = np.random.default_rng(5).normal(size=(40, 3)) * [0.01, 0.03, 0.06]
    table = robust.hull_bounds(A_cl, K, S, steps=12)
    for m in range(1, 11):
        for col, g in enumerate((np.eye(3)[0], K)):
            e = np.zeros(3)
            for l in range(m):
                v = S @ (np.linalg.matrix_power(A_cl, m - 1 - l).T @ g)
                e = A_cl @ e + np.sign(v[np.argmax(np.abs(v))]) * S[np.argmax(np.abs(v))]
            assert abs(g @ e - table[m, col]) < 1e-12
    long = sum(np.abs(S @ (np.linalg.matrix_power(A_cl, l).T @ np.stack([np.eye(3)[0], K]).T)).max(0)
               for l in range(2000))
    assert np.all(table[-1] >= table[:-1].max(axis=0))
    assert np.all(table[-1] >= long - 1e-15) and np.all(table[-1] <= long + 1e-10)


def test_symmetric_hull_vertices_keep_every_support():
    S = np.random.default_rng(6).normal(size=(300, 3))
    V = robust.symmetric_hull_vertices(S)
    assert len(V) < len(S)
    D = np.random.default_rng(7).normal(size=(5000, 3))
    np.testing.assert_allclose(np.abs(V @ D.T).max(0), np.abs(S @ D.T).max(0), atol=1e-12, rtol=0)


def test_read_hull_reads_and_refuses(tmp_path):
    f = tmp_path / "w.csv"
    f.write_text("plane,c,p,v\n1,0.01,0.02,0.03\n2,-0.01,0,0.5\n2,0.02,0.01,-0.1\n")
    p1, p2 = robust.read_hull(f)
    np.testing.assert_array_equal(p1, [[0.01, 0.02, 0.03]])
    assert p2.shape == (2, 3)
    for text, match in (("c,p,v\n1,2,3\n", "header"), ("plane,c,p,v\n1,0,0\n", "line 2"),
                        ("plane,c,p,v\n3,0,0,0\n2,0,0,0\n", "line 2"),
                        ("plane,c,p,v\n1,0,nan,0\n2,0,0,0\n", "line 2"),
                        ("plane,c,p,v\n1,0,0,0\n", "every plane")):
        bad = tmp_path / f"bad{abs(hash(text))}.csv"
        bad.write_text(text)
        with pytest.raises(ValueError, match=match):
            robust.read_hull(bad)
    with pytest.raises(ValueError, match="not found"):
        robust.read_hull(tmp_path / "missing.csv")


def test_sweep_checks_the_w_shape(tmp_path):
    f = tmp_path / "w.csv"
    f.write_text("plane,c,p,v\n1,0.01,0.02,0.03\n2,0.01,0.02,0.03\n")
    head = 'name = "t"\n[base]\nplant = "hlip"\n[base.mpc]\nrobust = true\n'
    tail = '\n[[paths]]\nname = "l"\nshape = "line"\n'
    ok = sweep.parse_sweep(head + f'w_shape = "hull"\nw_hull_file = "{f}"' + tail)
    assert ok.scenarios[0].mpc.w_shape == "hull"
    for body, match in ((f'w_shape = "hull"\nw_hull_file = "{f}"\nw_c_1 = 0.01', "mpc.w_c_1"),
                        (f'w_hull_file = "{f}"', "mpc.w_hull_file"),
                        (f'w_shape = "hull"\nw_hull_file = "{tmp_path / "no.csv"}"', "mpc.w_hull_file")):
        with pytest.raises(sweep.SweepError, match=match):
            sweep.parse_sweep(head + body + tail)


def test_a_relative_hull_file_is_read_from_the_sweep_files_directory(tmp_path, monkeypatch):
    # in [base], in a path's overrides, in a grid axis, and through extends (each file's own
    # directory), whatever the working directory
    (tmp_path / "a" / "data").mkdir(parents=True)
    (tmp_path / "b").mkdir()
    for name in ("w.csv", "v.csv"):
        (tmp_path / "a" / "data" / name).write_text("plane,c,p,v\n1,0.01,0.02,0.03\n2,0.01,0.02,0.03\n")
    (tmp_path / "a" / "parent.toml").write_text(
        'name = "p"\n[base]\nplant = "hlip"\n[base.mpc]\nrobust = true\nw_shape = "hull"\n'
        'w_hull_file = "data/w.csv"\n[[paths]]\nname = "l"\nshape = "line"\n'
        '[[paths]]\nname = "m"\nshape = "line"\n[paths.overrides.mpc]\nw_hull_file = "data/v.csv"\n')
    (tmp_path / "a" / "grid.toml").write_text(
        'extends = "parent"\n[grid.product]\n"mpc.w_hull_file" = ["data/w.csv", "data/v.csv"]\n')
    (tmp_path / "b" / "child.toml").write_text('extends = "../a/parent"\n')
    monkeypatch.chdir(tmp_path / "b")
    files = lambda sw: sorted({Path(c.mpc.w_hull_file).name for c in sw.scenarios})
    for f in ("a/parent.toml", "b/child.toml", "a/grid.toml"):
        sw = sweep.load_sweep(tmp_path / f)
        assert files(sw) == ["v.csv", "w.csv"]
        assert all(Path(c.mpc.w_hull_file).is_absolute() for c in sw.scenarios)
