"""Closed loop on the H-LIP plant: tracking, step limits, obstacles, pushes, failure isolation.

All scenarios run in one compiled, vmapped call (a module fixture), as a sweep would.
"""

import numpy as np
import pytest

from hlip_jax.simulation import arrays, execution, rollout
from hlip_jax.core import steplog
from hlip_jax.analysis import errors
from hlip_jax.simulation.config import (DisturbanceConfig, ObstacleConfig, PathConfig, PushConfig,
                             ScenarioConfig)

SHAPES = ("circle", "sinusoid", "square", "cardioid")
SPEEDS = (0.3, 0.8)
OBSTACLE = ObstacleConfig(x=2.0, y=0.0, radius=0.3)   # on the sinusoid's axis, crossed at x = 2
PUSH = PushConfig(time=10.0, duration=0.1, force=200.0, direction=90.0)


def _cases():
    cases = {}
    for shape in SHAPES:
        for v in SPEEDS:
            cases[f"{shape}-{v}"] = ScenarioConfig(
                path=PathConfig(shape=shape, params=dict(peak_speed=v)), duration=40.0)
    cases["obstacle"] = ScenarioConfig(
        path=PathConfig(shape="sinusoid", params=dict(peak_speed=0.5)), duration=40.0,
        obstacles=(OBSTACLE,))
    cases["obstacle_margin"] = ScenarioConfig(
        path=PathConfig(shape="sinusoid", params=dict(peak_speed=0.5)), duration=40.0,
        obstacles=(ObstacleConfig(x=2.0, y=0.0, radius=0.3, margin=0.2),))
    cases["push"] = ScenarioConfig(
        path=PathConfig(shape="line", params=dict(peak_speed=0.5, length=12.0)), duration=40.0,
        disturbance=DisturbanceConfig(pushes=(PUSH,), mass=33.0))
    cases["fall"] = ScenarioConfig(
        path=PathConfig(shape="line", params=dict(peak_speed=0.5, length=12.0)), duration=40.0,
        disturbance=DisturbanceConfig(pushes=(PushConfig(time=5.0, duration=1.0, force=4000.0),),
                                      mass=33.0))
    cases["measured"] = ScenarioConfig(
        path=PathConfig(shape="circle", params=dict(peak_speed=0.5)), duration=40.0,
        disturbance=DisturbanceConfig(noise_p=0.005, noise_v=0.02),
        mpc=ScenarioConfig().mpc.__class__(mode="measured"))
    for mode in ("position", "tube"):
        cases[f"slow-{mode}"] = ScenarioConfig(
            path=PathConfig(shape="circle", params=dict(peak_speed=0.5)), duration=40.0,
            gain=ScenarioConfig().gain.__class__(type="lqr", q_c=0.05, q_v=0.25, r=4.0),
            disturbance=DisturbanceConfig(noise_p=0.005, noise_v=0.02),
            mpc=ScenarioConfig().mpc.__class__(mode=mode))
    cases["lqr"] = ScenarioConfig(
        path=PathConfig(shape="circle", params=dict(peak_speed=0.5)), duration=40.0,
        gain=ScenarioConfig().gain.__class__(type="lqr", q_p=10.0, q_v=1.0, r=1.0),
        disturbance=DisturbanceConfig(noise_p=0.005, noise_v=0.02))
    return cases


@pytest.fixture(scope="module")
def run():
    cases = _cases()
    names = list(cases)
    log = execution.simulate([cases[n] for n in names])
    return names, cases, log


def _idx(run, name):
    return run[0].index(name)


def _path_error(log, i):
    v = log.valid[i]
    return np.linalg.norm(log.x_robot[i, :, :, 0] - log.ref_pos[i], axis=-1)[v]


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("speed", SPEEDS)
def test_paths_tracked(run, shape, speed):
    """Acceptance: mean pre-impact COM-to-path error ≤ 0.10 m and final position within 0.10 m."""
    _, _, log = run
    i = _idx(run, f"{shape}-{speed}")
    assert log.status[i] == steplog.STATUS_OK
    err = _path_error(log, i)
    assert err.mean() <= 0.10, err.mean()
    assert err[-1] <= 0.10, err[-1]
    assert np.all(log.qp_status[i][log.valid[i]] == 1)


def test_step_limits_never_violated(run):
    """Executed steps, rotated into the heading at the step instant, stay in the limits.
    Tolerance 2e-3 m: the ADMM solves to eps 1e-4 (absolute and relative on O(1) rows)."""
    names, cases, log = run
    tol = 2e-3
    for i, n in enumerate(names):
        if n in ("fall", "push", "measured", "slow-position", "slow-tube", "lqr"):
            continue
        m = cases[n].mpc
        v = log.valid[i]
        th = log.ref_heading[i]
        u = log.u_robot[i]
        length = u[:, 0] * np.cos(th) + u[:, 1] * np.sin(th)
        width = -u[:, 0] * np.sin(th) + u[:, 1] * np.cos(th)
        # step k is placed by the swing foot: left (width > 0) when the stance is right
        sign = np.where(log.stance[i] == rollout.STANCE_RIGHT, 1.0, -1.0)
        assert np.all(length[v] >= m.step_length_min - tol) and np.all(length[v] <= m.step_length_max + tol), n
        sw = sign * width
        assert np.all(sw[v] >= m.step_width_min - tol) and np.all(sw[v] <= m.step_width_max + tol), n


def test_obstacle_keep_out(run):
    """The executed pre-impact COM keeps the keep-out radius (−1 cm) and is back within
    0.10 m of the path 10 steps after passing the obstacle."""
    _, _, log = run
    i = _idx(run, "obstacle")
    v = log.valid[i]
    c = log.x_robot[i, :, :, 0]
    d = np.linalg.norm(c - [OBSTACLE.x, OBSTACLE.y], axis=-1)
    assert np.all(d[v] >= OBSTACLE.radius - 0.01), d[v].min()
    assert np.all(log.clearance[i][v] >= -0.01)
    passed = int(np.argmax((c[:, 0] > OBSTACLE.x + OBSTACLE.radius) & v))
    assert passed > 0
    err = np.linalg.norm(c - log.ref_pos[i], axis=-1)
    assert np.all(err[passed + 10:][v[passed + 10:]] <= 0.10)
    # the obstacle actually pushed the COM off the path (the test is not vacuous)
    assert err[v].max() > OBSTACLE.radius - 0.05


def test_obstacle_planning_margin(run):
    """With a planning margin the COM keeps radius + margin away (−1 cm, the exact H-LIP plant
    follows the plan), while the logged clearance is measured against the keep-out radius
    itself (to 1e-5 m: float32/float64 round-off of a distance of ~1 m)."""
    _, _, log = run
    i = _idx(run, "obstacle_margin")
    v = log.valid[i]
    d = np.linalg.norm(log.x_robot[i, :, :, 0] - [2.0, 0.0], axis=-1)
    assert np.all(d[v] >= 0.3 + 0.2 - 0.01), d[v].min()
    np.testing.assert_allclose(log.clearance[i][v], d[v] - 0.3, atol=1e-5)


def test_push_recovery(run):
    """200 N lateral for 0.1 s at t = 10 s on 33 kg: back within 0.10 m of the H-LIP in 6 steps."""
    _, _, log = run
    i = _idx(run, "push")
    assert log.status[i] == steplog.STATUS_OK
    e = np.abs(log.e[i, :, :, :2]).max(axis=(1, 2))      # c and p errors [m]
    k_push = int(np.floor(10.0 / log.t[i, 1] + 1e-9)) + 1  # first SSP- after the push began
    assert e[k_push] > 0.02                              # the push is felt
    assert np.all(e[k_push + 6:][log.valid[i, k_push + 6:]] <= 0.10)
    assert np.all(np.isfinite(log.e[i][log.valid[i]]))


def test_failure_is_isolated(run):
    """A robot pushed over is marked and frozen; every other scenario of the batch gives the
    same numbers as in a batch where that robot does not fall."""
    names, cases, log = run
    i = _idx(run, "fall")
    assert log.status[i] == steplog.STATUS_FELL
    assert log.fail_step[i] >= 0
    assert not log.valid[i, log.fail_step[i] + 1:].any()
    benign = [cases["push"] if n == "fall" else cases[n] for n in names]
    other = execution.simulate(benign)
    for j, n in enumerate(names):
        if n != "fall":
            np.testing.assert_array_equal(other.x_robot[j], log.x_robot[j], err_msg=n)


def test_disturbance_recursion(run):
    """e_{k+1} = (A + BK) e_k + w_k holds on the log (the identity the invariant analysis uses)."""
    _, _, log = run
    i = _idx(run, "lqr")
    A, B, K = log.A[i], log.B[i], log.K_gain[i]
    v = log.valid[i]
    for k in range(5, 40):
        if not (v[k] and v[k + 1]):
            continue
        for p in range(2):
            Acl = A + np.outer(B, K[p])
            lhs = log.e[i, k + 1, p]
            rhs = Acl @ log.e[i, k, p] + log.w[i, k, p]
            # u_R − u_H = K e exactly (no placement error here), so only w remains
            np.testing.assert_allclose(lhs, rhs, atol=1e-9)
    # w is the plant's S2S noise: inside its box (|δp| ≤ 0.005 m on c and p, |δv| ≤ 0.02 m/s)
    w = log.w[i][v]
    w = w[np.isfinite(w).all(axis=(1, 2))]
    assert len(w) > 50
    assert np.abs(w[:, :, :2]).max() <= 0.005 + 1e-9
    assert np.abs(w[:, :, 2]).max() <= 0.02 + 1e-9
    assert np.abs(w[:, :, 2]).max() > 0.015          # and fills it


def test_measured_mode_runs(run):
    _, _, log = run
    i = _idx(run, "measured")
    assert log.status[i] == steplog.STATUS_OK
    assert _path_error(log, i).mean() <= 0.10


@pytest.mark.parametrize("name", ["lqr", "slow-tube", "slow-position", "measured"])
def test_error_recursion_per_mode(run, name):
    """The logged errors obey the error system :func:`hlip_jax.core.invariant.closed_loop` gives for
    the run's ``mpc.mode`` (the log's ``anchor``): e_{k+1} = A_cl e_k + w_k on the H-LIP plant
    (no placement error), with A_cl = A + BK (tube), A (I − e_c e_cᵀ) + BK (position) and 0
    (measured: e⁺ = w).  Tolerance 1e-9: float64 rounding of O(1) states; a wrong A_cl misses
    by the size of e (≥ 1e-3 here)."""
    from hlip_jax.core import invariant as inv
    _, _, log = run
    i = _idx(run, name)
    assert log.status[i] == steplog.STATUS_OK
    Acl, beta = inv.closed_loop(log.A[i], log.B[i], log.K_gain[i], log.anchor[i])
    v = log.valid[i]
    ks = [k for k in range(5, v.size - 1) if v[k] and v[k + 1]]
    assert len(ks) > 80
    miss = 0.0
    for k in ks:
        for p in range(2):
            rhs = Acl[p] @ log.e[i, k, p] + log.w[i, k, p]
            np.testing.assert_allclose(log.e[i, k + 1, p], rhs, atol=1e-9)
            wrong = (log.A[i] + np.outer(log.B[i], log.K_gain[i, p])) @ log.e[i, k, p]
            miss = max(miss, float(np.abs(wrong + log.w[i, k, p] - log.e[i, k + 1, p]).max()))
    if name in ("slow-position", "measured"):
        assert miss > 1e-3        # the tube's A + BK would not describe this mode


def test_position_mode_keeps_c_error_small(run):
    """Planning from the robot's c: the position error is one step's worth (≤ 0.02 m: the
    plant's noise is 0.005 m on c and p and 0.02 m/s on v per step) while the tube, with the
    same gain's slow position mode (q_c 0.05), lets it drift further; both track the circle."""
    _, _, log = run
    i, j = _idx(run, "slow-position"), _idx(run, "slow-tube")
    vi = log.valid[i]
    assert np.abs(log.e[i, vi, :, 0]).max() <= 0.02
    assert _path_error(log, i).mean() <= 0.10
    assert np.abs(log.e[j, log.valid[j], :, 0]).max() > 0.02
    assert _path_error(log, j).mean() <= 0.10


def test_stepping_gain_per_plane():
    """``gain.lateral = "deadbeat"`` replaces only the y row by the deadbeat gain (closed form:
    A + B K nilpotent, checked through its spectral radius: |λ| < 1e-4, since the eigenvalues of a
    nilpotent 3×3 matrix are only accurate to about ε^(1/3) ≈ 6e-6 times its norm); the x row
    stays the LQR gain."""
    from hlip_jax.core import hlip
    from hlip_jax.simulation.config import GainConfig, HLIPConfig, ScenarioConfig
    h = HLIPConfig(z0=0.85, t_ssp=0.26, t_dsp=0.02)
    lqr = GainConfig(type="lqr", q_c=0.05, q_v=0.25, r=4.0)
    K0 = arrays.stepping_gain(ScenarioConfig(hlip=h, gain=lqr))
    K1 = arrays.stepping_gain(ScenarioConfig(hlip=h, gain=GainConfig(
        type="lqr", q_c=0.05, q_v=0.25, r=4.0, lateral="deadbeat")))
    np.testing.assert_array_equal(K1[0], K0[0])
    np.testing.assert_array_equal(K0[0], K0[1])
    A, B = (np.asarray(a, np.float64) for a in hlip.s2s_matrices(0.85, 0.26, 0.02))
    assert np.abs(np.linalg.eigvals(A + np.outer(B, K1[1]))).max() < 1e-4
    assert np.abs(np.linalg.eigvals(A + np.outer(B, K1[0]))).max() > 0.1     # LQR: not deadbeat


def test_progress_news_from_inside_the_loop():
    """While a listener is registered the steps run in segments and the end of every segment
    is reported once, counting up to the last step; the log equals a run without a listener
    (one scan over all steps) to float round-off: the segments only split the scan (1e-12 in
    float64; the two programs are compiled separately, so their last bits may differ)."""
    from hlip_jax.runtime import progress
    cfgs = [ScenarioConfig(path=PathConfig(shape="circle", params=dict(peak_speed=v)),
                           duration=4.0) for v in (0.3, 0.6)]
    heard = []
    with progress.listening(lambda k, n: heard.append((k, n))):
        loud = execution.simulate(cfgs)
    assert not progress.active()
    quiet = execution.simulate(cfgs)
    K = loud.t.shape[1]
    L = rollout.segment_length(K)
    assert heard == [(min(k + L, K), K) for k in range(0, K, L)] and len(heard) > 1
    for f in steplog.FIELDS:
        a, b = getattr(loud, f), getattr(quiet, f)
        if np.issubdtype(np.asarray(a).dtype, np.floating):
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-12, equal_nan=True, err_msg=f)
        else:
            np.testing.assert_array_equal(a, b, err_msg=f)


@pytest.mark.parametrize("name", ["slow-position", "measured"])
def test_summary_coverage_uses_the_modes_error_system(run, name):
    """The summary's metrics follow the mode's error system (:func:`metrics.closed_loop`):
    in-sample coverage is 1 (W and E from the disturbances the errors obey), the analysis
    keeps c, and E is far smaller than the same log read as a tube run (anchor zeroed), whose
    A + BK sums the disturbances over the slow position mode (|eig| 0.9+) or adds them up for
    the measured mode's one-step errors: at least 3× in volume."""
    from hlip_jax.analysis import metrics
    _, _, log = run
    i = _idx(run, name)
    d = log._asdict()
    m = metrics.scenario_metrics(d, i)
    assert m["cov_x_outer"] == 1.0 and m["cov_y_outer"] == 1.0
    assert errors.error_model(d, i)[3] == slice(0, 3)
    as_tube = metrics.scenario_metrics(dict(d, anchor=np.zeros_like(d["anchor"])), i)
    for plane in "xy":
        assert as_tube[f"e_size_{plane}"] > 3 * m[f"e_size_{plane}"], (plane, as_tube, m)
