"""Across-run coverage statistics (hlip_jax.coverage) and coverage.csv (hlip_jax.store).

Pure-statistics checks on synthetic samples of known distribution, then one small sweep of the
real H-LIP plant (uniform S2S noise of known half-width; a few seconds on a CPU core, one JIT
compile shared by the module fixture)."""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest
from scipy import stats as st

from hlip_jax import coverage as cov
from hlip_jax import metrics, runner
from hlip_jax import invariant as inv
from hlip_jax import report, store, sweep

# --------------------------------------------------------------------------------------------
# pure statistics


def test_coverage_ci_matches_analytic_probability():
    """Samples N(0, I₂) in the box [−1, 1]²: P = (Φ(1) − Φ(−1))² ≈ 0.4661.  Tolerance: the 95 %
    Clopper–Pearson interval itself; over 40 independent seeds it must contain P at least 34
    times (expected ≥ 38; P(fewer than 35 of 40 | p = 0.95) ≈ 1.4 %, and it is deterministic
    here, fixed seeds)."""
    P = (st.norm.cdf(1.0) - st.norm.cdf(-1.0)) ** 2
    E = inv.Box(np.array([-1.0, -1.0]), np.array([1.0, 1.0]))
    hits = 0
    for seed in range(40):
        x = np.random.default_rng(seed).standard_normal((500, 2))
        k, n, p, lo, hi = cov.coverage_ci(E, x)
        assert n == 500 and k == int(np.sum(np.all(np.abs(x) <= 1.0, axis=1)))
        assert lo <= p <= hi
        hits += lo <= P <= hi
    assert hits >= 35


def test_conformal_rank_and_too_few_samples():
    assert cov.conformal_rank(9, 0.9) == 9          # ⌈10 · 0.9⌉
    assert cov.conformal_rank(50, 0.9) == 46        # ⌈45.9⌉
    assert cov.conformal_rank(99, 0.5) == 50
    with pytest.raises(ValueError, match="needs n ≥ 9"):
        cov.conformal_rank(8, 0.9)
    with pytest.raises(ValueError, match="q"):
        cov.conformal_rank(10, 1.0)


@pytest.mark.parametrize("dist", ["normal", "uniform"])
def test_conformal_box_covers_at_least_q_on_fresh_draws(dist):
    """Split-conformal guarantee, per coordinate: E[P(|w*_j| ≤ r_j)] = m/(n+1) ∈ [q, q + 1/(n+1))
    for continuous exchangeable samples (n = 40, q = 0.9: m = 37, 37/41 = 0.9024).  Averaged
    over 300 calibration draws × 2000 fresh draws; the average's standard deviation is
    ≈ sqrt(m(n+1−m)/((n+1)²(n+2)) / 300) ≈ 0.0026, so a tolerance of 0.01 (≈ 4 sd) on each side
    of [q, q + 1/(n+1)]."""
    rng = np.random.default_rng(7)
    n, q, trials = 40, 0.9, 300
    draw = ((lambda size: rng.standard_normal(size) * [0.01, 0.05]) if dist == "normal" else
            (lambda size: rng.uniform(-1, 1, size) * [0.01, 0.05]))
    covs = []
    for _ in range(trials):
        lo, hi = cov.conformal_box_w(draw((n, 2)), q)
        assert np.all(lo == -hi)
        fresh = draw((2000, 2))
        covs.append(np.mean((fresh >= lo) & (fresh <= hi), axis=0))
    mean = np.mean(covs, axis=0)
    assert np.all(mean >= q - 0.01), mean
    assert np.all(mean <= q + 1 / (n + 1) + 0.01), mean
    # not a joint guarantee: the union bound only gives 1 − 2(1 − q) = 0.8 for both at once


def test_split_by_replicate_puts_no_seed_on_both_sides():
    keys = [3, 1, 2, 1, 3, 4, 2, 4, 5]
    tr, te = cov.split_by_replicate(keys)
    assert sorted(np.concatenate([tr, te]).tolist()) == list(range(len(keys)))
    assert not {keys[i] for i in tr} & {keys[i] for i in te}
    assert {keys[i] for i in tr} == {1, 2, 3}       # ⌈0.5 · 5⌉ smallest keys train
    tr, te = cov.split_by_replicate([7, 8])
    assert tr.tolist() == [0] and te.tolist() == [1]
    with pytest.raises(ValueError, match="2 distinct"):
        cov.split_by_replicate([4, 4, 4])


def _run(K=20, n=3, seed=0, alive=None):
    rng = np.random.default_rng(seed)
    em = np.ones(K, bool) if alive is None else np.arange(K) < alive
    return cov.RunSamples(rng.normal(size=(K, 2, n)), em, np.zeros(K, bool),
                          rng.normal(size=(K - 1, 2, n)), em[1:] & em[:-1],
                          np.zeros(K - 1, bool), rng.normal(size=(K, 2)))


def test_time_halves_are_disjoint_and_causal():
    r = _run(K=20, alive=15)
    tr, te = cov.time_halves(r)
    h = 15 // 2
    assert not (tr.emask & te.emask).any() and (tr.emask | te.emask).sum() == 15
    assert np.flatnonzero(tr.dmask).max() + 1 < h <= np.flatnonzero(te.emask).min()
    assert not te.dmask.any()


def test_group_rows_single_run_is_labelled_time_split():
    Acl = np.stack([np.diag([0.5, 0.3, 0.2])] * 2)
    rows = cov.group_rows("g", Acl, [_run(K=40)], [11], ("sagittal", "lateral"), q=0.5)
    assert {r["split"] for r in rows} == {"time"}
    assert [(r["plane"], r["w_method"]) for r in rows] == [
        ("sagittal", "box"), ("sagittal", "quantile"), ("lateral", "box"), ("lateral", "quantile")]
    for r in rows:
        assert r["train_runs"] == r["test_runs"] == 1 and r["test_samples"] == 20
        assert r["ci_low"] <= r["coverage"] <= r["ci_high"]


def test_fallen_training_runs_are_left_out_of_w():
    """W (the box of the training disturbances) is that of the walked training runs alone: a
    fallen run whose disturbances are 100× larger changes nothing but ``train_fell``; the
    fallen test run stays in the test samples, and its large errors fall outside E."""
    Acl = np.stack([np.diag([0.5, 0.3, 0.2])] * 2)
    walked_tr, walked_te = _run(seed=1), _run(seed=2)
    big = _run(seed=3)
    fallen = big._replace(d=100 * big.d, e=100 * big.e, fell=True)
    ref = cov.group_rows("g", Acl, [walked_tr, walked_te], [1, 2], ("x", "y"))
    rows = cov.group_rows("g", Acl, [walked_tr, fallen, walked_te, fallen], [1, 1, 2, 2],
                          ("x", "y"))
    for r0, r in zip(ref, rows):
        assert (r["train_runs"], r["train_fell"], r["test_runs"], r["test_fell"]) == (2, 1, 2, 1)
        assert r["w_lo"] == r0["w_lo"] and r["w_hi"] == r0["w_hi"]      # same W, exactly
        assert r["train_samples"] == r0["train_samples"]
        assert r["test_samples"] == 2 * r0["test_samples"]
        assert r["covered"] < r["test_samples"] and r["coverage"] < r0["coverage"]
    only_fallen = cov.group_rows("g", Acl, [fallen, walked_te], [1, 2], ("x", "y"))
    assert all(math.isnan(r["coverage"]) and "every training run fell" in r["note"]
               for r in only_fallen)


def test_time_split_of_a_fallen_run_trains_on_its_first_half():
    """A single run that fell: the fall is its last step, so the first half still gives W."""
    Acl = np.stack([np.diag([0.5, 0.3, 0.2])] * 2)
    rows = cov.group_rows("g", Acl, [_run(K=40)._replace(fell=True)], [11], ("x", "y"), q=0.5)
    for r in rows:
        assert r["split"] == "time" and r["train_fell"] == 0 and r["test_fell"] == 1
        assert np.isfinite(r["coverage"])


def test_group_rows_unstable_gain_says_why():
    Acl = np.stack([np.eye(3) * 1.1] * 2)
    rows = cov.group_rows("g", Acl, [_run(seed=1), _run(seed=2)], [1, 2], ("x", "y"))
    assert all(math.isnan(r["coverage"]) and "Schur" in r["note"] for r in rows)


# --------------------------------------------------------------------------------------------
# coverage.csv from a small sweep of the H-LIP plant

NP, NV = 0.01, 0.03        # half-widths of the plant's uniform S2S noise on p and v [m, m/s]

SWEEP = f"""
name = "cov"
[base]
plant = "hlip"
duration = 8.0
seed = 1
[base.disturbance]
noise_p = {NP}
noise_v = {NV}
[[paths]]
shape = "line"
[[paths]]
shape = "line"
name = "pushed"
[[paths.overrides.disturbance.pushes]]
time = 4.0
duration = 0.1
force = 150.0
direction = 90.0
[grid.product]
seed = [1, 2, 3, 4, 5, 6]
"""


@pytest.fixture(scope="module")
def hlip_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("cov") / "r"
    runner.run_sweep(sweep.parse_sweep(SWEEP), out, progress=False)
    return out


def _csv(out):
    with open(out / store.COVERAGE, newline="") as fh:
        rd = csv.reader(fh)
        head = next(rd)
        return head, [dict(zip(head, r)) for r in rd]


def test_coverage_csv_schema_and_values(hlip_run):
    """Columns as documented; one row per (group, plane, method); the seed split uses 3 seeds
    per side; test_samples equals the summary's step count of the test runs (an independent
    count: summary.csv's ``steps``); the CI contains the point estimate."""
    head, rows = _csv(hlip_run)
    assert tuple(head) == cov.COLUMNS
    for c in ("group", "plane", "w_method", "train_runs", "test_runs", "test_samples",
              "coverage", "ci_low", "ci_high", "insample_coverage"):
        assert c in head
    man = store.read_manifest(hlip_run)
    steps = {r["index"]: r["steps"] for r in store.read_summary(hlip_run)}
    groups = {r["group"] for r in rows}
    assert groups == {"line", "pushed"}
    for r in rows:
        assert r["split"] == "seed" and r["train_runs"] == "3" and r["test_runs"] == "3"
        # test side: the larger half of the swept seeds, 4, 5, 6
        n_test = sum(steps[i] for i, c in enumerate(man["configs"])
                     if c["swept"]["path"] == r["group"] and c["swept"]["seed"] >= 4)
        assert int(r["test_samples"]) == n_test
        if r["group"] == "line":      # no push: every pair of consecutive counted steps is a w
            n_train = sum(steps[i] - 1 for i, c in enumerate(man["configs"])
                          if c["swept"]["path"] == "line" and c["swept"]["seed"] <= 3)
            assert int(r["train_samples"]) == n_train
        c, lo, hi = float(r["coverage"]), float(r["ci_low"]), float(r["ci_high"])
        assert lo <= c <= hi
        assert int(r["covered"]) == round(c * n_test)
        assert float(r["e_c_max"]) > 0 and float(r["err_c_max"]) > 0   # [c, p, v]: gain on c
    # the push path's W has a box with the push steps and one without; the line path has none
    methods = {(r["group"], r["w_method"]) for r in rows}
    assert ("pushed", "box_with_push") in methods and ("line", "box_with_push") not in methods
    assert ("line", "quantile") in methods
    assert all(r["q"] == str(store.COVERAGE_Q) for r in rows if r["w_method"] == "quantile")


def test_push_steps_are_left_out_of_w_and_reported_separately(hlip_run):
    """The lateral push (150 N for 0.1 s) makes the box with push steps wider than the box of
    the other steps, which stays inside the noise box (|d_p| ≤ NP, |d_v| ≤ NV up to float32
    rounding, 1e-6 allowed); the errors after the push are counted on their own."""
    _, rows = _csv(hlip_run)
    by = {(r["group"], r["plane"], r["w_method"]): r for r in rows}
    nopush = np.array(by[("pushed", "lateral", "box")]["w_hi"].split(), float)
    withp = np.array(by[("pushed", "lateral", "box_with_push")]["w_hi"].split(), float)
    assert withp[2] > 2 * nopush[2]
    assert np.all(nopush <= np.array([NP, NP, NV]) + 1e-6)
    assert int(by[("pushed", "lateral", "box")]["push_test_samples"]) > 0
    assert (int(by[("pushed", "lateral", "box")]["train_samples"])
            < int(by[("pushed", "lateral", "box_with_push")]["train_samples"]))
    assert int(by[("line", "lateral", "box")]["push_test_samples"]) == 0


def test_true_w_gives_full_across_run_coverage(hlip_run):
    """On the line (heading 0: the analysis frame is the world frame) the disturbance is the
    plant's noise, d = (δp, δp, δv) with |δp| ≤ NP, |δv| ≤ NV; E from that true box must hold
    every test error (coverage exactly 1), and the estimated box lies inside it."""
    rows = [r for r in store.coverage_rows(hlip_run) if r["group"] == "line"]
    from hlip_jax import steplog
    man = store.read_manifest(hlip_run)
    log = store.load_log(hlip_run, [i for i, c in enumerate(man["configs"])
                                    if c["swept"]["path"] == "line"])
    A, B, K, _ = metrics.error_model(log, 0)
    true_W = inv.Box(-np.array([NP, NP, NV]) - 1e-6, np.array([NP, NP, NV]) + 1e-6)
    for s in range(log["index"].size):
        mask = steplog.alive(log["valid"][s])
        _, _, _, _, e, _, _ = metrics.error_samples(log, s, mask, metrics.placement(log, s))
        for p in range(2):
            E = inv.mrpi(A + np.outer(B, K[p]), true_W)
            k, n, c, lo, hi = cov.coverage_ci(E, e[mask, p])
            assert c == 1.0 and n == mask.sum()
    for r in rows:
        if r["w_method"] == "box":
            lo = np.array(r["w_lo"].split(), float)
            hi = np.array(r["w_hi"].split(), float)
            assert np.all(hi <= np.array([NP, NP, NV]) + 1e-6)
            assert np.all(lo >= -np.array([NP, NP, NV]) - 1e-6)
            # and close to it: n training samples of U(−a, a) all stay below (1 − ε) a with
            # probability (1 − ε/2)^n per side and coordinate; ε is chosen so that this is
            # 1e-6 (for n = 57: ε = 0.43), whatever the draw (float32 and float64 runs draw
            # different noise)
            n = int(r["train_samples"])
            frac = 1.0 - 2.0 * (1.0 - 1e-6 ** (1.0 / n))
            assert np.all(hi >= frac * np.array([NP, NP, NV])), (hi, frac)
            assert np.all(lo <= -frac * np.array([NP, NP, NV])), (lo, frac)


def test_single_replicate_sweep_falls_back_to_time_split(tmp_path):
    one = SWEEP[:SWEEP.index("[[paths]]")] + '[[paths]]\nshape = "line"\n'
    sw = sweep.parse_sweep(one)
    assert len(sw.scenarios) == 1
    runner.run_sweep(sw, tmp_path / "one", progress=False)
    _, rows = _csv(tmp_path / "one")
    assert rows and {r["split"] for r in rows} == {"time"}
    assert {r["train_runs"] for r in rows} == {"1"}


def test_report_leads_with_across_run_coverage(hlip_run):
    _, md = report.write_report(hlip_run)
    text = md.read_text()
    assert "## Across-run coverage" in text
    assert text.index("## Across-run coverage") < text.index("## Path:")
    for h in report.ACROSS_HEAD:
        assert h in text
    assert "conformal q-box q=0.9" in text and "box incl. push steps" in text


def test_unswept_seed_splits_by_run(tmp_path):
    """Runs that share the gain but differ in another swept field (the MPC weight) form one
    group; without a swept seed each run is its own replicate (split "run")."""
    text = (SWEEP[:SWEEP.index("[[paths]]")] + '[[paths]]\nshape = "line"\n'
            '[grid.product]\n"mpc.alpha" = [0.01, 0.1]\n')
    runner.run_sweep(sweep.parse_sweep(text), tmp_path / "r", progress=False)
    _, rows = _csv(tmp_path / "r")
    assert {r["group"] for r in rows} == {"line"}
    assert {(r["split"], r["train_runs"], r["test_runs"]) for r in rows} == {("run", "1", "1")}


def test_quantile_w_held_out_over_50_seeds(tmp_path):
    """Acceptance check on the H-LIP plant with uniform box noise: 50 replicate seeds, W the
    conformal q-box (q = 0.9) of the 25 training seeds' disturbances, coverage of the 25 test
    seeds' disturbances per coordinate.  The steps' noise is i.i.d., so the samples are
    exchangeable and the guarantee E[coverage] ∈ [q, q + 1/(n+1)] applies (n ≈ 475).  One
    draw, so the tolerance is sampling error: sd ≈ sqrt(q(1−q)/n_test + q(1−q)/n) ≈ 0.019 for
    ≈ 500 samples on each side; 0.05 (≈ 2.6 sd) below q.  Also, the E of that W is reported
    with a coverage of the test errors, which the theorem does not bound (only printed)."""
    text = (SWEEP[:SWEEP.index("[[paths]]")] + '[[paths]]\nshape = "line"\n'
            "[grid.product]\nseed = [" + ", ".join(str(i) for i in range(1, 51)) + "]\n")
    sw = sweep.parse_sweep(text)
    assert len(sw.scenarios) == 50
    out = tmp_path / "r"
    runner.run_sweep(sw, out, progress=False)
    man = store.read_manifest(out)
    d_by_seed = {}
    for f in store.chunk_files(out):
        z = store.load_chunk(f)
        for j, i in enumerate(z["index"]):
            cfg = sweep.config_from_dict(man["configs"][int(i)])
            run = store._run_samples(z, j, cfg)[3]
            d_by_seed[cfg.swept["seed"]] = run.d[run.dmask & ~run.dpush]
    tr, te = cov.split_by_replicate(sorted(d_by_seed))
    keys = sorted(d_by_seed)
    assert not {keys[i] for i in tr} & {keys[i] for i in te}
    for p in range(2):
        train = np.concatenate([d_by_seed[keys[i]][:, p] for i in tr])
        test = np.concatenate([d_by_seed[keys[i]][:, p] for i in te])
        lo, hi = cov.conformal_box_w(train, 0.9)
        frac = np.mean((test >= lo) & (test <= hi), axis=0)
        assert train.shape[0] > 400 and test.shape[0] > 400
        assert np.all(frac >= 0.9 - 0.05), frac
        assert np.all(frac <= 0.9 + 1 / (train.shape[0] + 1) + 0.05), frac
    rows = [r for r in store.read_coverage(out) if r["w_method"] == "quantile"]
    assert {(r["train_runs"], r["test_runs"]) for r in rows} == {(25, 25)}


def test_train_on_path_tests_w_on_the_other_path(tmp_path):
    """W from the straight line, E tested on the circle (same gain, so one group across the
    paths): the split column names it; every circle run is a test run."""
    text = (SWEEP[:SWEEP.index("[[paths]]")]
            + '[[paths]]\nshape = "line"\n[[paths]]\nshape = "circle"\n'
            '[grid.product]\nseed = [1, 2]\n')
    out = tmp_path / "r"
    runner.run_sweep(sweep.parse_sweep(text), out, progress=False)
    rows = store.coverage_rows(out, train_on=("path", ["line"]))
    assert rows and {r["group"] for r in rows} == {"line+circle"}
    for r in rows:
        assert r["split"] == "path in ['line']"
        assert (r["train_runs"], r["test_runs"]) == (2, 2)
        assert r["ci_low"] <= r["coverage"] <= r["ci_high"]
    with pytest.raises(store.StoreError, match="mpc.alpha"):
        store.coverage_rows(out, train_on=("mpc.alpha", [0.1]))
    with pytest.raises(store.StoreError, match="q"):
        store.coverage_rows(out, q=1.0)
