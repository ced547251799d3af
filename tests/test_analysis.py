"""The analysis pipeline's parts against simulated processes with known answers: intervals over
runs, the run-cluster bootstrap, the conformal sets, the masks, the splits, the set gauge."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats as st

from hlip_jax.core import invariant as inv
from hlip_jax.core import sets
from hlip_jax.analysis import estimators, masks, settings, splits, stats

# --------------------------------------------------------------------------------------------
# intervals over runs: AR(1) errors with a = 0.9 (the preset's largest |eig(A + BK)|)

A_AR, RUNS, STEPS, REPS, BOUND = 0.9, 128, 40, 1000, 1.96


def _ar1(rng, n_runs: int) -> np.ndarray:
    """Stationary AR(1) runs e_{k+1} = a e_k + w, unit marginal variance: (n_runs, STEPS)."""
    e = np.empty((n_runs, STEPS))
    e[:, 0] = rng.standard_normal(n_runs)
    w = rng.standard_normal((n_runs, STEPS)) * math.sqrt(1 - A_AR ** 2)
    for k in range(1, STEPS):
        e[:, k] = A_AR * e[:, k - 1] + w[:, k]
    return e


def test_run_and_cluster_intervals_hold_their_level_on_correlated_steps():
    """1000 replicates of 128 AR(1) runs x 40 steps, E = [−1.96, 1.96] (unit variance).
    Truths: per step P(|e| ≤ 1.96) = 2Φ(1.96) − 1 (closed form, stationary); per run
    P(all 40 inside), from 400,000 independent runs (Monte Carlo sd 7e-4).  The Clopper–Pearson
    interval over runs and the run-cluster bootstrap interval over steps must contain their
    truth in ≥ 93 % of the replicates (binomial sd of the count at 95 %: 0.7 %).  The interval
    that takes the 5120 steps as independent does not: asserted below 80 % (about 55 %)."""
    rng = np.random.default_rng(2026)
    p_step = 2 * st.norm.cdf(BOUND) - 1
    p_run = float(np.mean(np.all(np.abs(_ar1(rng, 400_000)) <= BOUND, axis=1)))
    hit_run = hit_boot = hit_naive = 0
    for _ in range(REPS):
        inside = np.abs(_ar1(rng, RUNS)) <= BOUND
        k_run = int(np.all(inside, axis=1).sum())
        lo, hi = stats.clopper_pearson(k_run, RUNS)
        hit_run += lo <= p_run <= hi
        lo, hi = stats.cluster_bootstrap(list(inside), n_boot=400, seed=int(rng.integers(1 << 30)))
        hit_boot += lo <= p_step <= hi
        lo, hi = stats.clopper_pearson(int(inside.sum()), inside.size)
        hit_naive += lo <= p_step <= hi
    assert hit_run / REPS >= 0.93, hit_run
    assert hit_boot / REPS >= 0.93, hit_boot
    assert hit_naive / REPS < 0.80, hit_naive


def test_cluster_bootstrap_edge_cases():
    assert all(math.isnan(v) for v in stats.cluster_bootstrap([]))
    # no failure: Clopper–Pearson over the 2 runs, not a collapsed [1, 1]
    lo, hi = stats.cluster_bootstrap([np.ones(5, bool), np.ones(3, bool)])
    assert hi == 1.0 and lo == pytest.approx(0.025 ** 0.5, rel=1e-9)
    with pytest.raises(ValueError, match="level"):
        stats.cluster_bootstrap([np.ones(2, bool)], level=1.5)


# --------------------------------------------------------------------------------------------
# estimators


def test_conformal_rank_and_too_few_units():
    assert estimators.conformal_rank(9, 0.9) == 9          # ⌈10 · 0.9⌉
    assert estimators.conformal_rank(50, 0.9) == 46        # ⌈45.9⌉
    with pytest.raises(ValueError, match="needs n >= 9"):
        estimators.conformal_rank(8, 0.9)
    with pytest.raises(ValueError, match="q"):
        estimators.conformal_rank(10, 1.0)


def test_registry_names_its_methods():
    assert list(estimators.METHODS) == ["box", "hull", "conformal_step", "conformal_run",
                                        "conformal_box"]
    with pytest.raises(ValueError, match="allowed: box, hull, conformal_step, conformal_run, "
                                         "conformal_box"):
        estimators.method("quantile")


@pytest.mark.parametrize("dist", ["normal", "uniform"])
def test_conformal_step_box_covers_at_least_q_on_fresh_draws(dist):
    """Per coordinate, E[P(|w*_j| ≤ r_j)] = m/(n+1) ∈ [q, q + 1/(n+1)) for exchangeable draws
    (n = 40, q = 0.9); averaged over 300 calibrations × 2000 fresh draws (sd ≈ 0.0026), 0.01
    tolerance on each side."""
    rng = np.random.default_rng(7)
    n, q = 40, 0.9
    draw = ((lambda size: rng.standard_normal(size) * [0.01, 0.05]) if dist == "normal" else
            (lambda size: rng.uniform(-1, 1, size) * [0.01, 0.05]))
    covs = []
    for _ in range(300):
        W = estimators.conformal_step_w(draw((n, 2)), q)
        assert np.all(np.asarray(W.lo) == -np.asarray(W.hi))
        fresh = draw((2000, 2))
        covs.append(np.mean((fresh >= W.lo) & (fresh <= W.hi), axis=0))
    mean = np.mean(covs, axis=0)
    assert np.all(mean >= q - 0.01) and np.all(mean <= q + 1 / (n + 1) + 0.01), mean


def test_run_calibrated_set_covers_q_of_new_runs():
    """The run-level conformal set on a 2-D linear error system with i.i.d. box noise: n = 99
    training runs, E_q = s_(90) E_shape; over 200 calibrations the mean coverage of 400 fresh
    runs lies in [q, q + 1/(n+1)] within 0.01 (sd of the mean ≈ 0.002).  A fallen training run
    scores +inf; more than (1 − q)(n + 1) falls leave E_q unbounded (ValueError)."""
    rng = np.random.default_rng(3)
    Acl = np.array([[0.5, 0.2], [0.0, 0.6]])

    def runs(n):
        e = np.zeros((n, 20, 2))
        for k in range(1, 20):
            e[:, k] = e[:, k - 1] @ Acl.T + rng.uniform(-1, 1, (n, 2)) * [0.01, 0.02]
        return e[:, 3:]

    shape = inv.mrpi(Acl, sets.Box(np.array([-0.01, -0.02]), np.array([0.01, 0.02])))
    covs = []
    for _ in range(200):
        scores = estimators.run_scores(shape, list(runs(99)), [False] * 99)
        E = estimators.calibrate(shape, scores, 0.9)
        fresh = runs(400)
        covs.append(np.mean([np.all(E.contains(r)) for r in fresh]))
    assert 0.9 - 0.01 <= np.mean(covs) <= 0.9 + 1 / 100 + 0.01, np.mean(covs)
    s = estimators.run_scores(shape, [np.zeros((0, 2)), runs(1)[0]], [True, False])
    assert s[0] == math.inf and 0 < s[1] < 1
    with pytest.raises(ValueError, match="fell"):
        estimators.calibrate(shape, np.r_[np.ones(89), np.full(10, np.inf)], 0.9)


def _ar_runs(rng, n, Acl, scale, steps=30, skip=4):
    """n runs of e⁺ = Acl e + d, d uniform in ±scale, from e = 0; the first ``skip`` dropped."""
    e = np.zeros((n, steps, Acl.shape[0]))
    for k in range(1, steps):
        e[:, k] = e[:, k - 1] @ Acl.T + rng.uniform(-1, 1, (n, Acl.shape[0])) * scale
    return list(e[:, skip:])


#: a [c, p, v]-like error system: c integrates p slowly (eigenvalue 0.9), p and v settle fast
ACL3 = np.array([[0.9, 0.3, 0.1], [0.0, 0.4, 0.2], [0.0, -0.3, 0.3]])
SCALE3 = np.array([0.002, 0.01, 0.03])


def test_calibrated_methods_fit_the_shape_on_half_and_score_the_other_half():
    """Alternate training runs fit E_shape, the others are scored: a fall among the shape runs
    does not enter the scores, one among the calibration runs scores +inf."""
    assert estimators.shape_and_calibration(5) == ([0, 2, 4], [1, 3])
    rng = np.random.default_rng(1)
    e = _ar_runs(rng, 40, ACL3, SCALE3)
    d = [x[1:] - x[:-1] @ ACL3.T for x in e]
    f = estimators.fit("conformal_box", ACL3, d, e, [False] * 40, 0.9)
    assert f.calibration_runs == 20 and f.samples == 20 * 25
    shape_fall = [i == 0 for i in range(40)]         # a shape run: E_q unchanged
    g = estimators.fit("conformal_box", ACL3, d, e, shape_fall, 0.9)
    assert g.calibration_runs == 20 and g.samples == 19 * 25
    cal_falls = [i in (1, 3, 5) for i in range(40)]  # 3 of 20 calibration runs: > (1 - q)(n + 1)
    with pytest.raises(ValueError, match="fell"):
        estimators.fit("conformal_box", ACL3, d, e, cal_falls, 0.9)


@pytest.mark.parametrize("name", ["conformal_run", "conformal_box"])
def test_calibrated_sets_cover_q_of_new_runs_with_the_shape_from_training_runs(name):
    """The whole procedure, shape included, on the 3-state system: n = 100 training runs (50
    scored, m = ⌈51 · 0.9⌉ = 46), 300 fresh runs; over 100 replicates the mean coverage lies
    in [q, q + 1/51] within 0.015 (sd of one replicate's coverage ≈ 0.04, of the mean ≈
    0.004)."""
    rng = np.random.default_rng(11)
    covs = []
    for _ in range(100):
        e = _ar_runs(rng, 100, ACL3, SCALE3)
        d = [x[1:] - x[:-1] @ ACL3.T for x in e]
        E = estimators.fit(name, ACL3, d, e, [False] * 100, 0.9).E
        covs.append(np.mean([np.all(E.contains(r, 1e-12)) for r in _ar_runs(rng, 300, ACL3, SCALE3)]))
    assert 0.9 - 0.015 <= np.mean(covs) <= 0.9 + 1 / 51 + 0.015, np.mean(covs)


def test_error_box_reaches_about_as_far_as_the_errors_and_the_mrpi_shape_does_not():
    """On the 3-state system, where c sums many partly cancelling disturbances: the
    run-calibrated box's half-width along c is within [0.5, 1.5] of the largest |e_c| of 200
    fresh runs; the run-calibrated mRPI shape's is more than 1.5 times it (its c extent is the
    worst case of the disturbance sums, which the runs do not reach while p or v set their
    scores)."""
    rng = np.random.default_rng(5)
    e = _ar_runs(rng, 200, ACL3, SCALE3)
    d = [x[1:] - x[:-1] @ ACL3.T for x in e]
    fresh = _ar_runs(rng, 200, ACL3, SCALE3)
    largest = np.max([np.max(np.abs(r), axis=0) for r in fresh], axis=0)
    ratio = {name: estimators.half_widths(estimators.fit(name, ACL3, d, e, [False] * 200,
                                                         0.9).E, 3) / largest
             for name in ("conformal_box", "conformal_run")}
    assert 0.5 <= ratio["conformal_box"][0] <= 1.5, ratio
    assert ratio["conformal_run"][0] > 1.5, ratio


# --------------------------------------------------------------------------------------------
# the gauge of a set and the scaled set


@pytest.mark.parametrize("kind", ["box", "zonotope", "hull"])
def test_gauge_is_one_on_the_boundary_and_matches_membership(kind):
    rng = np.random.default_rng(0)
    A = np.array([[0.4, 0.3, 0.1], [0.0, 0.5, 0.2], [0.1, 0.0, 0.3]])
    W = sets.Box(np.array([-0.01, -0.02, -0.03]), np.array([0.02, 0.02, 0.01]))
    S = {"box": W, "zonotope": inv.mrpi(A, W).outer,
         "hull": inv.estimate_w(rng.normal(size=(50, 3)), method="hull")}[kind]
    pts = rng.normal(size=(4000, 3)) * 0.05 + sets.center(S)
    g = sets.gauge(S, pts)
    np.testing.assert_array_equal(g <= 1 + 1e-9, np.asarray(S.contains(pts, 1e-9)))
    # a point scaled onto the boundary about the centre has gauge 1 (to 1e-12)
    c = sets.center(S)
    on = c + (pts[:20] - c) / g[:20, None]
    np.testing.assert_allclose(sets.gauge(S, on), 1.0, atol=1e-12)
    half = sets.Scaled(S, 0.5)
    np.testing.assert_array_equal(np.asarray(half.contains(pts)), g <= 0.5 * (1 + 1e-9))
    D = rng.normal(size=(7, 3))
    np.testing.assert_allclose(half.support(D), D @ c + 0.5 * (np.asarray(S.support(D)) - D @ c),
                               atol=1e-12)


# --------------------------------------------------------------------------------------------
# masks


def test_settled_never_counts_e0():
    assert masks.settled(6, 0).tolist() == [False, True, True, True, True, True]
    assert masks.settled(6, 3).tolist() == [False, False, False, True, True, True]
    with pytest.raises(ValueError, match="warmup"):
        masks.settled(6, -1)


def test_push_window_runs_until_the_error_is_back_in_the_pre_push_box():
    """Errors ±0.01 before a push at t = 4 s, a jump to 0.3 that decays by half per step: the
    window starts at the first step after the push and ends at the first step whose error is
    back in [−0.01, 0.01] (0.3 · 0.5^5 ≈ 0.0094 at the 6th step after it)."""
    K = 20
    t = np.arange(K) * 0.4
    e = np.zeros((K, 2, 3))
    e[:, :, :] = 0.01 * np.where(np.arange(K) % 2, 1, -1)[:, None, None]
    k0 = int(np.flatnonzero(t > 4.0)[0])
    for i, k in enumerate(range(k0, K)):
        e[k, 1, 2] = 0.3 * 0.5 ** i
    m = masks.masks(np.ones(K, bool), e, t, [(4.0, 0.1)], warmup=2)
    assert np.flatnonzero(m.push_window).tolist() == list(range(k0, k0 + 5))
    assert not m.kept[:2].any() and m.kept[2:k0].all() and m.kept[k0 + 5:].all()
    assert m.dkept.tolist() == (m.kept[:-1] & m.kept[1:]).tolist()
    fell = masks.masks(np.arange(K) < 12, e, t, [(4.0, 0.1)], warmup=2)
    assert not fell.kept[12:].any() and not (fell.push_window & fell.alive)[12:].any()


# --------------------------------------------------------------------------------------------
# splits and settings


def test_interleave_keeps_every_key_on_one_side():
    keys = [3, 1, 2, 1, 3, 4, 2, 4, 5]
    tr, te = splits.interleave(keys)
    assert sorted(np.concatenate([tr, te]).tolist()) == list(range(len(keys)))
    assert {keys[i] for i in tr} == {1, 3, 5} and {keys[i] for i in te} == {2, 4}
    with pytest.raises(ValueError, match="2 distinct"):
        splits.interleave([4, 4, 4])
    with pytest.raises(ValueError, match="allowed: seed, path, speed"):
        splits.split("time")


def test_analysis_settings_are_validated_with_one_line():
    assert settings.from_dict(None) == settings.AnalysisConfig()
    cfg = settings.from_dict({"splits": ["path"], "q": 0.8, "warmup": 0})
    assert (cfg.splits, cfg.q, cfg.warmup) == (("path",), 0.8, 0)
    assert settings.from_dict(settings.to_dict(cfg)) == cfg
    for raw, msg in (({"q": 1.0}, "analysis.q"), ({"splits": "seed"}, "analysis.splits"),
                     ({"methods": ["quantile"]}, "allowed: box"), ({"warmup": -1}, "warmup"),
                     ({"level": 1}, "analysis.level: unknown field")):
        with pytest.raises(ValueError, match=msg):
            settings.from_dict(raw)
