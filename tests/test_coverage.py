"""coverage.csv (hlip_jax.sweepio.store, hlip_jax.analysis.coverage) from sweeps of the exact H-LIP
plant with uniform S2S noise of known half-width: the disturbance set W is known, so E's
coverage has answers to check against (a few seconds per sweep on a CPU core)."""

from __future__ import annotations

import csv
import dataclasses
import math

import numpy as np
import pytest

from hlip_jax.core import invariant as inv
from hlip_jax.presentation import report
from hlip_jax.sweepio import runner, store, sweep
from hlip_jax.analysis import coverage as cov
from hlip_jax.analysis import runs, settings

NP, NV = 0.01, 0.03        # half-widths of the plant's uniform S2S noise on p and v [m, m/s]
#: on a straight line (heading 0) the error system's disturbance is the plant's noise,
#: d = (δp, δp, δv) with |δp| ≤ NP, |δv| ≤ NV (the noise on p moves c with it)
TRUE_HALF = np.array([NP, NP, NV])

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


def _head(text: str) -> str:
    return text[:text.index("[[paths]]")]


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


def _run_errors(out, warmup=4):
    """{scenario index: (config, RunErrors)} of a results directory (the pipeline's parts)."""
    man = store.read_manifest(out)
    found = {}
    for f in store.chunk_files(out):
        z = store.load_chunk(f)
        for j, i in enumerate(z["index"]):
            cfg = sweep.config_from_dict(man["configs"][int(i)])
            pushes = [(p.time, p.duration) for p in cfg.disturbance.pushes]
            found[int(i)] = (cfg, runs.run_errors(z, j, pushes, warmup)[2])
    return found


def test_coverage_csv_schema_and_counts(hlip_run):
    """Columns as documented; per (group, plane, method) a run row and a step row; the seed
    split alternates the seeds (1, 3, 5 train; 2, 4, 6 test); the run row counts test runs, the
    step row the kept test errors, which on the unpushed line is summary.csv's step count minus
    the warm-up of 4 (an independent count); each interval contains its estimate."""
    head, rows = _csv(hlip_run)
    assert tuple(head) == cov.COLUMNS + (store.COVERAGE_RUN,)    # the run it comes from, last
    man = store.read_manifest(hlip_run)
    steps = {r["index"]: r["steps"] for r in store.read_summary(hlip_run)}
    # the two paths share the gain: the path split pools them; the speed is not varied
    assert {(r["split"], r["group"]) for r in rows} == {
        ("seed", "line"), ("seed", "pushed"), ("path", "line+pushed")}
    rows = [r for r in rows if r["split"] == "seed"]
    assert {(r["w_method"], r["level"]) for r in rows} == {
        (m, lv) for m in settings.DEFAULT_METHODS for lv in ("run", "step")}
    for r in rows:
        assert (r["train_runs"], r["test_runs"]) == ("3", "3")
        if r["w_method"] in ("conformal_run", "conformal_box"):   # too few runs for q = 0.9
            assert "needs n >= 9 training units" in r["note"] and r["coverage"] == "nan"
            continue
        c, lo, hi = float(r["coverage"]), float(r["ci_low"]), float(r["ci_high"])
        assert lo <= c <= hi
        if r["level"] == "run":
            assert r["test_samples"] == "3"
        elif r["group"] == "line":
            n_test = sum(steps[i] - 4 for i, cf in enumerate(man["configs"])
                         if cf["swept"]["path"] == "line" and cf["swept"]["seed"] % 2 == 0)
            assert int(r["test_samples"]) == n_test
        assert int(r["covered"]) == round(c * int(r["test_samples"]))
        assert float(r["e_half_c"]) > 0 and float(r["err_max_c"]) >= float(r["err_q_c"]) > 0
        assert "exchangeable runs" in r["assumption"]
    assert all(r["q"] == "0.9" for r in rows if r["w_method"] != "box")


def test_push_window_is_reported_apart_and_kept_out_of_w(hlip_run):
    """The 150 N lateral push lies outside the noise, yet the pushed group's box W stays
    inside the noise box (the push window never enters W; float32 rounding: 1e-6), and its
    test runs' push windows are counted apart."""
    _, rows = _csv(hlip_run)
    for r in rows:
        if r["w_method"] != "box" or r["split"] != "seed":
            continue
        hi = np.array(r["w_hi"].split(), float)
        lo = np.array(r["w_lo"].split(), float)
        assert np.all(hi <= TRUE_HALF + 1e-6) and np.all(lo >= -TRUE_HALF - 1e-6), r["group"]
        assert int(r["push_test_runs"]) == (3 if r["group"] == "pushed" else 0)


def test_mrpi_of_the_true_w_covers_every_run(hlip_run):
    """E = mRPI(A + BK, true W) holds every kept error of every unpushed run (exactly: the
    errors obey e⁺ = A_cl e + d with d in W and e at the warm-up's end inside E? No — e_1
    starts from e_0 = 0, so every later e_k lies in the k-term sum ⊆ F_∞)."""
    found = _run_errors(hlip_run, warmup=0)
    true_W = inv.Box(-TRUE_HALF - 1e-6, TRUE_HALF + 1e-6)
    z = store.load_log(hlip_run, [0])
    Acl = runs.errors.error_system(z, 0)[4]
    n_checked = 0
    for cfg, run in found.values():
        if cfg.swept["path"] != "line":
            continue
        for p in range(2):
            E = inv.mrpi(Acl[p], true_W)
            assert np.all(np.asarray(E.contains(run.kept_e(p), 1e-6))), (cfg.name, p)
            n_checked += run.kept_e(p).shape[0]
    assert n_checked > 100


def test_report_leads_with_the_run_level_table(hlip_run):
    _, md = report.write_report(hlip_run)
    text = md.read_text()
    head = "## Coverage over held-out runs"
    assert head in text and text.index(head) < text.index("## Path:")
    for h in report.ACROSS_HEAD:
        assert h in text
    assert "run-calibrated box q=0.9" in text and "What is guaranteed" in text
    assert "What each split assumes: seed: test runs are other noise seeds" in text
    # one figure of the held-out errors against E per group of the first split (seed)
    for i in range(2):
        f = hlip_run / "figures" / f"coverage_seed_{i}.png"
        assert f.is_file() and f.stat().st_size > 5000 and f"figures/coverage_seed_{i}.png" in text


def test_the_report_drawn_by_worker_processes_is_the_one_drawn_here(hlip_run, tmp_path,
                                                                     monkeypatch):
    """The across-run coverage figures and the path sections, drawn as one task list in two
    spawned workers (:func:`hlip_jax.runtime.workers.starmap`), give the in-process report:
    the same Markdown and the same figure files."""
    import shutil
    copy = tmp_path / "r"
    shutil.copytree(hlip_run, copy)
    shutil.rmtree(copy / "figures", ignore_errors=True)
    _, md = report.write_report(copy)
    here, drawn = md.read_text(), sorted(p.name for p in (copy / "figures").iterdir())
    shutil.rmtree(copy / "figures")
    monkeypatch.setattr(report, "REPORT_RUNS_PER_WORKER", 1)
    monkeypatch.setattr(report.workers.os, "cpu_count", lambda: 2)
    used = []
    starmap = report.workers.starmap
    monkeypatch.setattr(report.workers, "starmap",
                        lambda fn, calls, n: used.append((len(calls), n)) or starmap(fn, calls, n))
    _, md = report.write_report(copy)
    n_paths = len(store.read_manifest(copy)["paths"])
    assert used == [(n_paths + 2, 2)], used       # two coverage figures (groups) + the paths
    assert md.read_text() == here
    assert sorted(p.name for p in (copy / "figures").iterdir()) == drawn


def test_one_run_per_path_says_there_is_no_held_out_statistic(tmp_path):
    out = tmp_path / "one"
    runner.run_sweep(sweep.parse_sweep(_head(SWEEP) + '[[paths]]\nshape = "line"\n'), out,
                     progress=False)
    assert _csv(out)[1] == []
    _, md = report.write_report(out)
    text = md.read_text()
    assert "no held-out statistic" in text
    splits = ", ".join(store.analysis_settings(out).splits)
    assert f"held-out field of this run's splits ({splits})" in text


def test_path_and_speed_splits_and_a_value_split(tmp_path):
    """Two paths x two speeds x two seeds: the seed split groups per path, the path split
    pools the paths (one group 'line+circle'), the speed split holds out a speed; a value split
    (--train-on) trains on the named path."""
    text = (_head(SWEEP) + '[[paths]]\nshape = "line"\n[[paths]]\nshape = "circle"\n'
            '[grid.product]\n"path.peak_speed" = [0.3, 0.5]\nseed = [1, 2]\n')
    out = tmp_path / "r"
    runner.run_sweep(sweep.parse_sweep(text), out, progress=False)
    rows = [r for r in store.read_coverage(out) if r["level"] == "run"]
    by_split = {s: {r["group"] for r in rows if r["split"] == s} for s in ("seed", "path", "speed")}
    assert by_split["seed"] == by_split["speed"] == {"line", "circle"}
    assert by_split["path"] == {"line+circle"}
    for r in rows:
        assert r["test_runs"] == (4 if r["split"] == "path" else 2)
    assert all("out-of-distribution" in r["assumption"] for r in rows if r["split"] == "path")
    rows = store.coverage_rows(out, train_on=("path", ["line"]))
    assert {r["group"] for r in rows} == {"line+circle"}
    assert all((r["train_runs"], r["test_runs"]) == (4, 4) for r in rows)
    with pytest.raises(store.StoreError, match="mpc.alpha"):
        store.coverage_rows(out, train_on=("mpc.alpha", [0.1]))


def test_analysis_table_of_a_sweep_reaches_coverage_csv(tmp_path):
    text = SWEEP + '[analysis]\nmethods = ["box"]\nwarmup = 5\n'
    out = tmp_path / "r"
    runner.run_sweep(sweep.parse_sweep(text), out, progress=False)
    assert store.analysis_settings(out).warmup == 5
    rows = store.read_coverage(out)
    assert {r["w_method"] for r in rows} == {"box"}
    with pytest.raises(sweep.SweepError, match="analysis.q"):
        sweep.parse_sweep(SWEEP + "[analysis]\nq = 2\n")


HELD, REPLICATES = 200, 5


@pytest.fixture(scope="module")
def many_runs(tmp_path_factory):
    """5 x 400 seeds of the noisy line (6 s, 11 kept steps each): per replicate 200 training
    and 200 held-out runs, the replicates disjoint."""
    n = 2 * HELD * REPLICATES
    text = (_head(SWEEP).replace("duration = 8.0", "duration = 6.0") + '[[paths]]\nshape = "line"\n'
            "[grid.product]\nseed = [" + ", ".join(str(i) for i in range(1, n + 1)) + "]\n")
    out = tmp_path_factory.mktemp("many") / "r"
    runner.run_sweep(sweep.parse_sweep(text), out, progress=False)
    found = _run_errors(out)
    z = store.load_log(out, [0])
    return runs.errors.error_system(z, 0)[4], [found[i] for i in sorted(found)]


@pytest.mark.parametrize("q", [0.8, 0.9])
def test_run_calibrated_set_covers_q_of_200_held_out_runs(many_runs, q):
    """Acceptance: exact H-LIP, i.i.d. box noise, 200 training and 200 held-out runs per
    replicate.  One replicate's run-level coverage of E_q has sd ≈ 0.04 (q = 0.8) and 0.03
    (q = 0.9), calibration and test sampling together (measured over 200 re-splits), so the
    target band [q − 0.05, q + 0.08] is checked on the mean of 5 disjoint replicates (sd ≈
    0.018), and each replicate within ±4 sd of q.  The box W's mRPI set holds every held-out
    run, and E_q's half-width along c stays within 1.5x the largest held-out c error."""
    Acl, found = many_runs
    covs = []
    for rep in range(REPLICATES):
        part = found[2 * HELD * rep: 2 * HELD * (rep + 1)]
        keys = [i % 2 for i in range(len(part))]        # alternate seeds: train 0, test 1
        rows = cov.group_rows("line", Acl, [r for _, r in part], keys, ("sagittal", "lateral"),
                              split=cov.splits.split("seed"), q=q,
                              methods=("box", "conformal_run", "conformal_box"))
        for r in (r for r in rows if r["level"] == "run"):
            assert r["test_runs"] == HELD
            if r["w_method"] == "box":
                assert r["coverage"] == 1.0
            else:
                assert abs(r["coverage"] - q) <= 0.16, (rep, r["plane"], r["coverage"])
                assert r["e_half_c"] < 1.5 * r["err_max_c"]
                covs.append(r["coverage"])
    assert q - 0.05 <= float(np.mean(covs)) <= q + 0.08, covs


def test_coverage_rows_in_worker_processes_equal_one_process(hlip_run):
    """The groups spread over two spawned processes give the same rows, in the same order, as
    one process (NaN where one process has NaN; every other cell equal)."""
    one = store.coverage_rows(hlip_run, workers=1)
    two = store.coverage_rows(hlip_run, workers=2)
    assert len(one) == len(two) > 0
    for a, b in zip(one, two):
        assert a.keys() == b.keys()
        for k in a:
            both_nan = isinstance(a[k], float) and math.isnan(a[k]) and math.isnan(b[k])
            assert both_nan or a[k] == b[k], (k, a[k], b[k])
